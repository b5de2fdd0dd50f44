"""Python SDK of the planar-pose service: which region of space a planar object is seen from.

    from planar_pose_client import PoseClient

    with PoseClient("http://127.0.0.1:8000") as client:
        pred = client.predict("photo.jpg")          # or bytes, a binary file, a numpy array
        print(pred.class_id, pred.label, f"{pred.confidence:.2f}")
        if pred.pose is not None:                   # whole mode, corner models
            print(pred.pose.distance_cm, pred.pose.azimuth_deg, pred.pose.elevation_deg)

`AsyncPoseClient` has the same methods as coroutines. Failures raise `PoseError` subclasses.
"""

from ._core import RetryPolicy
from .client import AsyncPoseClient, PoseClient
from .errors import (
    AuthError,
    BadImageError,
    CameraCorruptError,
    CameraNotFoundError,
    InvalidRequestError,
    ModelNotFoundError,
    NotFoundError,
    PoseConnectionError,
    PoseError,
    ServiceUnavailable,
    TooLargeError,
    UnsupportedMediaError,
)
from .images import ImageInput, encode_png
from .models import (
    Box,
    Camera,
    CameraIntrinsics,
    CameraList,
    Cell,
    CellNeighbour,
    ClassInfo,
    Detection,
    FxSource,
    Mode,
    ModelCard,
    ModelInfo,
    ModelList,
    Pose,
    Prediction,
    PredictResponse,
    Region,
)

__all__ = [
    "AsyncPoseClient",
    "AuthError",
    "BadImageError",
    "Box",
    "Camera",
    "CameraIntrinsics",
    "CameraList",
    "CameraCorruptError",
    "CameraNotFoundError",
    "Cell",
    "CellNeighbour",
    "ClassInfo",
    "Detection",
    "FxSource",
    "ImageInput",
    "InvalidRequestError",
    "ModelCard",
    "ModelInfo",
    "ModelList",
    "ModelNotFoundError",
    "Mode",
    "NotFoundError",
    "Pose",
    "PoseClient",
    "PoseConnectionError",
    "PoseError",
    "PredictResponse",
    "Prediction",
    "Region",
    "RetryPolicy",
    "ServiceUnavailable",
    "TooLargeError",
    "UnsupportedMediaError",
    "encode_png",
]
