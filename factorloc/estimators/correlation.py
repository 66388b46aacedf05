"""Step 3 of the hierarchy: panorama correlation → θ3 and scale (WO 2015/158682, step 204, claim 6).

The query's views are reprojected onto the reference panorama's grid
(:mod:`factorloc.vision.strips`), where a heading θ is a horizontal shift.
Each view is correlated (zero-mean normalized cross-correlation, OpenCV
``TM_CCOEFF_NORMED``, horizontally periodic: :mod:`factorloc.vision.ncc`)
against the reference over two image pyramids, as in claim 6:

* the reference downscaled in ``pyramid_steps`` steps of ``pyramid_ratio``,
  each level correlated with the full-size query (scale ``s = ratioᵏ < 1``:
  the robot is further from what it sees than the reference was), and
* the query downscaled in the same steps, each level correlated with the
  full-size reference (``s = ratio⁻ᵏ > 1``: the robot moved towards it).

Pyramid level ``m ∈ [−n, n]`` thus hypothesises the scale ``s = ratio⁻ᵐ``. For
each level the views' correlation curves (best vertical offset per shift,
in a band around the horizon) are resampled onto one heading axis and
averaged (weights: template areas). The best (level, heading) gives θ3,
refined to sub-pixel by a parabola through the peak and its neighbours; the
scale is refined by a parabola in ``log s`` over the neighbouring levels.

σθ3 from the peak's sharpness: with peak value ``ρ`` and curvature ``κ``
(per pixel² of the level), ``σ = max(sigma_gain·√((1 − ρ)/κ)·Δ, Δ)`` where
``Δ`` is the angle of one pixel at the chosen level (never below it).
Reliability: ``ρ ≥ min_peak`` (the patent's Ct), the best separated
secondary peak at least ``ambiguity_margin`` below ``ρ``, ``σ ≤ max_sigma_rad``,
and (seeded) the peak not on the edge of the searched window.

Seeded by the latest reliable heading θ̂ ± σ̂ (θ2, else θ1) the search is
limited to ``θ̂ ± max(min_window_rad, window_n_sigma·σ̂)``; without a seed the
whole panorama is searched. The world-frame heading is
``T_world_reference.theta + θ``.

Parallax (an extension of the patent): a query away from the reference sees
near surfaces turned by up to ``atan(d/D)``. When the reference carries a
cloud or a scan and a position hypothesis exists, the reference is first
re-rendered from the hypothesised position (:mod:`factorloc.vision.synth`; with a
heading seed only the columns the seeded window can reach),
the pyramids are then skipped (the warp already applies each column's
magnification; small residual scales only blur the peak, and small templates
of the coarse levels matched by chance), and σ gains the position's ``σ_p / range`` and a warp model term
growing with the displacement; the reported ``scale`` is then the residual
scale times the warp's magnification (``scale_residual`` holds the former).
Without a position hypothesis the query is assumed within
``unknown_position_sigma_m`` of the reference and σ covers that parallax.

Calibration (measured, left as is): θ3's NEES (1 dof) over its reliable estimates is 0.69 / 0.73 on the held-out
scenarios ``factorloc simulate --world apartment --queries 300 --seed 11`` / ``--seed 23``, but its errors
correlate with θ2's at 0.88 / 0.92 (same images, same position hypothesis) and the pair fused as independent has
NEES 1.58 / 1.35; see :mod:`factorloc.estimators.compass`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from factorloc.errors import ConfigError, InputError
from factorloc.estimators.base import Hypotheses, heading_not_measured, heading_seed_check, sigma_checks
from factorloc.estimators.compass import query_strips
from factorloc.geometry import Pose2, wrap_angle
from factorloc.types import Estimate, Query, Reference
from factorloc.verdicts import Check, Comparison, SeedEvidence, Unit, render_checks
from factorloc.vision.depth import DepthMap, depth_map, parallax_sigma, position_seed, uncorrected_parallax_sigma
from factorloc.vision.ncc import correlate_wrapped, parabolic_peak
from factorloc.vision.strips import Grid, Strip, texture_problem, to_gray
from factorloc.vision.synth import horizon_points, synthesize, wrap_padded

log = logging.getLogger(__name__)

STEP = "correlation"


@dataclass(frozen=True)
class CorrelationConfig:
    """Configuration of the panorama correlation (angles in radians).

    Parameters
    ----------
    pyramid_steps
        Downscaling steps of each pyramid (0 = plain correlation at scale 1).
    pyramid_ratio
        Downscaling ratio per step, in (0, 1).
    min_peak
        The threshold Ct in [−1, 1] the peak correlation must reach.
    ambiguity_margin, ambiguity_noise_gain
        Ambiguous (unreliable) when a separated secondary peak is within
        ``ambiguity_margin + ambiguity_noise_gain·(1 − peak)`` of the best peak (a weak peak
        is noisy, so it must stand out more).
    window_n_sigma, min_window_rad
        Seeded search half-window ``max(min_window_rad, window_n_sigma·σ)``.
    max_sigma_rad
        Unreliable above this σθ3.
    sigma_gain
        Multiplies the curvature-based σ (calibrated so that errors are ≈ σ).
    warp_sigma_rad_per_m
        Model error of the parallax-removing warp per metre between the hypothesised
        position and the reference (coarse depth, non-vertical surfaces), added to σ.
    unknown_position_sigma_m, default_range_m
        The parallax σ when it cannot be removed, as for the compass
        (:func:`factorloc.vision.depth.uncorrected_parallax_sigma`).
    seed_consistency_n_sigma
        Unreliable when θ3 is further than this many combined σ from the seed heading
        (a second alignment inside the window beat the true one).
    vertical_search_frac
        Vertical offsets searched around the horizon alignment, as a fraction of the panorama height.
    parallax_correction
        With a reference cloud/scan and a position hypothesis, correct the heading for the
        parallax of the query's displacement (:mod:`factorloc.vision.depth`).
    camera_height_m
        Height of the reference panorama's camera above the floor (m), to read the reference cloud.
    """

    enabled: bool = True
    pyramid_steps: int = 4
    pyramid_ratio: float = 0.85
    min_peak: float = 0.6
    ambiguity_margin: float = 0.08
    ambiguity_noise_gain: float = 0.3
    window_n_sigma: float = 3.0
    min_window_rad: float = math.radians(5.0)
    max_sigma_rad: float = math.radians(5.0)
    sigma_gain: float = 1.0
    warp_sigma_rad_per_m: float = math.radians(0.25)
    unknown_position_sigma_m: float = 0.3
    default_range_m: float = 3.0
    seed_consistency_n_sigma: float = 3.0
    vertical_search_frac: float = 0.1
    parallax_correction: bool = True
    camera_height_m: float = 1.0

    def __post_init__(self) -> None:
        if self.pyramid_steps < 0:
            raise ConfigError(f"correlation.pyramid_steps must be >= 0, got {self.pyramid_steps!r}")
        if not 0.0 < self.pyramid_ratio < 1.0:
            raise ConfigError(f"correlation.pyramid_ratio must be in (0, 1), got {self.pyramid_ratio!r}")
        if self.pyramid_ratio**self.pyramid_steps < 0.2:
            raise ConfigError(
                f"correlation.pyramid_ratio**pyramid_steps must be >= 0.2, got {self.pyramid_ratio**self.pyramid_steps:.3f}"
            )
        if not -1.0 <= self.min_peak <= 1.0:
            raise ConfigError(f"correlation.min_peak (Ct) must be in [-1, 1], got {self.min_peak!r}")
        for name in ("ambiguity_margin", "vertical_search_frac"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"correlation.{name} must be in [0, 1], got {getattr(self, name)!r}")
        for name in ("window_n_sigma", "min_window_rad", "max_sigma_rad", "sigma_gain"):
            if not getattr(self, name) > 0.0:
                raise ConfigError(f"correlation.{name} must be > 0, got {getattr(self, name)!r}")


@dataclass(frozen=True, eq=False)
class PreparedCorrelation:
    """The reference pyramid: level k is the grey panorama downscaled by ``ratioᵏ`` (k = 0 … n).

    ``scales`` holds each level's actual (width, height) ratio to level 0; ``padded`` is level 0 with its first
    two columns appended (:func:`factorloc.vision.synth.wrap_padded`), the source of the parallax warp, and
    ``horizon`` its per-column ranges and points (:func:`factorloc.vision.synth.horizon_points`), both built once.
    """

    grid: Grid
    levels: tuple[np.ndarray, ...]
    scales: tuple[tuple[float, float], ...]
    theta_reference_rad: float
    problem: str | None
    config: CorrelationConfig
    depth: DepthMap | None = None
    reference_pose: Pose2 = Pose2()
    padded: np.ndarray | None = None
    horizon: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None


def prepare(reference: Reference, config: CorrelationConfig = CorrelationConfig()) -> PreparedCorrelation:
    """Build the reference panorama's pyramid (grey float32)."""
    if reference.panorama is None:
        raise InputError(f"correlation needs Reference.panorama, reference {reference.name!r} has none")
    grid = Grid.of(reference.panorama)
    gray = to_gray(reference.panorama.image_bgr)
    problem = texture_problem(gray)
    depth = depth_map(reference, grid, config.camera_height_m) if config.parallax_correction else None
    pyr = _pyramid(gray, grid, config)
    pose = reference.T_world_reference
    padded = wrap_padded(pyr["levels"][0]) if depth is not None else None
    horizon = horizon_points(grid, depth) if depth is not None else None
    return PreparedCorrelation(grid, pyr["levels"], pyr["scales"], pose.theta, problem, config, depth, pose, padded, horizon)


