"""Figures of an evaluation: pure ``plot_*_on_axes(ax, ...)`` functions and thin wrappers.

Every ``plot_*_on_axes`` draws on a given matplotlib ``Axes`` and returns it,
so notebooks can compose them; every ``*_figure`` wrapper makes a new
:class:`matplotlib.figure.Figure` (no pyplot state, no display: safe on the
Agg backend, in tests and on servers) and returns it;
:func:`save_report_figures` writes all of them as PNG files.

Units at the edges: metres on the floor plan, centimetres and degrees on the
error plots. Covariance ellipses are drawn at a stated confidence: the
``p`` ellipse of a 2-D Gaussian is ``{e : eᵀ Σ⁻¹ e ≤ χ²₂⁻¹(p)}`` (5.991 for 95 %).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse, Polygon
from scipy.stats import chi2

from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.stats import chi2_quantile
from factorloc.types import StepStatus

if TYPE_CHECKING:  # pragma: no cover
    from factorloc.evaluation.report import EvaluationReport
    from factorloc.sim.world import World

__all__ = [
    "STATUS_COLORS",
    "availability_figure",
    "calibration_figure",
    "covariance_ellipse",
    "error_vs_distance_figure",
    "floor_plan_figure",
    "plot_availability_on_axes",
    "plot_covariance_ellipse_on_axes",
    "plot_error_vs_distance_on_axes",
    "plot_estimates_on_axes",
    "plot_nees_on_axes",
    "plot_places_on_axes",
    "plot_track_errors_on_axes",
    "plot_track_on_axes",
    "plot_world_on_axes",
    "save_report_figures",
]

#: Colours of the step statuses (green fused … red failed), shared by every figure.
STATUS_COLORS: dict[str, str] = {
    StepStatus.FUSED.value: "#2e9d5b",
    StepStatus.UNRELIABLE.value: "#f0b429",
    StepStatus.INCONSISTENT.value: "#d9534f",
    StepStatus.SKIPPED.value: "#b8bec6",
    StepStatus.FAILED.value: "#7a1f1f",
}
TRUTH_COLOR = "#1f4e79"
ESTIMATE_COLOR = "#d1495b"
FAULT_CMAP = "tab10"


# --------------------------------------------------------------------------
# Geometry of an ellipse
# --------------------------------------------------------------------------
def covariance_ellipse(covariance_xy: np.ndarray, confidence: float = 0.95) -> tuple[float, float, float]:
    """Full width, full height (m) and angle (deg, CCW from x) of the ``confidence`` ellipse of a 2×2 covariance.

    Half-axes are ``√(χ²₂⁻¹(p) λᵢ)`` along the eigenvectors of Σ.
    """
    cov = np.asarray(covariance_xy, dtype=np.float64)
    if cov.shape != (2, 2) or not np.all(np.isfinite(cov)):
        raise InputError(f"covariance_xy must be a finite 2×2 matrix, got {cov.tolist()}")
    if not 0.0 < confidence < 1.0:
        raise InputError(f"confidence must be in (0, 1), got {confidence!r}")
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    vals = np.maximum(vals, 0.0)
    k = chi2_quantile(confidence, 2)
    width, height = 2.0 * math.sqrt(k * vals[1]), 2.0 * math.sqrt(k * vals[0])
    angle = math.degrees(math.atan2(vecs[1, 1], vecs[0, 1]))
    return width, height, angle


def plot_covariance_ellipse_on_axes(
    ax: Axes, center_xy: Sequence[float], covariance_xy: np.ndarray, confidence: float = 0.95, **kwargs: Any
) -> Axes:
    """Draw the ``confidence`` ellipse of a 2×2 position covariance (m²) centred at ``center_xy`` (m)."""
    w, h, a = covariance_ellipse(covariance_xy, confidence)
    style = {"fill": False, "lw": 1.0, "ec": ESTIMATE_COLOR, "alpha": 0.8}
    style.update(kwargs)
    ax.add_patch(Ellipse((float(center_xy[0]), float(center_xy[1])), w, h, angle=a, **style))
    return ax


# --------------------------------------------------------------------------
# Floor plan
# --------------------------------------------------------------------------
def plot_world_on_axes(ax: Axes, world: World) -> Axes:
    """Draw a :class:`factorloc.sim.World`'s walls (lines) and obstacles (grey polygons), metres, equal aspect."""
    for w in world.walls:
        xs, ys = [w.start_xy[0], w.end_xy[0]], [w.start_xy[1], w.end_xy[1]]
        ax.plot(xs, ys, color="#333333", lw=2.0, solid_capstyle="round", zorder=1)
    for ob in world.obstacles:
        ax.add_patch(Polygon(np.asarray(ob.vertices_xy), closed=True, fc="#d8d2c4", ec="#8a8170", lw=0.8, zorder=1))
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    return ax


