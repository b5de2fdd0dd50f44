"""What every test shares: onnxruntime logs errors only.

The corner graphs' optional inputs are overridable initializers (`service.core.onnx_contract`),
about which onnxruntime warns at every load; the service sets the same level per session.
"""

import onnxruntime as ort

ort.set_default_logger_severity(3)