def _pyramid(gray: np.ndarray, grid: Grid, config: CorrelationConfig) -> dict[str, tuple]:
    """Levels (grey panorama downscaled by ratioᵏ, k = 0 … n) and their actual (width, height) ratios."""
    levels = [gray]
    scales = [(1.0, 1.0)]
    for k in range(1, config.pyramid_steps + 1):
        r = config.pyramid_ratio**k
        w, h = max(8, int(round(grid.width_px * r))), max(8, int(round(grid.height_px * r)))
        levels.append(cv2.resize(gray, (w, h), interpolation=cv2.INTER_AREA))
        scales.append((w / grid.width_px, h / grid.height_px))
    return {"levels": tuple(levels), "scales": tuple(scales)}


@dataclass
class _Curve:
    """One pyramid level's combined correlation curve over headings ``θ(x) = θ_s − (x − x_c)·β``."""

    m: float
    x: np.ndarray  # integer shifts of the first view
    c: np.ndarray  # combined score per shift
    theta_s: float
    x_c: float
    beta: float  # rad per shift
    pixel_rad: float  # angle of one pixel at this level (the coarser of template and reference)
    periodic: bool
    positions: int  # correlation positions evaluated (shifts × vertical offsets × views)

    def theta(self, x: float | np.ndarray) -> float | np.ndarray:
        return wrap_angle(self.theta_s - (np.asarray(x, dtype=np.float64) - self.x_c) * self.beta)


