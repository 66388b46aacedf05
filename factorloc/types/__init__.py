"""Frozen, validated value types: the inputs (panorama, camera image, point cloud, scan, odometry, reference,
query) and the outputs (estimate, step report, localization).

Frames and conventions (REP-103): x forward, y left, z up, headings counter-clockwise in radians. World-frame
poses are ``T_world_robot``. Images are OpenCV BGR ``uint8`` arrays. Every constructor validates its fields and
raises :class:`~factorloc.errors.InputError` naming the bad field.

One module per kind: :mod:`~factorloc.types.components`, :mod:`~factorloc.types.estimate`,
:mod:`~factorloc.types.sensors`, :mod:`~factorloc.types.results`.
"""

from factorloc.types.components import COMPONENT_INDEX, FULL, HEADING, POSITION, Component, component_indices
from factorloc.types.estimate import Estimate
from factorloc.types.results import Localization, StepReport, StepStatus
from factorloc.types.sensors import CameraImage, Odometry, Panorama, PointCloud, Query, Reference, Scan

__all__ = [
    "COMPONENT_INDEX",
    "FULL",
    "HEADING",
    "POSITION",
    "CameraImage",
    "Component",
    "Estimate",
    "Localization",
    "Odometry",
    "Panorama",
    "PointCloud",
    "Query",
    "Reference",
    "Scan",
    "StepReport",
    "StepStatus",
    "component_indices",
]
