"""factorloc: localize a robot in the plane by fusing partial estimators in a factor graph."""

from factorloc.config import Config
from factorloc.errors import ConfigError, DatasetError, FactorlocError, FusionError, InputError
from factorloc.fusion import FusionStrategy, GraphFusion, ProductFusion
from factorloc.geometry import Pose2, wrap_angle
from factorloc.odometry_model import OdometryModel, fit_odometry_model
from factorloc.pipeline import Localizer, fuse, localize
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

__all__ = [
    "CameraImage",
    "Component",
    "Config",
    "ConfigError",
    "DatasetError",
    "Estimate",
    "FactorlocError",
    "FusionError",
    "FusionStrategy",
    "GraphFusion",
    "InputError",
    "Localization",
    "Localizer",
    "Odometry",
    "OdometryModel",
    "Panorama",
    "PointCloud",
    "Pose2",
    "ProductFusion",
    "Query",
    "Reference",
    "Scan",
    "StepReport",
    "StepStatus",
    "fit_odometry_model",
    "fuse",
    "localize",
    "wrap_angle",
]
