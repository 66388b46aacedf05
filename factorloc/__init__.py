"""factorloc: localize a robot in the plane by fusing partial estimators in a factor graph."""

from factorloc.config import Config
from factorloc.errors import ConfigError, DatasetError, FactorlocError, FusionError, InputError
from factorloc.geometry import Pose2, wrap_angle
from factorloc.types import (
    CameraImage,
    Component,
    Estimate,
    Localization,
    Odometry,
    Panorama,
    PointCloud,
    Query,
    Reference,
    Scan,
    StepReport,
    StepStatus,
)

__version__ = "0.1.0"