def estimate(
    reference: Reference,
    query: Query,
    hypotheses: Hypotheses = Hypotheses(),
    config: CorrelationConfig = CorrelationConfig(),
    *,
    prepared: PreparedCorrelation | None = None,
) -> Estimate:
    """θ3 and the scale factor from correlating the query's views with the reference panorama.

    Parameters
    ----------
    reference
        Must hold a panorama (BGR uint8); ``T_world_reference`` places it.
    query
        Camera images and/or a panorama (BGR uint8).
    hypotheses
        Earlier reliable estimates; :meth:`Hypotheses.heading` limits the search band.
    config
        The correlation configuration.
    prepared
        The result of :func:`prepare` for ``reference`` (computed if None).

    Returns
    -------
    Estimate
        Heading-only, world frame; ``diagnostics`` hold ``peak``, ``second_peak``,
        ``scale`` (query magnification vs the reference, > 1 when closer),
        ``level``, ``searched_rad`` and ``searched_positions``.

    Raises
    ------
    InputError
        When the reference has no panorama or the query neither images nor panorama.
    """
    if prepared is None:
        prepared = prepare(reference, config)
    if not query.images and query.panorama is None:
        raise InputError(f"correlation needs Query.images or Query.panorama, query {query.id!r} has neither")
    return _estimate(prepared, query, hypotheses, config)


def _unreliable(prepared: PreparedCorrelation, theta: float, check: Check, **diag: Any) -> Estimate:
    """No heading measured: the failed ``check`` that stopped the step, at ``theta`` (reference frame)."""
    return heading_not_measured(STEP, prepared.theta_reference_rad + theta, check, diag)


