"""What :func:`factorloc.mapping.build_map` returns: the places, the trajectory of every scan, the loop closures
with their verdicts, and the graph's marginal covariances (also of the relative pose of any two scans)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from factorloc.errors import InputError
from factorloc.geometry import Pose2, rotate_covariance
from factorloc.verdicts import Check

__all__ = ["PLACE_COVARIANCES", "Closure", "MapResult", "MappedPlace", "PlaceCovariance", "relative_covariance"]

#: What each place of :meth:`MapResult.place_map` carries as the covariance of its pose: ``"local"`` its
#: uncertainty relative to the places around it (:meth:`MapResult.local_covariances`), ``"marginal"`` the graph's
#: absolute marginal in the map frame, ``"none"`` nothing (the pose taken as exact).
PlaceCovariance = Literal["local", "marginal", "none"]
#: The choices of :data:`PlaceCovariance`.
PLACE_COVARIANCES = ("local", "marginal", "none")

if TYPE_CHECKING:
    from factorloc.places import PlaceMap


@dataclass(frozen=True, eq=False)
class MappedPlace:
    """One place (keyframe) of the map.

    ``T_world_place`` is the optimized pose of the robot when it took the place's scan (map frame = the
    odometry frame at the first place); ``covariance`` its 3×3 marginal covariance of (x_m, y_m, θ_rad) in the
    world frame; ``points_m`` the scan (N×2, place frame, metres); ``stamp_s`` its time, ``scan_index`` its index in
    the log's scans.
    """

    id: int
    stamp_s: float
    scan_index: int
    T_world_place: Pose2
    covariance: np.ndarray
    points_m: np.ndarray


@dataclass(frozen=True, eq=False)
class Closure:
    """One loop closure proposed between an older place ``place_from`` and the new place ``place_to``.

    ``T_from_to`` is what the ICP step measured (the new place in the older one's frame), ``covariance`` its 3×3
    covariance in the older place's frame; ``reliable`` / ``reason`` / ``checks`` the step's typed verdict;
    ``used_global`` whether its global search ran (no usable seed from the graph); ``seed`` the graph's relative
    pose when proposed and ``seed_sigma_m`` its largest position σ. ``weight`` is the back end's final weight
    of the added factor (1 inlier, 0 rejected by GNC; NaN when not added because the step called it
    unreliable); ``accepted`` = reliable and weight ≥ 0.5. When the step answered with part of the pose only
    (e.g. the position, its heading unconstrained), the closure is unreliable, ``T_from_to`` is the seed and
    ``covariance`` the step's covariance of the components it measured. ``proposed_by``: ``"proximity"`` (the
    streaming estimate's pose proximity) or ``"recognition"`` (place recognition, ``MapConfig.recognition_every``;
    ``seed`` is then the match's pose and ``seed_sigma_m`` the σ given to it).
    """

    place_from: int
    place_to: int
    T_from_to: Pose2
    covariance: np.ndarray
    reliable: bool
    reason: str
    checks: tuple[Check, ...]
    used_global: bool
    seed: Pose2
    seed_sigma_m: float
    weight: float = math.nan
    proposed_by: str = "proximity"

    @property
    def accepted(self) -> bool:
        return bool(self.reliable and self.weight >= 0.5)


def _adjoint(T: Pose2) -> np.ndarray:
    """The adjoint of SE(2) in GTSAM's tangent order (x, y, θ): ``T·Exp(ξ) = Exp(Ad_T ξ)·T``."""
    c, s = math.cos(T.theta), math.sin(T.theta)
    return np.array([[c, -s, T.y], [s, c, -T.x], [0.0, 0.0, 1.0]])


def relative_covariance(T_a: Pose2, T_b: Pose2, joint: np.ndarray) -> np.ndarray:
    """Covariance of ``T_a⁻¹·T_b`` (tangent at it, body frame of b) from the 6×6 joint marginal of (a, b).

    ``joint`` is in GTSAM's convention (right perturbations ``T = T̂·Exp(ξ)``, blocks in the order a, b); to first
    order ``T_a⁻¹T_b = X̂·Exp(ξ_b − Ad(X̂⁻¹) ξ_a)``.
    """
    X = T_a.between(T_b)
    J = np.hstack([-_adjoint(X.inverse()), np.eye(3)])
    out = J @ np.asarray(joint, dtype=np.float64) @ J.T
    return 0.5 * (out + out.T)


@dataclass(frozen=True, eq=False)
class MapResult:
    """The map: places, the trajectory of every scan, the loop closures, and timing.

    Attributes
    ----------
    place_ids
        (P,) place ids (the graph's keys, 0..P-1 in the order of the run).
    place_stamps_s, place_scan_indices
        (P,) time and scan index of each place.
    place_poses
        (P, 3) optimized ``T_world_place`` as ``[x_m, y_m, θ_rad]``.
    place_covariances
        (P, 3, 3) marginal covariance of each place, world frame (x, y, θ).
    scan_stamps_s, scan_poses
        (M,) and (M, 3): every scan of the log at ``T_world_place ∘ offset`` of its nearest place along the path.
    scan_places
        (M,) the place each scan hangs from.
    scan_offsets, scan_offset_covariances
        (M, 3) the scan's offset from that place (``[x, y, θ]`` in the place frame: the ICP step's alignment to it,
        fused with the alignment to the place on the scan's other side when ``MapConfig.scan_places`` is 2, or
        the odometry's when no alignment is reliable) and (M, 3, 3) its covariance (tangent at the offset; zero
        for the place's own scan).
    closures
        Every verified loop-closure proposal with its verdict.
    stats
        Counts and seconds (``places``, ``scan_factors``, ``odometry_only_links``, ``closures_proposed``,
        ``closures_reliable``, ``closures_accepted``, ``seconds_total``, ``seconds_icp``, ``seconds_isam``,
        ``seconds_batch``, ``seconds_marginals``, ``back_end``).
    """

    place_ids: np.ndarray
    place_stamps_s: np.ndarray
    place_scan_indices: np.ndarray
    place_poses: np.ndarray
    place_covariances: np.ndarray
    place_points: tuple[np.ndarray, ...]
    scan_stamps_s: np.ndarray
    scan_poses: np.ndarray
    scan_places: np.ndarray
    scan_offsets: np.ndarray
    scan_offset_covariances: np.ndarray
    closures: tuple[Closure, ...]
    stats: dict[str, Any] = field(default_factory=dict)
    marginals: Any = None  # gtsam.Marginals of the final graph (joint marginals of place pairs)

    def __len__(self) -> int:
        return int(len(self.place_ids))

    def pose(self, place_id: int) -> Pose2:
        """``T_world_place`` of one place."""
        return Pose2.from_array(self.place_poses[int(place_id)])

    def places(self) -> tuple[MappedPlace, ...]:
        """The places as plain records (id, stamp, scan index, optimized pose, world-frame covariance, scan)."""
        return tuple(
            MappedPlace(
                int(self.place_ids[k]),
                float(self.place_stamps_s[k]),
                int(self.place_scan_indices[k]),
                Pose2.from_array(self.place_poses[k]),
                self.place_covariances[k].copy(),
                self.place_points[k],
            )
            for k in range(len(self))
        )

    def place_map(self, prefix: str = "place", *, covariance: PlaceCovariance | bool = "marginal") -> PlaceMap:
        """The map as a :class:`~factorloc.places.PlaceMap` for localization and tracking in it.

        Each place becomes a :class:`~factorloc.places.Place` ``f"{prefix}{id:05d}"`` whose reference is its scan
        (robot frame at the place), posed at the optimized ``T_world_place``, with the covariance ``covariance``
        names (:data:`PlaceCovariance`; ``True`` / ``False`` are ``"marginal"`` / ``"none"``), which
        :class:`~factorloc.places.Tracker` and :class:`~factorloc.places.MultiPlaceLocalizer` add to every factor of
        the place. The marginal is the absolute one in the map frame (anchored at the first place), growing with
        the distance from it, while neighbouring places share most of that error: added to every place factor as
        independent noise it makes the factors weaker than the odometry chain. ``"local"`` is the place's
        uncertainty relative to its neighbours, what a track through neighbouring places sees
        (``docs/mapping.md``, "Localizing in the map").
        """
        from factorloc.places import Place, PlaceMap
        from factorloc.types import Reference, Scan

        kind = ("marginal" if covariance else "none") if isinstance(covariance, bool) else covariance
        if kind not in PLACE_COVARIANCES:
            raise InputError(f"covariance must be one of {PLACE_COVARIANCES} (or a bool), got {covariance!r}")
        covs = self.local_covariances() if kind == "local" else self.place_covariances
        return PlaceMap(
            [
                Place(
                    f"{prefix}{p.id:05d}", Reference(scan=Scan(p.points_m)), p.T_world_place, None if kind == "none" else covs[k]
                )
                for k, p in enumerate(self.places())
            ]
        )

    def local_covariances(self, radius_m: float = 8.0, other_pass_s: float = 30.0) -> np.ndarray:
        """(P, 3, 3) each place's covariance relative to the places around it (world frame, x, y, θ; m², rad²).

        For place ``p`` the covariance of ``T_q⁻¹·T_p`` (:func:`relative_covariance` from the graph's joint marginal
        of the two, rotated into the world frame at ``p``) for two neighbours ``q``: the place before it in the run
        (after it, for the first), and the nearest place within ``radius_m`` (m) taken more than ``other_pass_s``
        (s) away in time — the same spot on another pass, where a map's errors show (a loop closed with a small
        error); the larger of the two (by the trace of the position block). A track moving through neighbouring
        places sees their errors relative to each other, not the map frame's drift from its first place, which the
        track shares. Zeros for a map of one place.
        """
        P = len(self)
        out = np.zeros((P, 3, 3))
        if P < 2:
            return out
        xy = self.place_poses[:, :2]
        stamps = self.place_stamps_s
        for p in range(P):
            neighbours = [p - 1 if p > 0 else 1]
            d = np.hypot(xy[:, 0] - xy[p, 0], xy[:, 1] - xy[p, 1])
            d[np.abs(stamps - stamps[p]) <= other_pass_s] = np.inf
            q = int(np.argmin(d))
            if d[q] <= radius_m:
                neighbours.append(q)
            best = -1.0
            for q in neighbours:
                joint = self.joint_marginal(q, p)
                rel = world_covariance(relative_covariance(self.pose(q), self.pose(p), joint), float(self.place_poses[p, 2]))
                if rel[0, 0] + rel[1, 1] > best:
                    best, out[p] = rel[0, 0] + rel[1, 1], rel
        return out

    def joint_marginal(self, place_a: int, place_b: int) -> np.ndarray:
        """6×6 joint marginal covariance of two places (GTSAM's body-frame tangents, blocks a then b)."""
        if self.marginals is None:
            raise InputError("this MapResult holds no marginals (built with marginals disabled)")
        a, b = int(place_a), int(place_b)
        if a == b:
            c = self.marginals.marginalCovariance(a)
            return np.block([[c, c], [c, c]])
        jm = self.marginals.jointMarginalCovariance(_key_vector([a, b]))
        return np.block([[jm.at(a, a), jm.at(a, b)], [jm.at(b, a), jm.at(b, b)]])

    def scan_relative(self, scan_a: int, scan_b: int) -> tuple[Pose2, np.ndarray]:
        """The map's ``T_a⁻¹·T_b`` of two scans and its 3×3 covariance (tangent at it, body frame of b).

        ``T_a = T_p·δ_a``, ``T_b = T_q·δ_b`` (places p, q; odometry offsets δ): to first order
        ``Σ = Ad(T̂⁻¹) Σ_δa Ad(T̂⁻¹)ᵀ + Ad(δ_b⁻¹) Σ_pq Ad(δ_b⁻¹)ᵀ + Σ_δb`` with ``Σ_pq`` the covariance of
        ``T_p⁻¹T_q`` from the joint marginal (:func:`relative_covariance`; 0 when p = q).
        """
        a, b = int(scan_a), int(scan_b)
        Ta, Tb = Pose2.from_array(self.scan_poses[a]), Pose2.from_array(self.scan_poses[b])
        T = Ta.between(Tb)
        p, q = int(self.scan_places[a]), int(self.scan_places[b])
        db = Pose2.from_array(self.scan_offsets[b])
        A = _adjoint(T.inverse())
        B = _adjoint(db.inverse())
        cov = A @ self.scan_offset_covariances[a] @ A.T + self.scan_offset_covariances[b]
        if p != q:
            sig = relative_covariance(self.pose(p), self.pose(q), self.joint_marginal(p, q))
            cov = cov + B @ sig @ B.T
        return T, 0.5 * (cov + cov.T)


def _key_vector(keys: list[int]) -> Any:
    import gtsam

    return gtsam.KeyVector(keys)


def world_covariance(body_covariance: np.ndarray, theta_rad: float) -> np.ndarray:
    """A GTSAM body-frame pose covariance rotated into the world frame (position block and cross terms)."""
    return rotate_covariance(np.asarray(body_covariance, dtype=np.float64), theta_rad)
