"""Step 2 of the hierarchy: the virtual compass → θ2 (WO 2015/158682, step 202).

Points of interest are detected once in the reference panorama and, per
query, in its views (camera images or a query panorama) after they are
reprojected onto the panorama's grid (:mod:`factorloc.vision.strips`), so
that a keypoint's column gives its azimuth directly: ``az_ref`` in the
reference robot's frame, ``az_query`` in the query robot's frame (the
camera's intrinsics and yaw are applied by the reprojection). Each matched
pair votes for the relative heading ``θ = az_ref − az_query``; the densest
mode of the votes (an inlier band around it) gives θ2, at least
``min_inliers`` ≥ 2 pairs being required (the patent's claim).

Seeding by θ1: with a reliable earlier heading θ̂ ± σ̂, a query point may
only match reference points whose vote lies within
``±max(min_window_rad, window_n_sigma·σ̂)`` of θ̂, which cuts time and false
matches; without a seed the whole panorama is searched.

σθ2: the inliers' spread ``s`` gives
``σ² = s²/(n_eff − 1) + band²/n_eff + σ_floor² + σ_parallax²`` with
``n_eff = min(n, max_effective_inliers)`` (vote errors from parallax are
correlated, so more inliers stop helping; ``band²/n_eff`` because a few
coincident votes locate the mode only to about the band over √n), and
``σ ≥`` one column's angle. ``σ_parallax`` is the position hypothesis's σ
over the range of the inlier points when the parallax is corrected
(:mod:`factorloc.vision.depth`), else the parallax an assumed
displacement could cause. After a resection (below) σθ2 is instead its heading
marginal (at least its leave-one-bearing-out jackknife) with the floor.
Parallax (an extension of the patent): with a reference cloud or scan and a
position hypothesis, each reference point's azimuth is replaced by its
bearing from the hypothesised position (:mod:`factorloc.vision.depth`)
before voting; without a position hypothesis the query is assumed within
``unknown_position_sigma_m`` of the reference. The world-frame heading is
``T_world_reference.theta + θ``.

Distinctiveness (repeated textures, wrong seeds): tiled wall textures give
look-alike keypoints a period apart, and the ratio test may keep a wrong copy
for a whole texture, so a tight cluster can be wrong. Hence (i) a significant
competing vote mode adds the spread of the two-mode mixture to σθ2
(``rival_sigma_weight``); (ii) when seeded, the best matches just beyond the
window (the distinctiveness margin) may not form a stronger mode than the
window's (a wrong seed, e.g. a kidnapped robot, would otherwise be
"confirmed" by a look-alike inside its window); (iii) with a position
hypothesis the pairs are re-voted from positions within ±2σ of it, and a
better-supported mode more than 3σθ2 away makes θ2 unreliable; (iv) after a
resection the inliers are chosen again with votes corrected from the
resected position (a biased inlier set from a wrong position misleads it).

Pose from bearings (*beyond the patent*, whose compass gives θ only): with reference depth each matched
pair is a bearing from the query robot to a known world point, and three or more give the whole pose
(x, y, θ) by 2D resection (:mod:`factorloc.vision.resection`: RANSAC over minimal 3-bearing sets, then
Gauss–Newton on the angular residuals, covariance from the residual variance × (JᵀWJ)⁻¹, widened by a
delete-a-group jackknife and so that no direction rests on one group of points). When its typed checks pass
(``compass.pose.*``: inliers, inlier ratio, condition number with a stated tolerance, residual σ, σ position
and heading, a rival optimum, consistency with the seeds) the compass emits that pose with that covariance —
no parallax inflation remains, at the reference's spot or away from it — and, without a position hypothesis
to check its position against, only its heading (``pose_needs_position_seed``). When the resection cannot tell
the robot from the reference's own spot (a Wald test of the reference position, :func:`_at_reference`), the
pose is re-estimated with the position fixed there: the same-spot heading without the position's share of
error. Otherwise the heading-only path below runs (the fallback when depth or geometry is missing). Figures:
``docs/calibration/vision.md``.

Calibration of the heading-only path (measured, not changed in session 3): over the reliable θ2 of the
held-out scenarios ``factorloc simulate --world apartment --queries 300 --seed
11`` / ``--seed 23`` (kidnapped queries left out), NEES (1 dof) 0.90 / 0.47,
θ3's 0.69 / 0.73; on ``--seed 7`` 0.58. Each looks ~1.3× cautious, but θ2 and θ3
see the same images from the same position hypothesis and their normalized
errors correlate at 0.88 / 0.92 on the queries where both are reliable: fused
as independent (as the fusion does), the pair's heading NEES is already 1.58 /
1.35. Shrinking either σ would make the pair overconfident, so it is left.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from factorloc.errors import ConfigError, InputError
from factorloc.estimators.base import Hypotheses, heading_not_measured, heading_seed_check, sigma_checks
from factorloc.geometry import Pose2, wrap_angle
from factorloc.stats import largest_sigma, mahalanobis_sq_2d, smallest_sigma
from factorloc.types import Estimate, Query, Reference
from factorloc.verdicts import ROUNDING_TOLERANCE, Check, Comparison, SeedEvidence, Unit, render_checks
from factorloc.vision import keypoints as kp
from factorloc.vision.depth import (
    DepthMap,
    depth_map,
    headings_from_points,
    parallax_sigma,
    position_seed,
    spread_parallax_bound,
    uncorrected_parallax_sigma,
)
from factorloc.vision.strips import Grid, Strip, camera_strip, panorama_strip, texture_problem, to_gray

log = logging.getLogger(__name__)

STEP = "compass"


@dataclass(frozen=True)
class CompassConfig:
    """Configuration of the virtual compass (angles in radians).

    Parameters
    ----------
    detector
        ``"sift"`` (default: on the real panoramas it is reliable more often
        and 2–4× more accurate than ORB, at a similar per-query time; its
        reference preparation is slower) or ``"orb"``. See ``benchmarks/bench_vision.py``.
    n_features_reference, n_features_query
        Keypoint budgets of the reference panorama and of each query view.
    query_scale, reference_scale
        Detection scale of the query views (on the reference grid) and of the reference panorama:
        each image is area-downsampled by it before detection (:func:`factorloc.vision.keypoints.detect`).
        SIFT's cost is its first, doubled octave: detecting a query view at half the grid's
        resolution (its doubled octave then lies at the grid's) is ~5× cheaper, and a view of
        the grid's 0.18°/px matched at 0.35°/px loses little (sub-pixel keypoints). A view
        is never reduced below ``query_min_detect_px`` pixels (≈ 90×130; smaller views yield
        too few keypoints for ``min_inliers``): its scale is ``min(1, max(query_scale,
        √(query_min_detect_px / pixels)))`` (:func:`detection_scale`).
    query_min_detect_px
        The fewest pixels a query view is reduced to before detection (see ``query_scale``).
    query_octave_layers
        SIFT's layers per octave for the query views (OpenCV's ``nOctaveLayers``).
    one_keypoint_per_location
        Keep one keypoint (and descriptor) per detected position, in the reference and in the query views
        (:func:`factorloc.vision.keypoints.one_per_location_index`): SIFT reports a keypoint once per dominant
        orientation, and copies of one point matched twice would be counted as independent bearings. Off by
        default: it loses the matches of points the two images keep with different orientations
        (``docs/calibration/vision.md``).
    query_sift_sigma
        SIFT's assumed input blur for the query views (OpenCV's ``sigma``; 1.6 in Lowe's paper):
        1.2 keeps ~30 % more keypoints on the downscaled views, at no extra cost.
    fast_threshold
        ORB's FAST threshold (lower finds more corners on plain walls).
    ratio
        Lowe's ratio test on descriptor distances.
    inlier_band_rad
        Half-width of the vote consensus band.
    window_n_sigma, min_window_rad
        Seeded search half-window ``max(min_window_rad, window_n_sigma·σθ1)``;
        a window ≥ π means an unseeded search.
    min_inliers
        Fewest inlier pairs for a reliable θ2 (≥ 2, the patent's claim).
    min_inlier_ratio
        Fewest inliers per match for a reliable θ2.
    max_ambiguity
        Unreliable when a separate vote mode has ≥ this fraction of the best one's support.
    max_outside_ambiguity
        Seeded search: unreliable when the best matches just beyond the window (within
        ``distinct_margin_rad``) form a mode with ≥ this fraction of the window's mode's support.
    rival_sigma_weight
        The competing vote mode (support ``r`` less the background expected from the unmatched
        pairs in one band, λ, and the rival vote itself, offset Δ from the mode, ``n`` inliers) adds
        ``w·√(p(1−p))·|Δ|`` with ``p = r/(n + r)`` to σθ2 (the spread of a two-mode mixture, scaled by ``w``),
        when the rival is significant (≥ 3 votes and ≥ λ + 3√λ + 1). ``w = 0.7`` was chosen on a
        simulated apartment (``factorloc simulate --world apartment --queries 300 --seed 7``).
    max_sigma_rad
        Unreliable above this σθ2.
    sigma_floor_rad
        The σ floor of the σ model (rad; see the module docstring).
    max_effective_inliers
        The most inliers the σ model counts (see the module docstring).
    parallax_correction
        With a reference cloud/scan and a position hypothesis, vote with
        parallax-free world bearings (:mod:`factorloc.vision.depth`).
    camera_height_m
        Height of the reference panorama's camera above the floor (m), to read the reference cloud.
    depth_sigma_rad_per_m
        Model error of the parallax correction (coarse depth map) per metre between the
        hypothesised position and the reference, added to σ.
    unknown_position_sigma_m, default_range_m
        Without a position hypothesis the query is assumed within ``unknown_position_sigma_m``
        of the reference; the parallax this may cause (σ_p / range, the range from the reference
        depth or ``default_range_m``) enters σ. With a position hypothesis but no reference
        depth, the displacement plus its σ enter the same way.
    distinct_margin_rad
        Seeded search: look-alikes this far beyond the window still take part in the ratio test.
    seed_consistency_n_sigma
        Unreliable when θ2 is further than this many combined σ from the seed heading.
    resection
        With a position hypothesis and reference depth, refine heading *and* position from the
        inlier bearings with the hypothesis as a prior (:func:`resect`), so that σθ2 is the
        heading's marginal σ (features at several depths and directions separate a turn from a
        sideways shift).
    parallax_from_spread
        The parallax term of the heading-only σ is at most what the inliers' own spread allows
        (:func:`factorloc.vision.depth.spread_parallax_bound`): at the reference spot the votes agree to a
        fraction of a pixel across the view, which no displacement large enough to matter would leave them,
        so the σ no longer assumes the displacement the position hypothesis allows (without reference depth
        that assumption was the whole σ: no same-spot view of the real panoramas was reliable).
    spread_confidence
        Confidence of the upper limit on the inliers' rms residual that bound uses.
    spread_bound_gain
        Multiplies that bound: the plane it assumes is the worst case of a plane, not of every scene (points
        near one circle through both positions shift alike, see the function).
    depth_relative_sigma
        The relative error of the reference ranges in the resection.
        A reference range's σ is the larger of ``depth_relative_sigma``·D and half the range spread
        around it in the depth map (depth edges): a dozen bearings on one wall plus two far ones whose
        coarse ranges were wrong made a confidently wrong resection (3.8°, 4.3σ, on the simulated apartment).
    planar_depth
        Whether a depth read from a planar scan alone (no cloud: :attr:`~factorloc.vision.depth.DepthMap.planar`,
        one row standing for every elevation) corrects the parallax and resects the pose. When False such a
        reference is treated as having no depth (the heading-only path, its parallax bounded by the votes' spread).
    position_shift_support
        With a position hypothesis the pairs are also voted from a 5×5 grid of positions within ±2σ of
        it; unreliable when one of them gives a mode with ≥ this many times the inliers, more than 3σθ2
        away (the heading then depends on where, within its uncertainty, the robot is).
    pose_from_bearings
        *Beyond the patent* (its compass gives θ only): with reference depth, resect the robot's whole pose
        (x, y, θ) from the matched pairs' bearings (:func:`factorloc.vision.resection.ransac`; no position
        prior) and emit it with the residual-variance covariance when its checks pass (see the module
        docstring), so that no parallax inflation remains; else the heading-only path below applies.
    pose_depth_cols, pose_depth_rows
        The depth map the resected points are read from (:func:`factorloc.vision.depth.depth_map`; rows only
        for a cloud). Finer than the parallax correction's 32×360: on the fitting set
        (``benchmarks/bench_vision.py --pose-fit 80``) 31 % of the views get a pose at 64×1440, 29 % at 32×360
        (same position error, 0.8 cm median; no confidently wrong pose either way).
    pose_threshold_rad
        RANSAC inlier threshold on a bearing's angular residual (0.015 rad ≈ 0.86°; with ``max_pose_condition``
        chosen on the fitting set ``benchmarks/bench_vision.py --pose-fit 80``: 35 % of the views posed vs 31 %
        at 0.5° and 10⁴, no more confidently wrong; see ``docs/calibration/vision.md``).
    pose_hypotheses
        RANSAC's minimal (3-bearing) sets per query (a fixed sampler seed).
    min_pose_inliers
        Fewest resection inliers for a reliable pose.
    max_pose_condition
        Unreliable when the resection's dimensionless normal matrix (position scaled by the median range) has a
        larger condition number (a turn and a shift not separated; :attr:`factorloc.vision.resection.Resection.condition`).
    max_pose_residual_rad
        Unreliable when the inliers' residual σ is larger (a wrong depth map or a wrong pose).
    max_pose_sigma_position_m
        Unreliable when the position's largest σ is larger.
    max_pose_ambiguity
        Unreliable when a rival pose explains ≥ this fraction of the inliers' count in *other* matches
        (:attr:`factorloc.vision.resection.Resection.runner_up`).
    pose_sigma_floor_m
        Position σ floor (m) added in quadrature to the resected covariance.
    pose_residual_floor_px
        The residual σ used in the resected covariance is at least this many query pixels (sub-pixel keypoints;
        guards against a lucky small scatter of few bearings).
    pose_group_m
        Bearings to points in one cell of a world grid of this size (m) form a *group*. The resected covariance
        covers the delete-a-group jackknife, and no direction of it is trusted beyond what the groups other than
        the dominant one verify (``σ² ((H − H_g*)⁻¹ − H⁻¹)`` is added, see :func:`_group_leverage`): two false
        matches on a near object pinned the weak direction of a narrow view of one far wall, a confident pose
        29 cm off, on the simulated apartment.
    pose_seed_consistency_d2
        Unreliable when the resected position is further than this squared Mahalanobis distance (2 dof,
        combined covariances; 11.83 ≈ 3σ) from a position hypothesis.
    same_spot_max_d2
        The test of "the robot stands at the reference's spot" on a resected pose (:func:`_at_reference`): when
        the reference position lies within this squared Mahalanobis distance (2 dof) of the resected position,
        under the resection's own covariance before its floors, and that covariance's largest σ is at most
        ``same_spot_max_sigma_m`` (5 cm: a loose resection cannot refuse a spot decimetres away), the pose is
        re-estimated with the position fixed there (the heading a weighted mean of the inliers' votes from that
        point, exact for bearings) and emitted at the reference position with the resection's covariance. 5.99
        is χ²₂'s 95 % quantile; ``None`` turns the test off. See ``docs/calibration/vision.md#same-spot``.
    pose_needs_position_seed
        Without a position hypothesis (no reliable odometry) emit only the resected pose's heading (its marginal
        σ): nothing then checks the position against a look-alike. Found on the held-out scenarios (seeds 11
        and 23, one query each): a texture repeated about 2 m away fitted 32–41 bearings with the heading right
        (0.02°, 0.7°) and the position 2.0 m off at σ 3–9 cm; both queries had no reliable odometry.
    record_pairs
        Put every matched pair ``[az_ref, el_ref, az_query]`` (rad; reference and query robot
        frames, before parallax correction) in ``diagnostics["pairs_rad"]`` (for evaluation).
    """

    enabled: bool = True
    detector: str = "sift"
    n_features_reference: int = 4000
    n_features_query: int = 1500
    query_scale: float = 0.5
    reference_scale: float = 1.0
    query_sift_sigma: float = 1.2
    query_octave_layers: int = 3
    one_keypoint_per_location: bool = False
    query_min_detect_px: int = 12000
    fast_threshold: int = 10
    ratio: float = 0.8
    inlier_band_rad: float = math.radians(1.5)
    window_n_sigma: float = 3.0
    min_window_rad: float = math.radians(3.0)
    min_inliers: int = 8
    min_inlier_ratio: float = 0.1
    max_ambiguity: float = 0.5
    max_outside_ambiguity: float = 1.0
    rival_sigma_weight: float = 0.7
    max_sigma_rad: float = math.radians(5.0)
    sigma_floor_rad: float = math.radians(0.1)
    max_effective_inliers: int = 30
    parallax_correction: bool = True
    camera_height_m: float = 1.0
    depth_sigma_rad_per_m: float = math.radians(0.15)
    unknown_position_sigma_m: float = 0.3
    default_range_m: float = 3.0
    distinct_margin_rad: float = math.radians(30.0)
    seed_consistency_n_sigma: float = 3.0
    record_pairs: bool = False
    position_shift_support: float = 1.1
    resection: bool = True
    parallax_from_spread: bool = True
    spread_confidence: float = 0.99
    spread_bound_gain: float = 1.0
    depth_relative_sigma: float = 0.1
    planar_depth: bool = False
    pose_from_bearings: bool = True
    pose_depth_cols: int = 1440
    pose_depth_rows: int = 64
    pose_threshold_rad: float = 0.015
    pose_hypotheses: int = 256
    min_pose_inliers: int = 12
    max_pose_condition: float = 1.0e5
    max_pose_residual_rad: float = math.radians(0.5)
    max_pose_sigma_position_m: float = 0.25
    max_pose_ambiguity: float = 0.5
    pose_sigma_floor_m: float = 0.01
    pose_residual_floor_px: float = 0.25
    pose_group_m: float = 0.3
    pose_seed_consistency_d2: float = 11.83
    same_spot_max_d2: float | None = 5.99
    same_spot_max_sigma_m: float = 0.05
    pose_needs_position_seed: bool = True

    def __post_init__(self) -> None:
        if self.detector not in kp.DETECTORS:
            raise ConfigError(f"compass.detector must be one of {kp.DETECTORS}, got {self.detector!r}")
        for name in ("n_features_reference", "n_features_query", "fast_threshold", "max_effective_inliers"):
            if getattr(self, name) < 1:
                raise ConfigError(f"compass.{name} must be >= 1, got {getattr(self, name)!r}")
        for name in ("query_scale", "reference_scale"):
            if not 0.2 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"compass.{name} must be in [0.2, 1], got {getattr(self, name)!r}")
        if self.query_octave_layers < 1:
            raise ConfigError(f"compass.query_octave_layers must be >= 1, got {self.query_octave_layers!r}")
        if not self.query_sift_sigma > 0.0:
            raise ConfigError(f"compass.query_sift_sigma must be > 0, got {self.query_sift_sigma!r}")
        if self.query_min_detect_px < 0:
            raise ConfigError(f"compass.query_min_detect_px must be >= 0, got {self.query_min_detect_px!r}")
        if self.min_inliers < 2:
            raise ConfigError(f"compass.min_inliers must be >= 2 (two pairs at least), got {self.min_inliers!r}")
        if not 0.0 < self.ratio <= 1.0:
            raise ConfigError(f"compass.ratio must be in (0, 1], got {self.ratio!r}")
        for name in ("inlier_band_rad", "window_n_sigma", "min_window_rad", "max_sigma_rad", "sigma_floor_rad"):
            if not getattr(self, name) > 0.0:
                raise ConfigError(f"compass.{name} must be > 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.min_inlier_ratio <= 1.0:
            raise ConfigError(f"compass.min_inlier_ratio must be in [0, 1], got {self.min_inlier_ratio!r}")
        if not 0.0 < self.max_ambiguity <= 1.0:
            raise ConfigError(f"compass.max_ambiguity must be in (0, 1], got {self.max_ambiguity!r}")
        if self.same_spot_max_d2 is not None and not (math.isfinite(self.same_spot_max_d2) and self.same_spot_max_d2 > 0.0):
            raise ConfigError(f"compass.same_spot_max_d2 must be > 0 and finite, or None, got {self.same_spot_max_d2!r}")
        if not (math.isfinite(self.same_spot_max_sigma_m) and self.same_spot_max_sigma_m > 0.0):
            raise ConfigError(f"compass.same_spot_max_sigma_m must be > 0 and finite, got {self.same_spot_max_sigma_m!r}")
        if not self.spread_bound_gain > 0.0:
            raise ConfigError(f"compass.spread_bound_gain must be > 0, got {self.spread_bound_gain!r}")
        if not 0.0 < self.spread_confidence < 1.0:
            raise ConfigError(f"compass.spread_confidence must be in (0, 1), got {self.spread_confidence!r}")


@dataclass(frozen=True, eq=False)
class PreparedCompass:
    """Reference-only work of the compass: the panorama's keypoints and their azimuths.

    ``azimuth_rad`` (N,) are in the reference robot's frame; ``descriptors``
    N×D (uint8 for ORB, float32 for SIFT); ``problem`` says why the reference
    cannot be used (no texture), else None. ``depth_points`` and ``pose_points``: the world points (N×2, m),
    ranges and range spreads ((N,), m) behind each keypoint in ``depth`` and ``pose_depth``
    (:meth:`~factorloc.vision.depth.DepthMap.lookup`), looked up once here instead of per query;
    ``descriptor_sq_norms`` the descriptors' squared norms (SIFT: :func:`factorloc.vision.keypoints.sq_norms`).
    """

    grid: Grid
    azimuth_rad: np.ndarray
    elevation_rad: np.ndarray
    descriptors: np.ndarray | None
    theta_reference_rad: float
    problem: str | None
    config: CompassConfig
    depth: DepthMap | None = None
    reference_pose: Pose2 | None = None
    pose_depth: DepthMap | None = None
    depth_points: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    pose_points: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    descriptor_sq_norms: np.ndarray | None = None


def _lookup(depth: DepthMap | None, az_rad: np.ndarray, el_rad: np.ndarray) -> tuple[np.ndarray, ...] | None:
    """World points, ranges and range spreads of the keypoints behind ``depth`` (:meth:`DepthMap.lookup`), read-only."""
    if depth is None:
        return None
    out = depth.lookup(az_rad, el_rad)
    for a in out:
        a.setflags(write=False)
    return out


def prepare(reference: Reference, config: CompassConfig = CompassConfig()) -> PreparedCompass:
    """Detect and describe the reference panorama's keypoints (with wrap-around)."""
    if reference.panorama is None:
        raise InputError(f"compass needs Reference.panorama, reference {reference.name!r} has none")
    pano = reference.panorama
    grid = Grid.of(pano)
    gray = to_gray(pano.image_bgr)
    problem = texture_problem(gray)
    det = kp.make_detector(config.detector, config.n_features_reference, config.fast_threshold)
    if problem is None:
        xy, desc = kp.detect(
            gray,
            det,
            wrap_pad_px=min(64, grid.width_px // 4),
            scale=config.reference_scale,
            one_per_location=config.one_keypoint_per_location,
        )
    else:
        xy, desc = np.zeros((0, 2)), None
    if problem is None and (desc is None or len(xy) < config.min_inliers):
        problem = f"reference panorama has only {len(xy)} keypoints"
    az = np.asarray(grid.azimuth_of_column(xy[:, 0]), dtype=np.float64) if len(xy) else np.zeros(0)
    el = np.asarray(grid.elevation_of_row(xy[:, 1]), dtype=np.float64) if len(xy) else np.zeros(0)
    depth = depth_map(reference, grid, config.camera_height_m) if config.parallax_correction else None
    if depth is not None and depth.planar and not config.planar_depth:
        depth = None
    pose = reference.T_world_reference
    pose_depth = depth
    if depth is not None and config.pose_from_bearings and (config.pose_depth_rows, config.pose_depth_cols) != (32, 360):
        pose_depth = depth_map(reference, grid, config.camera_height_m, (config.pose_depth_rows, config.pose_depth_cols))
    depth_points = _lookup(depth, az, el)
    return PreparedCompass(
        grid,
        az,
        el,
        desc,
        pose.theta,
        problem,
        config,
        depth,
        pose,
        pose_depth,
        depth_points,
        depth_points if pose_depth is depth else _lookup(pose_depth, az, el),
        kp.sq_norms(desc) if desc is not None and config.detector == "sift" else None,
    )


def detection_scale(pixels: int, config: CompassConfig) -> float:
    """The scale a query view of ``pixels`` pixels is detected at.

    ``min(1, max(query_scale, √(query_min_detect_px / pixels)))``: never below ``query_min_detect_px`` pixels.
    """
    if pixels <= 0:
        return 1.0
    return float(min(1.0, max(config.query_scale, math.sqrt(config.query_min_detect_px / pixels))))


def query_strips(query: Query, grid: Grid) -> tuple[list[Strip], list[str]]:
    """The query's views reprojected onto ``grid``, and the reasons some were dropped."""
    strips: list[Strip] = []
    dropped: list[str] = []
    for i, image in enumerate(query.images):
        s = camera_strip(image, grid, source=f"images[{i}]")
        if s is None:
            dropped.append(f"images[{i}]: too small on the reference grid")
            continue
        problem = texture_problem(s.gray)
        if problem:
            dropped.append(f"images[{i}]: {problem}")
            continue
        strips.append(s)
    if query.panorama is not None:
        s = panorama_strip(query.panorama, grid)
        if s is None:
            dropped.append("panorama: no rows in common with the reference band")
        else:
            problem = texture_problem(s.gray)
            if problem:
                dropped.append(f"panorama: {problem}")
            else:
                strips.append(s)
    return strips, dropped


def estimate(
    reference: Reference,
    query: Query,
    hypotheses: Hypotheses = Hypotheses(),
    config: CompassConfig = CompassConfig(),
    *,
    prepared: PreparedCompass | None = None,
) -> Estimate:
    """θ2: the robot's world-frame heading from keypoint azimuth votes.

    Parameters
    ----------
    reference
        Must hold a panorama (BGR uint8); ``T_world_reference`` places it.
    query
        Camera images and/or a panorama (BGR uint8).
    hypotheses
        Earlier reliable estimates; :meth:`Hypotheses.heading` seeds the search window.
    config
        The compass configuration.
    prepared
        The result of :func:`prepare` for ``reference`` (computed if None).

    Returns
    -------
    Estimate
        Heading-only, world frame. Unreliable (with a reason, σ = π) when the
        views have no texture or too few consistent pairs.

    Raises
    ------
    InputError
        When the reference has no panorama or the query neither images nor panorama.
    """
    if prepared is None:
        prepared = prepare(reference, config)
    if not query.images and query.panorama is None:
        raise InputError(f"compass needs Query.images or Query.panorama, query {query.id!r} has neither")
    return _estimate(prepared, query, hypotheses, config)


def _seed(hypotheses: Hypotheses, theta_reference_rad: float) -> tuple[float, float, str] | None:
    h = hypotheses.heading()
    if h is None:
        return None
    theta, sigma, step = h
    return float(wrap_angle(theta - theta_reference_rad)), sigma, step


def _unreliable(prepared: PreparedCompass, seed: tuple[float, float, str] | None, check: Check, **diag: Any) -> Estimate:
    """No heading measured: the failed ``check`` that stopped the step, at the seed's heading (or the reference's)."""
    theta = seed[0] if seed is not None else 0.0
    return heading_not_measured(STEP, prepared.theta_reference_rad + theta, check, diag)


def _estimate(prepared: PreparedCompass, query: Query, hypotheses: Hypotheses, config: CompassConfig) -> Estimate:
    """θ2 with the typed :class:`~factorloc.verdicts.SeedEvidence` of what seeded it (heading window, position)."""
    est = _measure(prepared, query, hypotheses, config)
    seed = _seed(hypotheses, prepared.theta_reference_rad)
    windowed = seed is not None and max(config.min_window_rad, config.window_n_sigma * seed[1]) < math.pi
    position = position_seed(hypotheses) if prepared.depth is not None else None
    h, p = hypotheses.heading(), hypotheses.position()
    evidence = SeedEvidence(
        position_step=p[4] if position is not None and p is not None else None,
        heading_step=h[2] if windowed and h is not None else None,
        windowed=windowed,
    )
    return replace(est, seed=evidence)


def _measure(prepared: PreparedCompass, query: Query, hypotheses: Hypotheses, config: CompassConfig) -> Estimate:
    seed = _seed(hypotheses, prepared.theta_reference_rad)
    window = None
    if seed is not None:
        window = max(config.min_window_rad, config.window_n_sigma * seed[1])
        if window >= math.pi:
            window = None
    base = {"window_rad": window, "detector": config.detector}
    if prepared.problem:
        check = Check.flag("compass.reference", "a usable reference panorama", False, failure=f"reference: {prepared.problem}")
        return _unreliable(prepared, seed, check, **base)
    strips, dropped = query_strips(query, prepared.grid)
    if not strips:
        check = Check.flag(
            "compass.query_views", "a usable query view", False, failure="no usable query view: " + "; ".join(dropped)
        )
        return _unreliable(prepared, seed, check, **base)
    det = kp.make_detector(
        config.detector,
        config.n_features_query,
        config.fast_threshold,
        sift_sigma=config.query_sift_sigma,
        octave_layers=config.query_octave_layers,
    )
    az_q_list = []
    desc_list = []
    scales = []
    for s in strips:
        scales.append(detection_scale(s.gray.size, config))
        xy, desc = kp.detect(
            s.gray,
            det,
            wrap_pad_px=min(64, s.width_px // 4) if s.full_circle else 0,
            scale=scales[-1],
            one_per_location=config.one_keypoint_per_location,
        )
        if desc is None or len(xy) == 0:
            continue
        az_q_list.append(np.asarray(s.azimuth_of_column(xy[:, 0]), dtype=np.float64))
        desc_list.append(desc)
    n_query = int(sum(len(a) for a in az_q_list))
    if n_query < config.min_inliers:
        check = Check.at_least("compass.query_keypoints", "query keypoints", n_query, config.min_inliers, Unit.COUNT)
        return _unreliable(prepared, seed, check, query_keypoints=n_query, **base)
    az_q = np.concatenate(az_q_list)
    desc_q = np.concatenate(desc_list)
    az_r, desc_r = prepared.azimuth_rad, prepared.descriptors
    ref_index = np.arange(len(az_r))
    position = position_seed(hypotheses) if prepared.depth is not None else None
    ranges = None
    norms_r = prepared.descriptor_sq_norms
    if position is not None:
        # parallax-free: each reference point's direction as seen from the query position (reference orientation)
        world_dir, ranges = headings_from_points(prepared.depth_points[0], position[0])
        az_r = np.asarray(wrap_angle(world_dir - prepared.theta_reference_rad))
    base["parallax_corrected"] = position is not None
    # a query keypoint is located to about one pixel of the image it was detected in
    pixel_rad = prepared.grid.rad_per_px / min(scales)
    allowed = None
    if window is not None:
        # a reference point is a candidate for a query point when its vote falls in the window widened by
        # the distinctiveness margin: the ratio test then also sees the look-alikes just outside the window
        # (periodic tiles, bricks), and a best match outside the window itself is dropped
        reach = window + config.inlier_band_rad + config.distinct_margin_rad
        used = kp.nearest_circular_distance(np.asarray(wrap_angle(az_r - seed[0])), az_q) <= reach
        az_r, desc_r, ref_index = az_r[used], desc_r[used], ref_index[used]
        norms_r = None if norms_r is None else norms_r[used]
        ranges = None if ranges is None else ranges[used]
    candidates = int(len(az_r))
    if window is not None and config.detector == "sift":
        qi, ri = kp.match_in_window(desc_q, az_q, desc_r, az_r, seed[0], reach, config.ratio, ref_sq_norms=norms_r)
    else:
        if window is not None:
            allowed = kp.circular_abs_diff(az_r, az_q, seed[0]) <= reach
        qi, ri = kp.match(desc_q, desc_r, kp.norm_of(config.detector), config.ratio, allowed, ref_sq_norms=norms_r)
    outside_votes = np.zeros(0)
    if window is not None:
        inside = np.abs(np.asarray(wrap_angle(az_r[ri] - az_q[qi] - seed[0]))) <= window + config.inlier_band_rad
        # best matches beyond the window (within the distinctiveness margin): evidence against the seed
        outside_votes = np.asarray(wrap_angle(az_r[ri[~inside]] - az_q[qi[~inside]]), dtype=np.float64)
        qi, ri = qi[inside], ri[inside]
    diag = dict(base, query_keypoints=n_query, candidates=candidates, matches=int(len(qi)), dropped_views=dropped)
    if len(qi) < 2:
        check = Check.at_least("compass.matches", "matched pairs", len(qi), 2, Unit.COUNT)
        return _unreliable(prepared, seed, check, inliers=0, **diag)
    if config.record_pairs:
        k = ref_index[ri]
        diag["pairs_rad"] = np.column_stack([prepared.azimuth_rad[k], prepared.elevation_rad[k], az_q[qi]]).tolist()
    if prepared.depth is not None and config.pose_from_bearings:
        posed = _pose_from_bearings(prepared, az_q[qi], ref_index[ri], hypotheses, pixel_rad, config, diag)
        if posed is not None:
            return posed
    votes = np.asarray(wrap_angle(az_r[ri] - az_q[qi]), dtype=np.float64)
    theta, inliers, runner_up = kp.vote_consensus(votes, config.inlier_band_rad)
    n_in = int(inliers.sum())
    resid = np.asarray(wrap_angle(votes[inliers] - theta))
    spread = float(np.sqrt(np.mean(resid**2))) if n_in else math.pi
    n_eff = min(n_in, config.max_effective_inliers)
    mode = theta  # the vote mode, before any resection
    shifted = None
    if position is not None and n_in:
        shifted = _position_sensitivity(prepared, az_q[qi], ref_index[ri], position, n_in, config)
    rival, rival_offset = kp.competing_mode(votes, mode, config.inlier_band_rad)
    outside, outside_offset = kp.competing_mode(np.concatenate([votes, outside_votes]), mode, config.inlier_band_rad)
    if position is not None and n_in:
        displacement = float(np.hypot(*(np.asarray(position[0]) - prepared.depth.T_world_reference.translation)))
        sigma_par = math.hypot(parallax_sigma(position[1], ranges[ri[inliers]]), config.depth_sigma_rad_per_m * displacement)
    else:
        sigma_par = uncorrected_parallax_sigma(
            hypotheses,
            prepared.depth,
            prepared.reference_pose or Pose2(0.0, 0.0, prepared.theta_reference_rad),
            az_r[ri[inliers]],
            config.unknown_position_sigma_m,
            config.default_range_m,
        )
    bound, bound_k = math.inf, math.inf
    if config.parallax_from_spread and n_in >= config.min_inliers:
        # the parallax a displacement leaves in the mode is bounded by what it leaves in the residuals
        bound, bound_k = spread_parallax_bound(
            az_r[ri[inliers]], resid, n_effective=n_eff, confidence=config.spread_confidence, band_rad=config.inlier_band_rad
        )
        bound *= config.spread_bound_gain
        sigma_par = min(sigma_par, bound)
    # spread of the inliers, a cluster term (a few coincident votes locate the mode only to about band/√n),
    # the floor, and the parallax term
    sigma_cluster = config.inlier_band_rad / math.sqrt(max(n_eff, 1))
    sigma = math.sqrt(spread**2 / max(n_eff - 1, 1) + sigma_cluster**2 + config.sigma_floor_rad**2 + sigma_par**2)
    sigma = max(sigma, prepared.grid.rad_per_px)
    resected = None
    if position is not None and config.resection and n_in >= config.min_inliers:
        k = ref_index[ri[inliers]]
        resected = resect(
            prepared.depth,
            prepared.azimuth_rad[k],
            prepared.elevation_rad[k],
            az_q[qi[inliers]],
            Pose2(position[0][0], position[0][1], prepared.theta_reference_rad + theta),
            position[1],
            pixel_rad,
            config,
            lookup=tuple(a[k] for a in prepared.depth_points),
        )
        if resected is not None:
            # the inliers were chosen with votes corrected from the *hypothesised* position: when that is off,
            # true pairs fall out of the band and the rest is a biased subset. Choose them again with votes
            # corrected from the resected position, and resect once more (same prior).
            k_all = ref_index[ri]
            world_vote, _ = headings_from_points(prepared.depth_points[0][k_all], resected[2], az_q[qi])
            again = np.abs(wrap_angle(world_vote - resected[0])) <= config.inlier_band_rad
            if int(again.sum()) >= config.min_inliers and np.any(again != inliers):
                k = ref_index[ri[again]]
                second = resect(
                    prepared.depth,
                    prepared.azimuth_rad[k],
                    prepared.elevation_rad[k],
                    az_q[qi[again]],
                    Pose2(position[0][0], position[0][1], resected[0]),
                    position[1],
                    pixel_rad,
                    config,
                    lookup=tuple(a[k] for a in prepared.depth_points),
                )
                if second is not None:
                    resected, inliers = second, again
                    n_in = int(inliers.sum())
            theta = float(wrap_angle(resected[0] - prepared.theta_reference_rad))
            # no cluster term: the resection's own noise model covers the bearings (pixel, range σ incl. depth edges)
            # and its jackknife their leverage (with the term: heading NEES 0.31 on simulated views, 0.49 without)
            sigma = math.sqrt(resected[1] ** 2 + config.sigma_floor_rad**2)
            sigma = max(sigma, prepared.grid.rad_per_px)
            diag["resection_position_m"] = [resected[2][0], resected[2][1]]
    ambiguity = runner_up / n_in if n_in else 1.0
    # a competing mode that is not distinctive enough to be ignored: θ2 is a two-mode mixture, and its σ must cover
    # the separation (repeated textures put look-alike modes a period away; a tight cluster is no proof)
    span = 2.0 * math.pi if window is None else 2.0 * (window + config.inlier_band_rad)
    # the rival counts itself; a stray vote or two among the unmatched pairs (λ expected per band) is no mode
    background = (len(qi) - n_in) * min(1.0, 2.0 * config.inlier_band_rad / span)
    significant = rival >= max(3.0, background + 3.0 * math.sqrt(background) + 1.0)
    excess = max(rival - background - 1.0, 0.0) if significant else 0.0
    p_rival = excess / (n_in + excess) if n_in else 1.0
    sigma_rival = config.rival_sigma_weight * math.sqrt(p_rival * (1.0 - p_rival)) * abs(rival_offset)
    sigma = math.hypot(sigma, sigma_rival)
    diag.update(
        inliers=n_in,
        inlier_ratio=n_in / len(qi),
        spread_rad=spread,
        sigma_parallax_rad=sigma_par,
        parallax_bound_rad=bound,
        parallax_bound_k=bound_k,
        ambiguity=ambiguity,
        rival_support=rival,
        rival_offset_rad=rival_offset,
        sigma_rival_rad=sigma_rival,
        outside_matches=int(len(outside_votes)),
        extended_rival_support=outside,
        extended_rival_offset_rad=outside_offset,
        position_shift_mode=None if shifted is None else list(shifted),
        mode_seed_gap_rad=None if window is None else abs(float(wrap_angle(mode - seed[0]))),
        theta_relative_rad=theta,
    )
    votes_seen = VoteEvidence(n_in, len(qi), runner_up, outside, outside_offset, shifted)
    theta_world = prepared.theta_reference_rad + theta
    est = Estimate.heading(STEP, theta_world, sigma, reliable=False, diagnostics=diag)
    seed_check = heading_seed_check(STEP, theta_world, sigma, hypotheses.heading(), config.seed_consistency_n_sigma)
    checks = (
        heading_checks(votes_seen, theta, sigma, config)
        + (() if seed_check is None else (seed_check,))
        + sigma_checks(est, max_sigma_heading_rad=config.max_sigma_rad)
    )
    if all(c.passed for c in checks):
        return est.with_verdict(True, f"{n_in} inlier pairs of {len(qi)} matches", checks)
    return est.with_verdict(False, render_checks(checks), checks)


@dataclass(frozen=True)
class VoteEvidence:
    """What the heading-only compass's rules read about its vote (:func:`heading_checks`): the inlier pairs of the
    mode and the matched pairs; the runner-up mode's support; the strongest mode with the best matches just beyond a
    seeded window (support, offset from the mode, rad); the re-vote from positions around the hypothesis
    (``(mode_rad, support, offset_m)`` or None)."""

    n_inliers: int
    n_matches: int
    runner_up: int
    outside: int
    outside_offset_rad: float
    shifted: tuple[float, int, float] | None


def _ambiguity_note(ambiguity: float, limit: float, runner_up: int, n_inliers: int) -> str:
    """The words of a failed ambiguity rule ("" when it passed); at the limit itself, that the limit fails."""
    if ambiguity < limit:
        return ""
    at_limit = " (at the limit, which fails)" if ambiguity == limit else ""
    return f"ambiguous: a second vote mode has {runner_up} pairs vs {n_inliers}{at_limit}"


def heading_checks(ev: VoteEvidence, theta_rad: float, sigma_rad: float, config: CompassConfig) -> tuple[Check, ...]:
    """The rules of the heading-only compass (θ2 from the vote mode, the patent's compass), in the order they apply:

    * ``compass.inliers``, ``compass.inlier_ratio``: at least ``min_inliers`` pairs in the mode, at least
      ``min_inlier_ratio`` of the matched pairs (the patent's ≥ 2 pairs, with margin);
    * ``compass.ambiguity``: a second vote mode holds less than ``max_ambiguity`` of the mode's support;
    * ``compass.distinct``: no stronger mode with the best matches just beyond a seeded window, more than three
      bands away (a wrong seed "confirmed" by a look-alike inside its window);
    * ``compass.position_shift`` (with a position hypothesis, when a re-vote from within ±2σ of it reaches
      ``position_shift_support`` of the support): that mode within 3σθ2 of θ2.

    The shared rules follow them: ``compass.seed_consistency`` (with a heading seed,
    :func:`~factorloc.estimators.base.heading_seed_check`) and the σ rule (``compass.sigma_heading``,
    :func:`~factorloc.estimators.base.sigma_checks`).
    """
    n_in = ev.n_inliers
    ambiguity = ev.runner_up / n_in if n_in else 1.0
    checks = [
        Check.at_least("compass.inliers", "inlier pairs", n_in, config.min_inliers, Unit.COUNT),
        Check.at_least("compass.inlier_ratio", "inlier ratio", n_in / ev.n_matches, config.min_inlier_ratio, Unit.FRACTION),
        # fails at the limit itself (a second mode as strong as the limit allows is already ambiguous)
        Check(
            "compass.ambiguity",
            "second vote mode's support over the mode's",
            ambiguity < config.max_ambiguity,
            ambiguity,
            config.max_ambiguity,
            Comparison.AT_MOST,
            Unit.FRACTION,
            _ambiguity_note(ambiguity, config.max_ambiguity, ev.runner_up, n_in),
        ),
    ]
    stronger = (
        ev.outside >= config.max_outside_ambiguity * max(n_in, 1) and abs(ev.outside_offset_rad) > 3.0 * config.inlier_band_rad
    )
    checks.append(
        Check.flag(
            "compass.distinct",
            "no stronger vote mode just beyond the seeded window",
            not stronger,
            failure=f"a stronger vote mode ({ev.outside} pairs vs {n_in}) {math.degrees(ev.outside_offset_rad):+.1f}° away, "
            "beyond the seeded window",
        )
    )
    shifted = ev.shifted
    if shifted is not None and shifted[1] >= config.position_shift_support * n_in:
        checks.append(
            Check.at_most(
                "compass.position_shift",
                f"gap to the mode of {shifted[1]} pairs re-voted from a position {shifted[2]:.2f} m off the hypothesis",
                abs(float(wrap_angle(shifted[0] - theta_rad))),
                3.0 * sigma_rad,
                Unit.RADIAN,
                note="3σθ2",
            )
        )
    return tuple(checks)


def _pose_from_bearings(
    prepared: PreparedCompass,
    az_query_rad: np.ndarray,
    ref_index: np.ndarray,
    hypotheses: Hypotheses,
    pixel_rad: float,
    config: CompassConfig,
    diag: dict[str, Any],
) -> Estimate | None:
    """The robot's pose (x, y, θ) resected from the matched pairs' bearings, when every pose check passes.

    *Beyond the patent.* Each pair is a bearing ``az_query`` (query robot frame) to the world point behind the
    reference keypoint (:meth:`DepthMap.world_points`). RANSAC over minimal 3-bearing sets, then weighted
    Gauss–Newton (:mod:`factorloc.vision.resection`): a bearing's relative variance is
    ``pixel² + (σ_D sin Δ / r)²`` (a range error σ_D along the reference ray, seen at angle Δ from range r;
    σ_D as in :func:`resect`), the covariance ``σ̂² (JᵀWJ)⁻¹`` from the residuals' own variance, plus the
    heading floor ``sigma_floor_rad`` and the position floor ``pose_sigma_floor_m``.
    Returns None (the heading-only path then runs) when the pose fails a check; the failed checks are put in
    ``diag["pose_rejected"]`` (only the inlier checks when they fail: the refinement is then skipped).
    """
    from factorloc.vision import resection as rs

    depth = prepared.pose_depth or prepared.depth
    az_ref = prepared.azimuth_rad[ref_index]
    pts, ranges_ref, spread_ref = (a[ref_index] for a in prepared.pose_points)
    fit = rs.ransac(
        pts,
        az_query_rad,
        config.pose_threshold_rad,
        hypotheses=config.pose_hypotheses,
        min_inliers=3,
    )
    if fit is None:
        diag["pose_rejected"] = "no pose fits three bearings"
        return None
    inl = fit.inliers
    n_in = fit.n_inliers
    checks = [
        Check.at_least("compass.pose.inliers", "resection inliers", n_in, config.min_pose_inliers, Unit.COUNT),
        Check.at_least(
            "compass.pose.inlier_ratio", "resection inlier ratio", n_in / len(inl), config.min_inlier_ratio, Unit.FRACTION
        ),
    ]
    if not all(c.passed for c in checks):
        # too few bearings agree: no refinement could pass (the two checks only read the RANSAC inliers)
        failed = [c for c in checks if not c.passed]
        diag.update(pose_inliers=n_in, pose_runner_up=fit.runner_up, pose_rejected=render_checks(failed))
        return None
    sigma_range = np.maximum(config.depth_relative_sigma * ranges_ref, 0.5 * spread_ref)
    az_ref_world = depth.T_world_reference.theta + az_ref
    d = pts - np.array([fit.pose.x, fit.pose.y])
    r = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-6)
    sin_delta = np.abs(np.cos(az_ref_world) * d[:, 1] - np.sin(az_ref_world) * d[:, 0]) / r
    weights = pixel_rad**2 / (pixel_rad**2 + (sigma_range * sin_delta / r) ** 2)
    groups = _groups(pts, config.pose_group_m)
    final = rs.refine(
        pts[inl],
        az_query_rad[inl],
        fit.pose,
        weights=weights[inl],
        sigma_floor_rad=config.pose_residual_floor_px * pixel_rad,
        jackknife=True,
        groups=groups[inl],
    )
    if final is None:
        checks.append(Check.flag("compass.pose.solvable", "resection solvable", False, failure="singular resection"))
    else:
        cov = np.array(final.covariance)
        leverage, extra = _group_leverage(pts[inl], final.pose, weights[inl], cell_m=config.pose_group_m)
        s_res = max(final.residual_sigma_rad, config.pose_residual_floor_px * pixel_rad)
        with np.errstate(invalid="ignore", over="ignore"):
            cov = cov + s_res**2 * extra  # no direction trusted beyond what the other groups verify (inf: unverifiable)
        if not np.all(np.isfinite(cov)):
            cov = np.diag([1e6, 1e6, math.pi**2])  # rests on one group alone: fails the σ checks below
        cov_fit = cov.copy()  # the resection's own, before the floors: what the same-spot test reads
        cov[:2, :2] += np.eye(2) * config.pose_sigma_floor_m**2
        cov[2, 2] += config.sigma_floor_rad**2
        sigma_pos = float(math.sqrt(np.linalg.eigvalsh(cov[:2, :2])[-1]))
        sigma_theta = float(math.sqrt(cov[2, 2]))
        checks += [
            # a condition number of a 3×3 normal matrix: rounding moves it by ~1e-12 relative
            Check.at_most(
                "compass.pose.condition",
                "resection condition number",
                final.condition,
                config.max_pose_condition,
                tolerance=1e-9 * config.max_pose_condition,
            ),
            Check.at_most(
                "compass.pose.residual",
                "resection residual σ",
                final.residual_sigma_rad,
                config.max_pose_residual_rad,
                Unit.RADIAN,
            ),
            Check.at_most("compass.pose.sigma_position", "σ position", sigma_pos, config.max_pose_sigma_position_m, Unit.METRE),
            Check.at_most("compass.pose.sigma_heading", "σ heading", sigma_theta, config.max_sigma_rad, Unit.RADIAN),
            Check.at_most(
                "compass.pose.ambiguity", "rival pose support", fit.runner_up / n_in, config.max_pose_ambiguity, Unit.FRACTION
            ),
        ]
        diag["pose_group_leverage"] = leverage
        p = hypotheses.position()
        if p is not None:
            delta = np.array([final.pose.x - p[0], final.pose.y - p[1]])
            s = cov[:2, :2] + np.diag([p[2] ** 2, p[3] ** 2])
            d2 = float(delta @ np.linalg.solve(s, delta))
            checks.append(
                Check.at_most(
                    "compass.pose.seed_position",
                    f"d² from the {p[4]} position",
                    d2,
                    config.pose_seed_consistency_d2,
                    Unit.SQUARED,
                )
            )
        h = hypotheses.heading()
        if h is not None:
            gap = abs(float(wrap_angle(final.pose.theta - h[0])))
            checks.append(
                Check.at_most(
                    "compass.pose.seed_heading",
                    f"gap to the {h[2]} heading",
                    gap,
                    config.seed_consistency_n_sigma * math.hypot(sigma_theta, h[1]),
                    Unit.RADIAN,
                )
            )
    q = pts[inl] - pts[inl].mean(axis=0)
    minor_m = float(math.sqrt(max(np.linalg.eigvalsh(q.T @ q / max(len(q), 1))[0], 0.0)))
    span = float(np.ptp(np.unwrap(np.sort(az_query_rad[inl])))) if n_in else 0.0
    diag.update(
        pose_minor_spread_m=minor_m,
        pose_span_rad=span,
        pose_inliers=n_in,
        pose_runner_up=fit.runner_up,
        pose_resection=[final.pose.x, final.pose.y, final.pose.theta] if final is not None else None,
        pose_condition=None if final is None else final.condition,
        pose_residual_rad=None if final is None else final.residual_sigma_rad,
    )
    failed = [c for c in checks if not c.passed]
    if failed:
        diag["pose_rejected"] = render_checks(failed)
        return None
    d2_ref, sigma_fit, at_ref = _at_reference(
        pts[inl], az_query_rad[inl], weights[inl], final.pose, cov_fit, depth.T_world_reference, config
    )
    diag.update(same_spot_d2=d2_ref, same_spot_sigma_m=sigma_fit, at_reference=at_ref is not None)
    pose = final.pose if at_ref is None else at_ref
    displacement = float(np.hypot(final.pose.x - depth.T_world_reference.x, final.pose.y - depth.T_world_reference.y))
    diag.update(
        inliers=n_in,
        inlier_ratio=n_in / len(inl),
        displacement_m=displacement,
        theta_relative_rad=float(wrap_angle(pose.theta - prepared.theta_reference_rad)),
    )
    if config.pose_needs_position_seed and hypotheses.position() is None:
        # nothing corroborates the position: a look-alike texture a translation away (the same picture on another
        # wall) fits the bearings as well as the truth, with the heading unchanged. Keep the heading marginal.
        reason = f"heading of a pose from {n_in} bearings of {len(inl)} matches (no position hypothesis to check its position)"
        return Estimate.heading(
            STEP, pose.theta, sigma_theta, reliable=True, reason=reason, diagnostics=diag, checks=tuple(checks)
        )
    if at_ref is not None:
        where = f"at the reference: {displacement * 100:.1f} cm away, d² {d2_ref:.2f}"
    else:
        where = f"{displacement:.2f} m from the reference"
    reason = f"pose from {n_in} bearings of {len(inl)} matches ({where})"
    return Estimate.pose(STEP, pose, covariance=cov, reliable=True, reason=reason, diagnostics=diag, checks=tuple(checks))


def _at_reference(
    points_xy_m: np.ndarray,
    bearings_rad: np.ndarray,
    weights: np.ndarray,
    pose: Pose2,
    cov_fit: np.ndarray,
    T_world_reference: Pose2,
    config: CompassConfig,
) -> tuple[float, float, Pose2 | None]:
    """Whether the resected bearings say the robot stands at the reference's spot, and the pose if they do.

    A nested-model test (Wald): ``d² = Δᵀ Σ⁻¹ Δ`` with ``Δ`` the resected position (world, m) minus the
    reference's and ``Σ`` the resection's position covariance before its floors (``cov_fit``). When
    ``d² ≤ same_spot_max_d2`` and Σ's largest σ is at most ``same_spot_max_sigma_m``, the position is fixed at
    the reference and the heading re-estimated there: with the position known the bearing residuals are
    linear in θ, so the weighted least-squares heading is the ``weights``-weighted mean of the inliers' votes
    (world azimuth of each point from the reference minus its query bearing), taken about the resected heading.
    Returns ``(d², Σ's largest σ (m), Pose2 or None)``; ``d²`` is inf when ``Σ`` is singular (its smallest
    eigenvalue at most ``ROUNDING_TOLERANCE`` of its trace). The covariance the compass emits
    stays the resection's: the restricted heading differs from the resected one by ``K Δ`` (``K = Σ_θp Σ_pp⁻¹``),
    at most ``√d²`` times the part of the heading's σ that the position explains (``√(Σ_θθ − Σ_θθ|p)``), so
    within 2.45 σ at the default. Beyond the patent (its compass gives θ only, with no position to test).
    """
    if config.same_spot_max_d2 is None:
        return math.nan, math.nan, None
    s_pos = cov_fit[:2, :2]
    sigma_max = largest_sigma(s_pos)
    # Σ is a covariance: positive definite unless the fit left a direction unobserved (then d² is inf)
    scale = float(np.trace(s_pos))
    if not (math.isfinite(scale) and scale > 0.0) or smallest_sigma(s_pos) ** 2 <= ROUNDING_TOLERANCE * scale:
        return math.inf, sigma_max, None
    d2 = mahalanobis_sq_2d(np.array([pose.x - T_world_reference.x, pose.y - T_world_reference.y]), s_pos)
    # only a resection that locates the robot well can say "here": a loose one (σ of decimetres) cannot refuse a
    # spot half a metre away (seed 41's q0063: d² 5.2 at 0.49 m, σ 0.2 m)
    if d2 > config.same_spot_max_d2 or sigma_max > config.same_spot_max_sigma_m:
        return d2, sigma_max, None
    votes = np.arctan2(points_xy_m[:, 1] - T_world_reference.y, points_xy_m[:, 0] - T_world_reference.x) - bearings_rad
    offset = np.asarray(wrap_angle(votes - pose.theta), dtype=np.float64)
    theta = float(wrap_angle(pose.theta + float(np.sum(weights * offset) / np.sum(weights))))
    return d2, sigma_max, Pose2(T_world_reference.x, T_world_reference.y, theta)


def _group_leverage(points_xy_m: np.ndarray, pose: Pose2, weights: np.ndarray, *, cell_m: float) -> tuple[float, np.ndarray]:
    """The dominant group of bearings: its share of the pose's information, and what the covariance lacks without it.

    The groups are the points' cells on four grids of ``cell_m`` offset by half a cell in x, in y and in both, so
    that any cluster smaller than half a cell in each direction falls whole into one cell of at least one grid: a
    near object whose false matches straddle a cell boundary does not split into two groups that hide each other
    (``docs/calibration/vision.md``). With ``H = Σ_g H_g`` the weighted normal matrix of the bearings at ``pose``
    (unit σ, for each grid), the group ``g*`` of the largest ``λ_max(H^-½ H_g H^-½)`` over the four grids (its share
    of the information in some direction, in [0, 1]) is returned with ``(H − H_g*)⁻¹ − H⁻¹`` (PSD; infinite when
    the rest is singular): added (× σ²) to the covariance, the pose is as uncertain in every direction as the other
    groups alone make it — a direction that rests on one group is not trusted beyond what the others verify.
    """
    d = points_xy_m - np.array([pose.x, pose.y])
    r2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-12)
    jac = np.column_stack([d[:, 1] / r2, -d[:, 0] / r2, -np.ones(len(d))])
    outer = weights[:, None, None] * jac[:, :, None] * jac[:, None, :]
    h = outer.sum(axis=0)
    w, v = np.linalg.eigh(h)
    if w[0] <= 0.0:
        return 1.0, np.full((3, 3), np.inf)
    s = v @ np.diag(w**-0.5) @ v.T
    best_share, best_h = -1.0, None
    for off in ((0.0, 0.0), (0.5, 0.0), (0.0, 0.5), (0.5, 0.5)):
        labels = _groups(points_xy_m + np.array(off) * cell_m, cell_m)
        uniq, inverse = np.unique(labels, return_inverse=True)
        gh = np.zeros((len(uniq), 3, 3))
        np.add.at(gh, inverse.ravel(), outer)
        shares = np.linalg.eigvalsh(s[None] @ gh @ s[None])[:, -1]
        g = int(np.argmax(shares))
        if shares[g] > best_share:
            best_share, best_h = float(shares[g]), gh[g]
    rest = h - best_h
    wr = np.linalg.eigvalsh(rest)
    if wr[0] <= 1e-12 * w[-1]:
        return float(np.clip(best_share, 0.0, 1.0)), np.full((3, 3), np.inf)
    with np.errstate(invalid="ignore", over="ignore"):
        extra = np.linalg.inv(rest) - np.linalg.inv(h)
    return float(np.clip(best_share, 0.0, 1.0)), 0.5 * (extra + extra.T)


