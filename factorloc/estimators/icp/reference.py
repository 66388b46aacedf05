"""The reference scan prepared once per reference, and the query's points."""

from __future__ import annotations

from functools import cached_property

import numpy as np

from factorloc.errors import InputError
from factorloc.estimators.icp.config import IcpConfig
from factorloc.geometry import Pose2
from factorloc.registration.global_search import LikelihoodField, reference_fields
from factorloc.registration.icp2d import PreparedScan, prepare_target
from factorloc.registration.scan2d import extract_scan, polar_profile
from factorloc.types import Query, Reference

__all__ = ["MAX_SCAN_POINTS", "IcpReference", "bounded_points", "prepare_reference", "query_points"]

#: The most points of a scan (query or reference, or the cut of a cloud) the ICP step aligns: more are thinned
#: to this many, evenly along the scan's order (deterministic), and the step's diagnostics say so
#: (``downsampled_query_points`` / ``downsampled_reference_points``: [given, kept]). A laser scan has 360–1080.
MAX_SCAN_POINTS = 4_000


def bounded_points(points_m: np.ndarray, limit: int = MAX_SCAN_POINTS) -> np.ndarray:
    """``points_m`` with at most ``limit`` rows: every row when it has no more, else ``limit`` evenly spaced ones."""
    n = len(points_m)
    if n <= limit:
        return points_m
    return points_m[np.linspace(0, n - 1, limit).round().astype(np.int64)]


class IcpReference:
    """The reference scan prepared once: points, KD-tree and normals; the global-search fields on first use.

    Parameters
    ----------
    points_m
        M×2 reference scan in the reference robot's frame (metres).
    T_world_reference
        Pose of the reference robot in the world.
    config
        The step's configuration.
    """

    def __init__(self, points_m: np.ndarray, T_world_reference: Pose2, config: IcpConfig = IcpConfig()) -> None:
        if not isinstance(T_world_reference, Pose2):
            raise InputError(f"T_world_reference must be a Pose2, got {type(T_world_reference).__name__}")
        if not isinstance(config, IcpConfig):
            raise InputError(f"config must be an IcpConfig, got {type(config).__name__}")
        self.config = config
        self.T_world_reference = T_world_reference
        self.T_reference_world = T_world_reference.inverse()
        self.n_given_points = len(points_m)
        self.target: PreparedScan = prepare_target(bounded_points(np.asarray(points_m)), config.alignment.icp)

    @property
    def points_m(self) -> np.ndarray:
        """M×2 reference points (m, reference frame)."""
        return self.target.points_m

    @cached_property
    def profile(self) -> np.ndarray:
        """Free range per bearing of the reference sensor (see :func:`~factorloc.registration.scan2d.polar_profile`)."""
        return polar_profile(self.target.points_m, gap_free_m=self.config.alignment.gap_free_m)

    @cached_property
    def fields(self) -> tuple[LikelihoodField, LikelihoodField]:
        """(coarse, fine) likelihood fields of the global search, built on first use."""
        return reference_fields(self.target.points_m, self.config.global_init.search)


def prepare_reference(reference: Reference, config: IcpConfig = IcpConfig()) -> IcpReference | None:
    """Build the :class:`IcpReference` from ``reference.scan`` (preferred) or the cut of ``reference.cloud``.

    Returns None when the reference has neither.
    """
    if not isinstance(reference, Reference):
        raise InputError(f"reference must be a Reference, got {type(reference).__name__}")
    if reference.scan is not None:
        pts = reference.scan.points_m
    elif reference.cloud is not None:
        pts = extract_scan(reference.cloud, config.scan).points_m
    else:
        return None
    return IcpReference(pts, reference.T_world_reference, config)


def query_points(query: Query, config: IcpConfig = IcpConfig()) -> np.ndarray | None:
    """The query scan (N×2, query robot frame): ``query.scan``, else the cut of ``query.cloud``; None without either."""
    if query.scan is not None:
        return query.scan.points_m
    if query.cloud is not None:
        return extract_scan(query.cloud, config.scan).points_m
    return None