def _arrow(ax: Axes, pose: Pose2, length: float, color: str, **kwargs: Any) -> None:
    ax.annotate(
        "",
        xy=(pose.x + length * math.cos(pose.theta), pose.y + length * math.sin(pose.theta)),
        xytext=(pose.x, pose.y),
        arrowprops={"arrowstyle": "-|>", "color": color, "lw": 1.0, "mutation_scale": 7},
        **kwargs,
    )


def plot_estimates_on_axes(
    ax: Axes,
    report: EvaluationReport,
    *,
    confidence: float = 0.95,
    arrow_m: float = 0.25,
    ellipse_scale: float = 1.0,
    max_scaled_m: float | None = None,
) -> Axes:
    """True poses (blue dots, heading arrows), estimates (red crosses) and their ``confidence`` ellipses.

    A grey line joins each estimate to its truth; queries whose position is
    under-determined show their truth only (hollow marker). The reference
    poses are black stars. ``ellipse_scale`` magnifies the ellipses (cm-sized
    ellipses are invisible on a 10 m plan); the legend states it. An ellipse
    whose magnified major half-axis would exceed ``max_scaled_m`` is drawn at
    its true size, dashed.
    """
    refs = [r.T_world_reference for r in report.run.dataset.references.values()]
    tx, ty, ex, ey, ux, uy = [], [], [], [], [], []
    dashed = False
    for r in report.results:
        det = r.determined
        if r.truth is not None:
            _arrow(ax, r.truth, arrow_m, TRUTH_COLOR, zorder=3)
            if det[0] and det[1]:
                tx.append(r.truth.x)
                ty.append(r.truth.y)
            else:
                ux.append(r.truth.x)
                uy.append(r.truth.y)
        if det[0] and det[1]:
            ex.append(r.pose.x)
            ey.append(r.pose.y)
            if r.truth is not None:
                ax.plot([r.truth.x, r.pose.x], [r.truth.y, r.pose.y], color="#777777", lw=0.6, zorder=2)
            cov2 = r.covariance[:2, :2]
            half_major = 0.5 * covariance_ellipse(cov2, confidence)[0]
            if ellipse_scale != 1.0 and max_scaled_m is not None and ellipse_scale * half_major > max_scaled_m:
                plot_covariance_ellipse_on_axes(ax, (r.pose.x, r.pose.y), cov2, confidence, zorder=4, ls="--", lw=0.7)
                dashed = True
            else:
                plot_covariance_ellipse_on_axes(ax, (r.pose.x, r.pose.y), (ellipse_scale**2) * cov2, confidence, zorder=4)
    ax.scatter(tx, ty, s=14, color=TRUTH_COLOR, label="true pose", zorder=5)
    if ux:
        ax.scatter(ux, uy, s=18, facecolors="none", edgecolors=TRUTH_COLOR, label="true pose (position undetermined)", zorder=5)
    ax.scatter(ex, ey, s=18, marker="x", color=ESTIMATE_COLOR, lw=1.2, label="estimate", zorder=6)
    ax.scatter([p.x for p in refs], [p.y for p in refs], s=140, marker="*", color="black", label="reference", zorder=7)
    scale = "" if ellipse_scale == 1.0 else f" ×{ellipse_scale:g}"
    ax.plot([], [], color=ESTIMATE_COLOR, lw=1.0, label=f"{100 * confidence:.0f} % ellipse{scale}")
    if dashed:
        ax.plot([], [], color=ESTIMATE_COLOR, lw=0.7, ls="--", label=f"{100 * confidence:.0f} % ellipse, true size")
    ax.set_aspect("equal")
    ax.legend(loc="best", fontsize="small", framealpha=0.9)
    return ax