def _groups(points_xy_m: np.ndarray, cell_m: float) -> np.ndarray:
    """Integer labels of the world grid cells (``cell_m``) the points fall in."""
    cells = np.floor(points_xy_m / cell_m).astype(np.int64)
    if not len(cells):
        return np.zeros(0, dtype=np.int64)
    # one integer per cell, in the cells' lexicographic (x, then y) order: the labels np.unique(cells, axis=0)
    # gives, without its row-wise (structured) sort
    lo = cells.min(axis=0)
    span_y = int(cells[:, 1].max() - lo[1]) + 1
    _, labels = np.unique((cells[:, 0] - lo[0]) * span_y + (cells[:, 1] - lo[1]), return_inverse=True)
    return labels.ravel()


def _position_sensitivity(
    prepared: PreparedCompass,
    az_query_rad: np.ndarray,
    ref_index: np.ndarray,
    position: tuple[tuple[float, float], float],
    n_inliers: int,
    config: CompassConfig,
) -> tuple[float, int, float] | None:
    """The strongest vote mode over positions within ±2σ of the position hypothesis, when it beats the seed's.

    The matched pairs are re-voted with parallax corrected from each point of a
    5×5 grid (steps of σ_p) around the hypothesised position. Returns
    ``(theta_relative_rad, support, shift_m)`` of the grid point whose mode has more
    support than ``n_inliers`` (the mode at the hypothesis), or None.
    """
    (x0, y0), sigma_p = position
    pts = prepared.depth_points[0][ref_index]
    steps = sigma_p * np.arange(-2.0, 2.5, 1.0)
    dx, dy = (g.ravel() for g in np.meshgrid(steps, steps, indexing="ij"))
    off = (dx != 0.0) | (dy != 0.0)
    dx, dy = dx[off], dy[off]  # 24 grid points, all pairs re-voted at once
    bearing = np.arctan2(pts[None, :, 1] - (y0 + dy)[:, None], pts[None, :, 0] - (x0 + dx)[:, None])
    votes = np.asarray(wrap_angle(bearing - prepared.theta_reference_rad - az_query_rad[None, :]))
    support = kp.support_rows(votes, config.inlier_band_rad)
    # only grid points whose densest vote beats the hypothesis' inliers can win: refine those (the mode's inliers
    # after refinement may differ from the raw support by a vote or two)
    best = None
    for g in np.flatnonzero(support.max(axis=1) > n_inliers):
        theta, inl, _ = kp.vote_consensus(votes[g], config.inlier_band_rad)
        n = int(inl.sum())
        if n > n_inliers and (best is None or n > best[1]):
            best = (theta, n, float(math.hypot(dx[g], dy[g])))
    return best