def _template(strip: Strip, q: float) -> tuple[np.ndarray, float] | None:
    """The view's template resized by ``q`` and its actual width scale (None when too small)."""
    t = strip.gray
    if q != 1.0:
        w, h = int(round(t.shape[1] * q)), int(round(t.shape[0] * q))
        if w < 8 or h < 8:
            return None
        t = cv2.resize(t, (w, h), interpolation=cv2.INTER_AREA if q < 1.0 else cv2.INTER_LINEAR)
    return t, t.shape[1] / strip.width_px


def _level_curve(
    prepared: PreparedCorrelation,
    strips: list[Strip],
    m: float,
    k: int,
    q: float,
    seed: tuple[float, float] | None,
    config: CorrelationConfig,
    offsets: list[float] | None = None,
) -> _Curve | None:
    """Correlate every view, resized by ``q``, with reference level ``k`` (hypothesised scale label ``m``).

    ``offsets[i]`` (rad) is view i's parallax near the seed (corrected − uncorrected heading): its
    window is shifted by it and its curve aligned on the corrected axis.
    """
    grid = prepared.grid
    ref = prepared.levels[k]
    sx, sy = prepared.scales[k]
    h_ref, w_ref = ref.shape
    beta = 2.0 * math.pi / w_ref
    curves = []
    total = 0
    first = None
    for i, strip in enumerate(strips):
        off = 0.0 if offsets is None else offsets[i]
        if strip.full_circle and (k != 0 or q != 1.0):
            continue  # a 360° view has no single scale: only level 0
        tpl = _template(strip, q)
        if tpl is None:
            continue
        t, sq = tpl
        sq_y = t.shape[0] / strip.height_px
        # vertical placement: align the horizons (grid row H/2) of template and reference level
        hor_t = (0.5 * grid.height_px - strip.row0 + 0.5) * sq_y - 0.5
        hor_r = (0.5 * grid.height_px + 0.5) * sy - 0.5
        margin = int(math.ceil(config.vertical_search_frac * h_ref))
        if t.shape[0] > h_ref - 2:  # crop the template around its horizon to fit
            keep = h_ref - 2
            top = int(np.clip(round(hor_t - keep / 2), 0, t.shape[0] - keep))
            t = t[top : top + keep]
            hor_t -= top
        dy0 = int(round(hor_r - hor_t))
        dy_lo, dy_hi = max(0, dy0 - margin), min(h_ref - t.shape[0], dy0 + margin)
        if dy_hi < dy_lo or t.shape[1] >= 2 * w_ref or texture_problem(t) is not None:
            continue
        c_t = (t.shape[1] - 1) / 2.0
        a_c = float(strip.azimuth_of_column((c_t + 0.5) / sq - 0.5))
        # θ(x) = A − β·x for template column 0 on reference-level column x
        A = grid.azimuth_col0_rad - 2.0 * math.pi * ((c_t + 0.5) / sx - 0.5) / grid.width_px - a_c
        if first is None:
            theta_s = seed[0] if seed is not None else float(wrap_angle(A))
            half = None if seed is None else seed[1] / beta
            if half is not None and 2 * half + 3 >= w_ref:
                half = None
            first = (theta_s, half)
        theta_s, half = first
        x_c = float(wrap_angle(A - (theta_s - off))) / beta
        if half is None:
            x_lo, x_hi = 0, w_ref - 1
        else:
            x_lo, x_hi = int(math.floor(x_c - half)) - 1, int(math.ceil(x_c + half)) + 1
        band = np.ascontiguousarray(ref[dy_lo : dy_hi + t.shape[0]])
        scores = correlate_wrapped(band, np.ascontiguousarray(t), x_lo, x_hi)
        total += scores.size
        curves.append((np.arange(x_lo, x_hi + 1), scores.max(axis=0).astype(np.float64), x_c, float(t.size), sq))
    if not curves:
        return None
    x0, c0, xc0, _, _ = curves[0]
    periodic = first[1] is None
    combined = np.zeros_like(c0)
    weights = 0.0
    for x, c, xc, wgt, _ in curves:
        at = x0 + (xc - xc0)
        if periodic:
            vals = np.interp(np.mod(at, w_ref), np.append(x, w_ref), np.append(c, c[0]))
        else:
            vals = np.interp(at, x, c, left=-1.0, right=-1.0)
        combined += wgt * vals
        weights += wgt
    combined /= weights
    min_sq = min(sq for *_, sq in curves)
    pixel = 2.0 * math.pi / (grid.width_px * min(sx, min_sq))
    return _Curve(m, x0, combined, first[0], xc0, beta, pixel, periodic, total)