def floor_plan_figure(
    report: EvaluationReport, world: World | None = None, *, confidence: float = 0.95, ellipse_scale: float | None = None
) -> Figure:
    """The floor plan (``world``, default the report's) with true/estimated poses and ellipses.

    ``ellipse_scale`` defaults to a factor (1, 2, 5, 10, …) that makes the median ellipse
    ~2 % of the plan's size; ellipses that would then exceed 10 % are drawn at true size, dashed.
    """
    world = world if world is not None else report.run.dataset.world
    fig = Figure(figsize=(9.0, 7.0), layout="constrained")
    ax = fig.add_subplot()
    if world is not None:
        plot_world_on_axes(ax, world)
    if ellipse_scale is None:
        ellipse_scale = _auto_ellipse_scale(report, world)
    size = _plan_size(report, world)
    plot_estimates_on_axes(ax, report, confidence=confidence, ellipse_scale=ellipse_scale, max_scaled_m=0.05 * size)
    if world is not None:  # the plan, not the ellipses, sets the view
        x0, y0, x1, y1 = world.bounds_xy
        margin = 0.05 * size
        ax.set_xlim(x0 - margin, x1 + margin)
        ax.set_ylim(y0 - margin, y1 + margin)
    ax.set_title(f"{report.name}: true and estimated poses ({report.strategy})")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    return fig


def _plan_size(report: EvaluationReport, world: World | None) -> float:
    """The larger side (m) of the world's bounds, or of the true poses' spread (≥ 1 m)."""
    if world is not None:
        x0, y0, x1, y1 = world.bounds_xy
        return max(x1 - x0, y1 - y0)
    pts = np.array([[r.truth.x, r.truth.y] for r in report.results if r.truth is not None] or [[0.0, 0.0]])
    return max(float(np.ptp(pts[:, 0])), float(np.ptp(pts[:, 1])), 1.0)


def _auto_ellipse_scale(report: EvaluationReport, world: World | None) -> float:
    sig = [math.sqrt(max(np.linalg.eigvalsh(r.covariance[:2, :2])[-1], 0.0)) for r in report.results if r.determined[:2].all()]
    if not sig:
        return 1.0
    target = 0.01 * _plan_size(report, world)  # half-width ≈ 1 % of the plan
    med = float(np.median(sig)) * math.sqrt(chi2_quantile(0.95, 2))
    if med <= 0.0 or med >= target:
        return 1.0
    ratio = target / med
    magnitude = 10.0 ** math.floor(math.log10(ratio))
    return next(m * magnitude for m in (5.0, 2.0, 1.0) if m * magnitude <= ratio)


# --------------------------------------------------------------------------
# Errors against distance from the reference
# --------------------------------------------------------------------------
def _fault_label(faults: tuple[str, ...]) -> str:
    return "+".join(faults) if faults else "no fault"


def plot_error_vs_distance_on_axes(ax: Axes, report: EvaluationReport, *, component: str = "position") -> Axes:
    """Position error (cm) or heading error (deg) against the true distance from the reference (m), by fault.

    ``component`` is ``"position"`` or ``"heading"``; undetermined results are left out.
    """
    if component not in ("position", "heading"):
        raise InputError(f"component must be 'position' or 'heading', got {component!r}")
    err = report.errors
    d = np.array([r.distance_to_reference_m for r in report.results])
    y = 100.0 * np.hypot(err[:, 0], err[:, 1]) if component == "position" else np.degrees(np.abs(err[:, 2]))
    floor = 0.01 if component == "position" else 0.001
    labels = [_fault_label(r.faults) for r in report.results]
    order = sorted(set(labels), key=lambda s: (s != "no fault", s))
    cmap = _colormap(FAULT_CMAP)
    for i, lab in enumerate(order):
        sel = np.array([lb == lab for lb in labels]) & np.isfinite(y) & np.isfinite(d)
        if sel.any():
            ax.scatter(d[sel], np.maximum(y[sel], floor), s=16, color=cmap(i % 10), label=f"{lab} ({int(sel.sum())})", alpha=0.85)
    ax.set_xlabel("distance from the reference (m)")
    ax.set_ylabel("position error (cm)" if component == "position" else "heading error (°)")
    ax.set_yscale("log")  # values below the floor (0.1 mm / 0.001°) are drawn at the floor
    finite = y[np.isfinite(y)]
    if finite.size:
        ax.set_ylim(bottom=max(floor, 0.5 * float(np.min(np.maximum(finite, floor)))))
    ax.grid(True, which="both", alpha=0.3)
    if order:
        ax.legend(fontsize="small", loc="upper left")
    return ax


