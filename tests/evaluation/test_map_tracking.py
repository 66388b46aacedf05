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
