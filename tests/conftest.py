"""What every test shares: onnxruntime logs errors only; the service's camera store in a
temporary folder, never the user's; in-process apps write no optimized graphs in the
background (`POSE_MODEL_PREPARE`: the many short-lived apps would each optimize every shipped
model; `test_service_model_cache.py` turns it on, and server processes get a clean
environment).

The corner graphs' optional inputs are overridable initializers (`service.core.onnx_contract`),
about which onnxruntime warns at every load; the service sets the same level per session.
"""

import os
import tempfile
from pathlib import Path

import onnxruntime as ort

ort.set_default_logger_severity(3)
os.environ["POSE_MODEL_PREPARE"] = "false"
os.environ["POSE_CAMERA_DB"] = str(Path(tempfile.mkdtemp(prefix="pose-cameras-")) / "cameras.db")