def _colormap(name: str) -> Any:
    from matplotlib import colormaps

    return colormaps[name]


def error_vs_distance_figure(report: EvaluationReport) -> Figure:
    """Position and heading error against distance from the reference, side by side."""
    fig = Figure(figsize=(11.0, 4.2), layout="constrained")
    a1, a2 = fig.subplots(1, 2)
    plot_error_vs_distance_on_axes(a1, report, component="position")
    plot_error_vs_distance_on_axes(a2, report, component="heading")
    a1.set_title("position error")
    a2.set_title("heading error")
    fig.suptitle(f"{report.name}: error vs distance from the reference ({report.strategy})")
    return fig


# --------------------------------------------------------------------------
# Availability
# --------------------------------------------------------------------------
def plot_availability_on_axes(ax: Axes, report: EvaluationReport) -> Axes:
    """Per step, the fraction of queries it was fused / unreliable / inconsistent / skipped / failed (stacked bars)."""
    steps = report.summary().overall.steps
    names = list(steps)
    left = np.zeros(len(names))
    for status in [s.value for s in StepStatus]:
        frac = np.array([steps[n].status_rates.get(status, 0.0) for n in names])
        if frac.any():
            ax.barh(names, frac, left=left, color=STATUS_COLORS[status], label=status, edgecolor="white", height=0.6)
            for i, (lft, f) in enumerate(zip(left, frac, strict=True)):
                if f >= 0.08:
                    ax.text(lft + f / 2, i, f"{100 * f:.0f} %", ha="center", va="center", fontsize=8, color="white")
        left += frac
    ax.set_xlim(0.0, 1.0)
    ax.invert_yaxis()  # hierarchy order top to bottom
    ax.set_xlabel("fraction of queries")
    ax.legend(ncol=5, fontsize="small", loc="lower center", bbox_to_anchor=(0.5, 1.0), frameon=False)
    return ax


def availability_figure(report: EvaluationReport) -> Figure:
    """The per-step availability bar chart."""
    n = len(report.run.step_names)
    fig = Figure(figsize=(8.0, 1.2 + 0.55 * max(n, 1)), layout="constrained")
    plot_availability_on_axes(fig.add_subplot(), report)
    fig.suptitle(f"{report.name}: what became of each step ({len(report.results)} queries)")
    return fig


# --------------------------------------------------------------------------
# Calibration
# --------------------------------------------------------------------------
def plot_nees_on_axes(ax: Axes, report: EvaluationReport, *, max_nees: float = 20.0, bins: int = 30) -> Axes:
    """Histogram (density) of the 3-dof NEES of fully determined results against the χ²(3) density.

    Values above ``max_nees`` are counted in the last bin; the title-less
    legend gives their number, the mean NEES and the expected 3.
    """
    e, k = report.nees
    v = e[(k == 3) & np.isfinite(e)]
    x = np.linspace(0.0, max_nees, 400)
    ax.plot(x, chi2.pdf(x, 3), color="black", lw=1.5, label="χ²(3) density (calibrated)")
    if v.size:
        over = int(np.count_nonzero(v > max_nees))
        ax.hist(
            np.minimum(v, max_nees * 0.9999),
            bins=bins,
            range=(0.0, max_nees),
            density=True,
            color="#4c8bc9",
            alpha=0.7,
            label=f"NEES of {v.size} results (mean {v.mean():.2f}, median {np.median(v):.2f})",
        )
        if over:
            ax.plot([], [], " ", label=f"{over} above {max_nees:g} (in last bin)")
    ax.axvline(chi2_quantile(0.99, 3), color="#d9534f", ls="--", lw=1.0, label="99 % bound (11.34); χ²(3) median 2.37")
    ax.set_xlim(0.0, max_nees)
    ax.set_xlabel("NEES  εᵀΣ⁻¹ε  (3 dof)")
    ax.set_ylabel("density")
    ax.legend(fontsize="small")
    return ax