def _lobe_mask(c: np.ndarray, k: int, periodic: bool, min_half: int) -> np.ndarray:
    """Samples of the peak's own lobe: walk down both sides while the curve decreases (at least ``min_half``)."""
    n = c.size
    mask = np.zeros(n, dtype=bool)
    mask[k] = True
    for step in (-1, 1):
        i, prev, walked = k, c[k], 0
        while walked < n - 1:
            j = i + step
            if periodic:
                j %= n
            elif not 0 <= j < n:
                break
            if c[j] > prev and walked >= min_half:
                break
            mask[j] = True
            prev, i, walked = c[j], j, walked + 1
    return mask


def _reachable_columns(
    strips: list[Strip], grid: Grid, seed: tuple[float, float] | None, margin_px: int = 8
) -> np.ndarray | None:
    """Boolean mask (W,) of the reference columns any view can cover at a heading within the seeded window.

    A heading θ moves robot azimuth ``a`` to reference azimuth ``a + θ``, i.e. grid column ``c(a) − θ/Δ``
    (Δ = one column's angle): strip columns ``col0 … col0 + n − 1`` reach ``col0 − (θ̂ + h)/Δ … col0 + n − 1 − (θ̂ − h)/Δ``
    for θ ∈ [θ̂ − h, θ̂ + h], widened by ``margin_px``. None (every column) without a seed or for a 360° view.
    """
    if seed is None or any(s.full_circle for s in strips):
        return None
    w = grid.width_px
    mask = np.zeros(w, dtype=bool)
    theta, half = seed
    for s in strips:
        lo = s.col0 - (theta + half) / grid.rad_per_px - margin_px
        hi = s.col0 + s.width_px - 1 - (theta - half) / grid.rad_per_px + margin_px
        if hi - lo + 1 >= w:
            return None
        mask[np.mod(np.arange(math.floor(lo), math.ceil(hi) + 1), w)] = True
    return mask


def _estimate(prepared: PreparedCorrelation, query: Query, hypotheses: Hypotheses, config: CorrelationConfig) -> Estimate:
    """θ3 with the typed :class:`~factorloc.verdicts.SeedEvidence` of what seeded it (heading window, position)."""
    est = _measure(prepared, query, hypotheses, config)
    h, p = hypotheses.heading(), hypotheses.position()
    windowed = h is not None and max(config.min_window_rad, config.window_n_sigma * h[1]) < math.pi
    position = position_seed(hypotheses) if prepared.depth is not None else None
    evidence = SeedEvidence(
        position_step=p[4] if position is not None and p is not None else None,
        heading_step=h[2] if windowed and h is not None else None,
        windowed=windowed,
    )
    return replace(est, seed=evidence)