def resect(
    depth: DepthMap,
    az_ref_rad: np.ndarray,
    el_ref_rad: np.ndarray,
    az_query_rad: np.ndarray,
    T_world_seed: Pose2,
    sigma_position_m: float,
    pixel_rad: float,
    config: CompassConfig,
    *,
    lookup: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[float, float, tuple[float, float]] | None:
    """Heading (and position) from bearings to known points, with a position prior (Gauss–Newton).

    Model: the query at world ``(x, y)`` with heading θ sees the reference point
    ``P_i`` (from ``depth``) at robot azimuth ``az_query_i``:
    ``atan2(P_i,y − y, P_i,x − x) − θ = az_query_i + ε_i``, with
    ``σ(ε_i)² = pixel² + (σ_D,i · sin Δ_i / r_i)²`` (a range error σ_D,i along the reference ray,
    seen from the query at angle Δ_i and range r_i; ``σ_D = max(depth_relative_sigma · D_i, ½ spread_i)``
    with ``spread_i`` the depth map's range spread around the point, large at depth edges), and the
    prior ``(x, y) ~ N(seed, σ_p² I)``. Bearings further than 3σ from the solution are
    dropped once. The measurement information is scaled by
    ``min(1, max_effective_inliers / n)`` (correlated errors). The heading's σ is the larger of
    the posterior's and the jackknife's (leave-one-bearing-out, linearized at the solution):
    a few bearings with high leverage (one far point among many on one wall) are otherwise
    trusted beyond what their scatter supports. ``lookup``: the bearings' world points, ranges and range
    spreads when already looked up (:attr:`PreparedCompass.depth_points` indexed), else read from ``depth``.

    Returns
    -------
    (theta_world_rad, sigma_theta_rad, (x_m, y_m)) or None
        None when fewer than ``min_inliers`` bearings remain or the system is singular.
    """
    pts, ranges_ref, spread_ref = depth.lookup(az_ref_rad, el_ref_rad) if lookup is None else lookup
    # a range's σ: relative, or half the range spread around it where the coarse map has a depth edge
    sigma_range = np.maximum(config.depth_relative_sigma * ranges_ref, 0.5 * spread_ref)
    az_ref_world = depth.T_world_reference.theta + np.asarray(az_ref_rad)
    ref_dir = np.column_stack([np.cos(az_ref_world), np.sin(az_ref_world)])
    prior = np.array([T_world_seed.x, T_world_seed.y])
    state = np.array([T_world_seed.x, T_world_seed.y, T_world_seed.theta])
    keep = np.ones(len(pts), dtype=bool)
    info_prior = np.diag([1.0 / sigma_position_m**2, 1.0 / sigma_position_m**2, 0.0])
    for it in range(8):
        d = pts - state[:2]
        r2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-6)
        r = np.sqrt(r2)
        bearing = np.arctan2(d[:, 1], d[:, 0])
        res = np.asarray(wrap_angle(bearing - state[2] - az_query_rad))
        sin_delta = np.abs(ref_dir[:, 0] * d[:, 1] - ref_dir[:, 1] * d[:, 0]) / r
        var = pixel_rad**2 + (sigma_range * sin_delta / r) ** 2
        if it == 4:  # drop outlying bearings once, then re-converge
            keep &= np.abs(res) <= 3.0 * np.sqrt(var)
        n = int(keep.sum())
        if n < config.min_inliers:
            return None
        jac = np.column_stack([d[:, 1] / r2, -d[:, 0] / r2, -np.ones(len(d))])
        w = keep / var * min(1.0, config.max_effective_inliers / n)
        h = (jac * w[:, None]).T @ jac + info_prior
        g = (jac * w[:, None]).T @ res + info_prior @ np.append(state[:2] - prior, 0.0)
        try:
            step = np.linalg.solve(h, -g)
        except np.linalg.LinAlgError:
            return None
        state = state + step
        if np.all(np.abs(step) < 1e-7):
            break
    try:
        cov = np.linalg.inv(h)  # the normal matrix of the last step (as the covariance was before the loop ended)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(cov)) or cov[2, 2] <= 0.0:
        return None
    var_theta = float(cov[2, 2])
    # jackknife: the heading's change when one bearing is left out (one Gauss–Newton step from the solution,
    # Δ_i = (H − w_i J_iᵀJ_i)⁻¹ J_iᵀ w_i r_i). Few bearings on one wall plus a far one with a bad range give a
    # confident but wrong solution that the curvature H does not reveal; their influence does.
    idx = np.flatnonzero(keep)
    if idx.size >= 3:
        ji, wi, ri = jac[idx], w[idx], res[idx]
        h_loo = h[None, :, :] - wi[:, None, None] * ji[:, :, None] * ji[:, None, :]
        try:
            delta = np.linalg.solve(h_loo, (ji * (wi * ri)[:, None])[:, :, None])[:, :, 0]
            var_theta = max(var_theta, (idx.size - 1) / idx.size * float(np.sum(delta[:, 2] ** 2)))
        except np.linalg.LinAlgError:
            pass
    return float(wrap_angle(state[2])), float(math.sqrt(var_theta)), (float(state[0]), float(state[1]))


class CompassStep:
    """The virtual compass as a pipeline step (needs a reference panorama and query images or panorama)."""

    name = STEP

    def __init__(self, config: CompassConfig = CompassConfig()) -> None:
        self.config = config

    def prepare(self, reference: Reference) -> PreparedCompass | None:
        if reference.panorama is None:
            return None
        return prepare(reference, self.config)

    def estimate(self, prepared: PreparedCompass | None, query: Query, hypotheses: Hypotheses) -> Estimate | None:
        if prepared is None or (not query.images and query.panorama is None):
            return None
        return _estimate(prepared, query, hypotheses, self.config)