def calibration_figure(report: EvaluationReport) -> Figure:
    """The calibration plot: NEES histogram against the χ²(3) density."""
    fig = Figure(figsize=(7.0, 4.2), layout="constrained")
    plot_nees_on_axes(fig.add_subplot(), report)
    fig.suptitle(f"{report.name}: is the claimed covariance honest? ({report.strategy})")
    return fig


# --------------------------------------------------------------------------
# Places and tracks
# --------------------------------------------------------------------------
def plot_places_on_axes(ax: Axes, positions_xy: np.ndarray, labels: Sequence[str] = (), **kwargs: Any) -> Axes:
    """The places of a map (black triangles at their N×2 positions, m), with ``labels`` beside them when given."""
    pts = np.asarray(positions_xy, dtype=np.float64).reshape(-1, 2)
    if labels and len(labels) != len(pts):
        raise InputError(f"{len(labels)} labels for {len(pts)} places")
    style = {"s": 28, "marker": "^", "color": "black", "label": "place", "zorder": 3}
    style.update(kwargs)
    ax.scatter(pts[:, 0], pts[:, 1], **style)
    for (x, y), text in zip(pts, labels, strict=False):
        ax.annotate(text, (x, y), xytext=(3, 3), textcoords="offset points", fontsize="x-small", color="#444444")
    ax.set_aspect("equal")
    return ax


def _track_arrays(poses: np.ndarray, covariances: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"poses must be N×3 [x_m, y_m, theta_rad], got shape {p.shape}")
    if covariances is None:
        return p, None
    c = np.asarray(covariances, dtype=np.float64)
    if c.shape != (len(p), 3, 3):
        raise InputError(f"covariances must be N×3×3 with N = {len(p)}, got shape {c.shape}")
    return p, c


