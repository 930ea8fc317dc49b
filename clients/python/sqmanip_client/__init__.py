"""SQManip client SDK: typed, sync and async access to the SQManip gateway.

>>> from sqmanip_client import Client
>>> scene = Client("http://127.0.0.1:8080").recognize(points)  # doctest: +SKIP
"""

from .client import AsyncClient, Client
from .errors import (
    AuthenticationError,
    BadRequestError,
    ConnectionError,
    GatewayTimeoutError,
    NotFoundError,
    ServerError,
    ServiceUnavailableError,
    SQManipError,
    TimeoutError,
    TooManyRequestsError,
)
from .geometry import surface_points, to_mesh, to_superquadric
from .planning import EpisodeStatus, MPCPlan, SearchMaps
from .types import (
    CameraIntrinsics,
    Grasp,
    GraspPlan,
    Pose,
    Prediction,
    RecognizedObject,
    Scene,
    SimActionResult,
    SimObject,
    SimObservation,
    SimResetResult,
    SimState,
    SuperquadricPart,
    SupportPlane,
    TargetGrasps,
)

__all__ = [
    "AuthenticationError",
    "AsyncClient",
    "BadRequestError",
    "CameraIntrinsics",
    "Client",
    "ConnectionError",
    "EpisodeStatus",
    "MPCPlan",
    "SearchMaps",
    "GatewayTimeoutError",
    "Grasp",
    "GraspPlan",
    "NotFoundError",
    "Pose",
    "Prediction",
    "RecognizedObject",
    "SQManipError",
    "Scene",
    "ServerError",
    "ServiceUnavailableError",
    "SimActionResult",
    "SimObject",
    "SimObservation",
    "SimResetResult",
    "SimState",
    "SupportPlane",
    "SuperquadricPart",
    "TargetGrasps",
    "TimeoutError",
    "TooManyRequestsError",
    "surface_points",
    "to_mesh",
    "to_superquadric",
]
