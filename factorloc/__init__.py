"""factorloc: localize a robot in the plane by fusing partial estimators in a factor graph.

``import factorloc`` loads only the value types, the errors and the geometry; the rest of the public face
(:func:`localize`, :class:`Localizer`, :class:`Config`, the fusion strategies) is imported on first use,
so that ``factorloc --help`` and a plain import stay fast (the estimators bring OpenCV, numba and GTSAM).
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

from factorloc.errors import ConfigError, DatasetError, FactorlocError, FusionError, InputError
from factorloc.geometry import Pose2, wrap_angle
from factorloc.odometry_model import OdometryModel, fit_odometry_model
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

if TYPE_CHECKING:  # pragma: no cover
    from factorloc.config import Config
    from factorloc.fusion import FusionStrategy, GraphFusion, ProductFusion
    from factorloc.pipeline import Localizer, fuse, localize
    from factorloc.places import Place, PlaceMap

__version__ = "0.1.0"

#: The public names imported on first use, and their modules.
_LAZY = {
    "Config": "factorloc.config",
    "FusionStrategy": "factorloc.fusion",
    "GraphFusion": "factorloc.fusion",
    "ProductFusion": "factorloc.fusion",
    "Localizer": "factorloc.pipeline",
    "Place": "factorloc.places",
    "PlaceMap": "factorloc.places",
    "fuse": "factorloc.pipeline",
    "localize": "factorloc.pipeline",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'factorloc' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


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
    "Place",
    "PlaceMap",
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