def plot_track_on_axes(
    ax: Axes,
    poses: np.ndarray,
    covariances: np.ndarray | None = None,
    *,
    truth: np.ndarray | None = None,
    states: Sequence[str] = (),
    kidnapped: Sequence[int] = (),
    confidence: float = 0.95,
    ellipse_every: int = 1,
    ellipse_scale: float = 1.0,
    color: str = ESTIMATE_COLOR,
    label: str = "estimate",
) -> Axes:
    """A tracked trajectory on the floor plan: the estimated path (``poses``, N×3 world frame, a NaN row where there
    was no estimate: the line breaks there), the ``confidence`` ellipse of every ``ellipse_every``-th position
    covariance (``covariances`` N×3×3, its x–y block, magnified by ``ellipse_scale``: the legend says so), the true
    path (``truth`` N×3, blue), the ``kidnapped`` queries (dotted grey line from the true pose before to the one
    after: the robot was carried) and, with ``states`` (N of ``tracking`` / ``relocalized`` / ``lost``), the
    re-localizations (green diamonds) and the lost queries (hollow grey circles)."""
    p, c = _track_arrays(poses, covariances)
    if isinstance(ellipse_every, bool) or not isinstance(ellipse_every, int) or ellipse_every < 1:
        raise InputError(f"ellipse_every must be an integer >= 1, got {ellipse_every!r}")
    if states and len(states) != len(p):
        raise InputError(f"{len(states)} states for {len(p)} poses")
    cut = set(int(k) for k in kidnapped)
    if truth is not None:
        t, _ = _track_arrays(truth, None)
        if len(t) != len(p):
            raise InputError(f"truth has {len(t)} poses, the track {len(p)}")
        t_line = t[:, :2].copy()
        for k in cut:
            if 0 < k < len(t):
                ax.plot(t[k - 1 : k + 1, 0], t[k - 1 : k + 1, 1], ls=":", color="#777777", lw=1.2, zorder=2)
        broken = np.insert(t_line, sorted(k for k in cut if 0 < k < len(t)), np.nan, axis=0)
        ax.plot(broken[:, 0], broken[:, 1], color=TRUTH_COLOR, lw=1.2, label="truth", zorder=2)
        if cut:
            ax.plot([], [], ls=":", color="#777777", lw=1.2, label="kidnapped (carried)")
    line = p[:, :2].copy()
    line = np.insert(line, sorted(k for k in cut if 0 < k < len(p)), np.nan, axis=0)
    ax.plot(line[:, 0], line[:, 1], color=color, lw=1.0, label=label, zorder=4)
    if c is not None:
        drawn = 0
        for i in range(0, len(p), ellipse_every):
            if np.all(np.isfinite(p[i, :2])) and np.all(np.isfinite(c[i, :2, :2])):
                plot_covariance_ellipse_on_axes(ax, p[i, :2], (ellipse_scale**2) * c[i, :2, :2], confidence, ec=color, zorder=5)
                drawn += 1
        if drawn:
            scale = "" if ellipse_scale == 1.0 else f" ×{ellipse_scale:g}"
            ax.plot([], [], color=color, lw=1.0, label=f"{100 * confidence:.0f} % ellipse{scale}")
    if states:
        st = np.asarray([str(s) for s in states])
        rel, lost = st == "relocalized", st == "lost"
        ok = np.all(np.isfinite(p[:, :2]), axis=1)
        if (rel & ok).any():
            ax.scatter(p[rel & ok, 0], p[rel & ok, 1], s=50, marker="D", color="#2e9d5b", label="re-localized", zorder=6)
        if (lost & ok).any():
            ax.scatter(p[lost & ok, 0], p[lost & ok, 1], s=30, facecolors="none", edgecolors="#777777", label="lost", zorder=6)
    ax.set_aspect("equal")
    return ax


def plot_track_errors_on_axes(
    ax: Axes, poses: np.ndarray, truth: np.ndarray, *, kidnapped: Sequence[int] = (), color: str = ESTIMATE_COLOR, label: str = ""
) -> Axes:
    """Position error (cm, log scale) of a track against the query index; NaN poses (no estimate) leave gaps;
    the ``kidnapped`` queries are dotted vertical lines."""
    p, _ = _track_arrays(poses, None)
    t, _ = _track_arrays(truth, None)
    if len(t) != len(p):
        raise InputError(f"truth has {len(t)} poses, the track {len(p)}")
    err_cm = 100.0 * np.hypot(p[:, 0] - t[:, 0], p[:, 1] - t[:, 1])
    ax.semilogy(np.arange(len(p)), np.maximum(err_cm, 1e-2), color=color, lw=1.0, marker=".", ms=3, label=label)
    for k in kidnapped:
        ax.axvline(int(k), color="#777777", ls=":", lw=1.0)
    ax.set_xlabel("query")
    ax.set_ylabel("position error (cm)")
    return ax


# --------------------------------------------------------------------------
# All of them
# --------------------------------------------------------------------------
def save_report_figures(
    report: EvaluationReport, out_dir: str | Path, world: World | None = None, *, dpi: int = 120
) -> list[Path]:
    """Write the four figures of ``report`` as PNG into ``out_dir`` (created) and return their paths.

    Files: ``floor_plan.png``, ``error_vs_distance.png``, ``availability.png``, ``calibration.png``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figures = {
        "floor_plan.png": floor_plan_figure(report, world),
        "error_vs_distance.png": error_vs_distance_figure(report),
        "availability.png": availability_figure(report),
        "calibration.png": calibration_figure(report),
    }
    paths = []
    for name, fig in figures.items():
        path = out / name
        fig.savefig(path, dpi=dpi)
        paths.append(path)
    return paths