def _measure(prepared: PreparedCorrelation, query: Query, hypotheses: Hypotheses, config: CorrelationConfig) -> Estimate:
    h = hypotheses.heading()
    seed = None
    if h is not None:
        half = max(config.min_window_rad, config.window_n_sigma * h[1])
        if half < math.pi:
            seed = (float(wrap_angle(h[0] - prepared.theta_reference_rad)), half)
    theta_fallback = seed[0] if seed is not None else 0.0
    base: dict[str, Any] = {"window_rad": None if seed is None else seed[1]}
    if prepared.problem:
        check = Check.flag(
            "correlation.reference", "a usable reference panorama", False, failure=f"reference: {prepared.problem}"
        )
        return _unreliable(prepared, theta_fallback, check, **base)
    strips, dropped = query_strips(query, prepared.grid)
    base["dropped_views"] = dropped
    if not strips:
        failure = "no usable query view: " + "; ".join(dropped)
        check = Check.flag("correlation.query_views", "a usable query view", False, failure=failure)
        return _unreliable(prepared, theta_fallback, check, **base)
    position = position_seed(hypotheses) if prepared.depth is not None else None
    magnification = None
    if position is not None:
        # remove the parallax: correlate with the reference re-rendered from the hypothesised position
        p_ref = prepared.depth.T_world_reference.inverse().transform_points(np.array([position[0]]))[0]
        synth, range_m, magnification = synthesize(
            prepared.levels[0],
            prepared.grid,
            prepared.depth,
            (p_ref[0], p_ref[1]),
            columns=_reachable_columns(strips, prepared.grid, seed),
            padded=prepared.padded,
            horizon=prepared.horizon,
        )
        # only level 0 is correlated after the warp (below): no pyramid of the re-rendered panorama
        prepared = dataclasses.replace(prepared, levels=(synth,), scales=((1.0, 1.0),))
    base["parallax_corrected"] = position is not None
    offsets = None
    # after the warp the residual scale is near 1: no pyramid (small templates of coarse levels match by chance)
    n = 0 if position is not None else config.pyramid_steps
    levels = [(m, max(0, -m), config.pyramid_ratio ** max(0, m)) for m in range(-n, n + 1)]
    curves = [cv for m, k, q in levels if (cv := _level_curve(prepared, strips, m, k, q, seed, config, offsets)) is not None]
    if not curves:
        check = Check.flag("correlation.pyramid", "a view that fits the reference pyramid", False)
        return _unreliable(prepared, theta_fallback, check, **base)
    searched = sum(cv.positions for cv in curves)
    base.update(searched_positions=int(searched), searched_rad=2.0 * math.pi if seed is None else 2.0 * seed[1])
    best = max(curves, key=lambda cv: float(cv.c.max()))
    k = int(np.argmax(best.c))
    peak = float(best.c[k])
    nb = best.c.size
    at_edge = not best.periodic and (k == 0 or k == nb - 1)
    if at_edge:
        delta, kappa = 0.0, 0.0
    else:
        ym, yp = best.c[(k - 1) % nb], best.c[(k + 1) % nb]
        delta, kappa = parabolic_peak(float(ym), peak, float(yp))
    theta = float(best.theta(best.x[k] + delta))
    # ambiguity: the best peak outside the main lobe
    lobe = _lobe_mask(best.c, k, best.periodic, min_half=3)
    second = float(best.c[~lobe].max()) if (~lobe).any() else None
    # scale: parabola in level index over the levels' values at θ
    values = {}
    for cv in curves:
        near = np.abs(wrap_angle(cv.theta(cv.x) - theta)) <= 2.0 * cv.beta
        values[cv.m] = float(cv.c[near].max()) if near.any() else -1.0
    m_ref = float(best.m)
    if best.m - 1 in values and best.m + 1 in values:
        dm, _ = parabolic_peak(values[best.m - 1], values[best.m], values[best.m + 1])
        m_ref += dm
    scale = config.pyramid_ratio ** (-m_ref)
    if not at_edge and abs(m_ref) > 0.05:
        # refinement pass at the refined scale: the views resized by 1/scale against the full reference
        fine = _level_curve(prepared, strips, m_ref, 0, 1.0 / scale, (float(wrap_angle(theta)), 3.0 * best.beta), config, offsets)
        if fine is not None and fine.c.size >= 3:
            kf = int(np.argmax(fine.c))
            if 0 < kf < fine.c.size - 1:
                df, kappa_f = parabolic_peak(float(fine.c[kf - 1]), float(fine.c[kf]), float(fine.c[kf + 1]))
                if kappa_f > 0.0:
                    theta = float(fine.theta(fine.x[kf] + df))
                    peak, kappa = max(peak, float(fine.c[kf])), kappa_f
                    pixel = max(fine.pixel_rad, best.pixel_rad)
                    best = dataclasses.replace(best, beta=fine.beta, pixel_rad=pixel)
                    searched += fine.positions
                    base["searched_positions"] = int(searched)
    if kappa > 0.0:
        sigma_px = config.sigma_gain * math.sqrt(max(1.0 - peak, 1e-3) / kappa)
        sigma = max(sigma_px * best.beta, best.pixel_rad)
    else:
        sigma = math.pi
    view_az = np.asarray(strips[0].azimuth_of_column(np.linspace(0.1, 0.9, 9) * (strips[0].width_px - 1)))
    sigma_par = uncorrected_parallax_sigma(
        hypotheses,
        prepared.depth,
        prepared.reference_pose,
        np.asarray(wrap_angle(theta + view_az)),
        config.unknown_position_sigma_m,
        config.default_range_m,
    )
    sigma = math.hypot(sigma, sigma_par)
    scale_residual = scale
    if position is not None:
        displacement = float(np.hypot(*(np.asarray(position[0]) - prepared.depth.T_world_reference.translation)))
        sigma = math.hypot(sigma, config.warp_sigma_rad_per_m * displacement)
        # the columns the first view covers at θ: their range from the query and magnification vs the reference
        cols = np.mod(np.rint(prepared.grid.column_of_azimuth(theta + view_az)).astype(int), prepared.grid.width_px)
        sigma_par = parallax_sigma(position[1], np.percentile(range_m[cols], 25))
        sigma = math.hypot(sigma, sigma_par)
        scale = scale_residual * float(np.median(magnification[cols]))
    diag = dict(
        base,
        peak=peak,
        second_peak=second,
        level=best.m,
        scale=scale,
        scale_residual=scale_residual,
        curvature_per_px2=kappa,
        pixel_rad=best.pixel_rad,
        level_peaks={str(m): v for m, v in sorted(values.items())},
        sigma_parallax_rad=sigma_par,
        views=len(strips),
        theta_relative_rad=theta,
    )
    theta_world = prepared.theta_reference_rad + theta
    est = Estimate.heading(STEP, theta_world, sigma, reliable=False, diagnostics=diag)
    seed_check = heading_seed_check(STEP, theta_world, sigma, h, config.seed_consistency_n_sigma)
    checks = (
        peak_checks(peak, second, at_edge, config)
        + (() if seed_check is None else (seed_check,))
        + sigma_checks(est, max_sigma_heading_rad=config.max_sigma_rad)
    )
    if all(c.passed for c in checks):
        margin = "no secondary peak in the window" if second is None else f"secondary peak {second:.3f}"
        return est.with_verdict(True, f"peak {peak:.3f} ≥ Ct {config.min_peak:.2f}, {margin}", checks)
    return est.with_verdict(False, render_checks(checks), checks)


