"""planar-pose runtime: preprocessing, onnxruntime inference and the HTTP service (no torch)."""
