"""Localizing in a built map on the real Intel log: every 10th of the first 600 scans held back, tracked in the map of
the rest (issue 19, item 3; figures of the whole logs in docs/mapping.md, "Localizing in the map")."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from factorloc.errors import InputError
from factorloc.evaluation.map_tracking import compare_with_map, hold_back, track_in_map, track_relations


@pytest.fixture(scope="module")
def intel_600(shared_data: Path):
    from factorloc.datasets.rosbag import LaserLog, ScanTrack, read_laser_log
    from factorloc.evaluation.relations import Relations, read_relations

    full = read_laser_log(shared_data / "laser" / "intel.sort.bag")
    n = 600
    log = LaserLog(full.odometry, ScanTrack(full.scans.stamps_s[:n], full.scans.scans[:n]), full.source)
    rel = read_relations(shared_data / "laser" / "intel.relations")
    t_end = float(log.scans.stamps_s[-1])
    keep = (rel.t1_s <= t_end) & (rel.t2_s <= t_end)
    return log, Relations(rel.t1_s[keep], rel.t2_s[keep], rel.poses[keep])


def test_hold_back_keeps_the_first_scan_and_the_odometry(intel_600) -> None:
    log, _ = intel_600
    rest, held, kept = hold_back(log, 10)
    assert held[0] == 9 and kept[0] == 0 and len(held) == 60 and len(kept) == 540
    assert rest.odometry is log.odometry
    assert np.array_equal(rest.scans.stamps_s, log.scans.stamps_s[kept])
    with pytest.raises(InputError, match="every"):
        hold_back(log, 1)


def test_held_back_intel_scans_are_tracked_in_the_map_of_the_rest(intel_600) -> None:
    from factorloc.mapping import MapConfig, build_map

    log, rel = intel_600
    full = build_map(log, MapConfig())
    # places posed exactly (the map as the frame): the tracker follows the places
    exact = track_in_map(log, 10, place_covariance=False)
    assert not exact.lost.any()
    c = compare_with_map(exact, full)
    assert c["unflagged_position_rmse_cm"] < 6.0 and c["unflagged_heading_rmse_deg"] < 0.6, c
    rows = track_relations(exact, rel, log)
    assert len(rows) >= 5 and all(r.method == "track+map" for r in rows)
    assert np.mean([r.error_translation_m for r in rows]) < 0.03


def _run(flags: list[bool], errors_m: list[float]):
    from types import SimpleNamespace

    from factorloc.evaluation.map_tracking import KidnapRun

    results = tuple(SimpleNamespace(flagged=f) for f in flags)
    errors = np.column_stack([errors_m, np.zeros(len(errors_m))])
    return KidnapRun(np.arange(len(flags)), results, errors)


def test_kidnap_figures_count_the_first_vouched_for_result_of_each_run() -> None:
    from factorloc.evaluation.map_tracking import kidnap_figures

    runs = (
        _run([True, False, False], [5.0, 0.1, 0.1]),  # right on the 2nd scan
        _run([False, False, False], [3.0, 0.1, 0.1]),  # a wrong first commitment (then right)
        _run([True, True, True, True, False], [0.1, 0.1, 0.1, 0.1, 0.1]),  # right, but on the 5th scan
        _run([True, True], [4.0, 4.0]),  # never committed
    )
    f = kidnap_figures(runs)
    assert f["runs"] == 4 and f["right_within"] == 0.25 and f["wrong_commit"] == 0.25 and f["never"] == 0.25
    assert f["unflagged_wrong_rate"] == pytest.approx(1 / 6)  # six vouched-for results, one wrong
    assert f["median_scans_to_commit"] == pytest.approx(3.5)  # the right commitments: scans 2 and 5
    # a heading 15° off is wrong too (10° limit)
    turned = _run([False], [0.1])
    turned.errors[0, 1] = np.radians(15.0)
    assert kidnap_figures((turned,))["wrong_commit"] == 1.0
    with pytest.raises(InputError, match="at least one run"):
        kidnap_figures(())


def test_kidnapped_starts_on_intel_relocalize_from_no_pose(intel_600) -> None:
    from factorloc.evaluation.map_tracking import kidnap_figures, kidnapped_starts

    log, _ = intel_600
    found = kidnapped_starts(log, 10, starts=6, run_length=4)
    assert len(found.runs) == 6 and all(r.errors.shape == (4, 2) for r in found.runs)
    held = set(hold_back(log, 10)[1].tolist())
    assert all(set(r.held.tolist()) <= held for r in found.runs)  # held-back scans only: not in the map
    f = kidnap_figures(found.runs)
    # measured: every start right within 3 scans (median 2: confirmed by the second), none vouched for wrong
    assert f["right_within"] >= 5 / 6 and f["wrong_commit"] == 0.0, f
    assert f["unflagged_wrong_rate"] == 0.0, f
    with pytest.raises(InputError, match="run_length"):
        kidnapped_starts(log, 10, starts=6, run_length=0, map_result=found.map)
    with pytest.raises(InputError, match="fewer than run_length"):
        kidnapped_starts(log, 10, starts=1, run_length=61, map_result=found.map)
    with pytest.raises(InputError, match="map_result"):
        kidnapped_starts(log, 20, starts=1, run_length=2, map_result=found.map)