def peak_checks(peak: float, second: float | None, at_edge: bool, config: CorrelationConfig) -> tuple[Check, ...]:
    """The rules of the panorama correlation (WO 2015/158682, claim 6: reliable only if the peak exceeds Ct), in
    the order they apply:

    * ``correlation.peak``: the normalized cross-correlation peak at least ``min_peak`` (Ct);
    * ``correlation.ambiguity`` (with a secondary peak): the peak above it by at least
      ``ambiguity_margin + ambiguity_noise_gain · (1 − peak)`` (a weaker peak needs a wider margin);
    * ``correlation.window_edge``: the peak not on the edge of a seeded window (the maximum may lie beyond it).

    The shared rules follow them: ``correlation.seed_consistency`` (with a heading seed,
    :func:`~factorloc.estimators.base.heading_seed_check`) and the σ rule (``correlation.sigma_heading``,
    :func:`~factorloc.estimators.base.sigma_checks`).
    """
    checks = [Check.at_least("correlation.peak", "correlation peak", peak, config.min_peak, note="Ct")]
    if second is not None:
        needed = config.ambiguity_margin + config.ambiguity_noise_gain * (1.0 - peak)
        ok = not peak - second < needed
        checks.append(
            Check(
                "correlation.ambiguity",
                "margin of the peak over the secondary peak",
                ok,
                peak - second,
                needed,
                Comparison.AT_LEAST,
                Unit.NONE,
                "" if ok else f"ambiguous: secondary peak {second:.3f}",
            )
        )
    checks.append(
        Check.flag(
            "correlation.window_edge",
            "the peak inside the seeded window",
            not at_edge,
            failure="peak on the edge of the seeded window",
        )
    )
    return tuple(checks)


class CorrelationStep:
    """Panorama correlation as a pipeline step (needs a reference panorama and query images or panorama)."""

    name = STEP

    def __init__(self, config: CorrelationConfig = CorrelationConfig()) -> None:
        self.config = config

    def prepare(self, reference: Reference) -> PreparedCorrelation | None:
        if reference.panorama is None:
            return None
        return prepare(reference, self.config)

    def estimate(self, prepared: PreparedCorrelation | None, query: Query, hypotheses: Hypotheses) -> Estimate | None:
        if prepared is None or (not query.images and query.panorama is None):
            return None
        return _estimate(prepared, query, hypotheses, self.config)
