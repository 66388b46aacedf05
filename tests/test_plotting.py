"""Figures: ellipse geometry against hand computation, bars against the report, files written."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse, Rectangle

from factorloc import Estimate, InputError, Pose2, ProductFusion, Query, Reference, Scan
from factorloc.estimators.base import Hypotheses
from factorloc.evaluation import Case, EvaluationSet, evaluate
from factorloc.plotting import (
    STATUS_COLORS,
    covariance_ellipse,
    plot_availability_on_axes,
    plot_estimates_on_axes,
    plot_nees_on_axes,
    save_report_figures,
)


class _Step:
    """Truth + N(0, σ²); unreliable on every third query; heading-only when ``heading_only``."""

    def __init__(self, name: str, truth: dict[str, Pose2], heading_only: bool = False) -> None:
        self.name, self.truth, self.heading_only = name, truth, heading_only
        self.rng = np.random.default_rng(len(name))

    def prepare(self, reference: Reference) -> Any:
        return None

    def estimate(self, prepared: Any, query: Query, hypotheses: Hypotheses) -> Estimate | None:
        t = self.truth[query.id]
        if self.heading_only:
            return Estimate.heading(self.name, t.theta + 0.01 * self.rng.normal(), 0.01)
        v = t.as_array() + np.array([0.05, 0.05, 0.02]) * self.rng.normal(size=3)
        return Estimate.pose(self.name, Pose2.from_array(v), 0.05, 0.05, 0.02, reliable=int(query.id[1:]) % 3 != 0, reason="x")


@pytest.fixture(scope="module")
def report():  # noqa: ANN201
    rng = np.random.default_rng(0)
    truth = {f"q{i}": Pose2(rng.uniform(0, 4), rng.uniform(0, 3), rng.uniform(-3, 3)) for i in range(9)}
    cases = tuple(Case(Query(id=k), v, ("blur",) if k == "q4" else ()) for k, v in truth.items())
    ref = Reference(scan=Scan(np.eye(2)), T_world_reference=Pose2(2.0, 1.5, 0.0))
    steps = [_Step("icp", truth), _Step("compass", truth, heading_only=True)]
    return evaluate(EvaluationSet(ref, cases, name="tiny"), ProductFusion(), steps=steps)


def test_ellipse_axes_follow_the_chi2_quantile_and_the_eigenvectors() -> None:
    w, h, a = covariance_ellipse(np.diag([4.0, 1.0]), 0.95)
    k = 5.991464547107979  # χ²₂⁻¹(0.95)
    assert w == pytest.approx(2 * math.sqrt(k * 4)) and h == pytest.approx(2 * math.sqrt(k))
    assert abs(math.sin(math.radians(a))) < 1e-9  # major axis along x
    # rotated by 30°: the major axis turns with it
    r = np.array([[math.cos(0.5236), -math.sin(0.5236)], [math.sin(0.5236), math.cos(0.5236)]])
    _, _, a30 = covariance_ellipse(r @ np.diag([4.0, 1.0]) @ r.T, 0.95)
    assert math.tan(math.radians(a30)) == pytest.approx(math.tan(0.5236), rel=1e-6)
    with pytest.raises(InputError, match="2×2"):
        covariance_ellipse(np.diag([np.inf, 1.0]))


def test_floor_plan_draws_one_ellipse_per_position_determined_result(report) -> None:  # noqa: ANN001
    ax = Figure().add_subplot()
    plot_estimates_on_axes(ax, report)
    ellipses = [p for p in ax.patches if isinstance(p, Ellipse)]
    assert len(ellipses) == 6  # queries 0, 3, 6 have only a heading: position undetermined
    first = next(r for r in report.results if r.determined[:2].all())
    assert ellipses[0].center == pytest.approx((first.pose.x, first.pose.y))
    assert ellipses[0].width == pytest.approx(covariance_ellipse(first.covariance[:2, :2])[0])


def test_availability_bars_match_the_status_rates(report) -> None:  # noqa: ANN001
    ax = Figure().add_subplot()
    plot_availability_on_axes(ax, report)
    bars = [p for p in ax.patches if isinstance(p, Rectangle)]
    fused_green = [b for b in bars if np.allclose(b.get_facecolor()[:3], _rgb(STATUS_COLORS["fused"]))]
    widths = sorted(b.get_width() for b in fused_green)
    assert widths == pytest.approx([6 / 9, 1.0])  # icp fused on 6 of 9, compass on all


def test_nees_histogram_is_a_density_over_the_fully_determined_results(report) -> None:  # noqa: ANN001
    ax = Figure().add_subplot()
    plot_nees_on_axes(ax, report, max_nees=30.0, bins=15)
    bars = [p for p in ax.patches if isinstance(p, Rectangle)]
    area = sum(b.get_width() * b.get_height() for b in bars)
    assert area == pytest.approx(1.0)
    assert any("6 results" in t.get_text() for t in ax.get_legend().get_texts())


def test_save_report_figures_writes_four_pngs(report, tmp_path: Path) -> None:  # noqa: ANN001
    paths = save_report_figures(report, tmp_path / "figs")
    assert sorted(p.name for p in paths) == ["availability.png", "calibration.png", "error_vs_distance.png", "floor_plan.png"]
    for p in paths:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 5000


def _rgb(hex_color: str) -> tuple[float, float, float]:
    return tuple(int(hex_color[i : i + 2], 16) / 255 for i in (1, 3, 5))  # type: ignore[return-value]


def test_a_track_is_drawn_with_its_ellipses_at_the_stated_confidence_and_breaks_where_it_has_no_pose() -> None:
    from factorloc.plotting import plot_places_on_axes, plot_track_errors_on_axes, plot_track_on_axes

    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [np.nan, np.nan, np.nan], [3.0, 1.0, 0.5]])
    covs = np.stack([np.diag([0.04, 0.01, 0.001])] * 4)
    truth = poses.copy()
    truth[2] = [2.0, 0.0, 0.0]
    ax = Figure().add_subplot()
    plot_track_on_axes(
        ax, poses, covs, truth=truth, states=["relocalized", "tracking", "lost", "tracking"], kidnapped=[3], confidence=0.9
    )
    ellipses = [p for p in ax.patches if isinstance(p, Ellipse)]
    assert len(ellipses) == 3  # not for the query without a pose
    half_major = math.sqrt(0.04 * -2.0 * math.log(1.0 - 0.9))  # χ²₂⁻¹(p) = −2 ln(1 − p)
    assert ellipses[0].width == pytest.approx(2.0 * half_major) and ellipses[0].height == pytest.approx(half_major)
    labels = ax.get_legend_handles_labels()[1]
    assert {"truth", "estimate", "90 % ellipse", "kidnapped (carried)", "re-localized"} <= set(labels)
    est = next(line for line in ax.lines if line.get_label() == "estimate").get_xydata()
    assert np.isnan(est[2]).all() and np.isnan(est[3]).all()  # the gap and the kidnapping both break the line
    every_other = Figure().add_subplot()
    plot_track_on_axes(every_other, poses, covs, ellipse_every=3, ellipse_scale=10.0)
    ells = [p for p in every_other.patches if isinstance(p, Ellipse)]
    assert len(ells) == 2 and ells[0].width == pytest.approx(10.0 * 2.0 * math.sqrt(0.04 * -2.0 * math.log(0.05)))
    err_ax = plot_track_errors_on_axes(Figure().add_subplot(), poses, truth + np.array([0.03, 0.04, 0.0]), kidnapped=[3])
    assert err_ax.lines[0].get_ydata()[0] == pytest.approx(5.0)  # cm
    places = plot_places_on_axes(Figure().add_subplot(), np.array([[1.0, 2.0], [3.0, 4.0]]), ["a", "b"])
    assert [t.get_text() for t in places.texts] == ["a", "b"]
    with pytest.raises(InputError, match="covariances"):
        plot_track_on_axes(Figure().add_subplot(), poses, covs[:2])
    with pytest.raises(InputError, match="ellipse_every"):
        plot_track_on_axes(Figure().add_subplot(), poses, covs, ellipse_every=0)
