"""Localizing in a built map on a real laser log (issue 19, item 3): held-back scans tracked through the map of the
rest, with the relations metric of Kümmerle et al. (2009) on that track.

Every ``every``-th scan of the log (indices ``every-1, 2·every-1, …``; scan 0 always stays, so the map frame — the
odometry frame at the first place — is the same as the full log's) is held back; :func:`factorloc.mapping.build_map`
maps the log without them (the odometry stays complete). The held-back scans are then tracked in time order by the
:class:`~factorloc.places.Tracker` in ``MapResult.place_map()``, each query carrying the log's odometry at its stamp.
The tracker starts at the map's own estimate of the first held-back scan: the map's pose of the scan just before it
(kept, so in the map) composed with the odometry between the two; it never sees the ground truth.

Two exact yardsticks (:func:`track_relations`, :func:`compare_with_map`):

* the **relations metric** over the ground-truth relations with at least one end held back: a held-back end is
  posed by the track, a kept end by the map of the rest (method ``"track"`` when both ends are held back,
  ``"track+map"`` when one is) — the error of ``T(t1)⁻¹·T(t2)`` against the relation, as the map's own metric;
* the **pose of each held-back scan in the full map** (built with all scans, same frame): the difference of the
  tracked pose from it, and the share of unflagged results whose position lies beyond 3σ of the tracker's own
  covariance (χ², 2 dof, p = 0.9973). The full map is itself an estimate (a scan between places is posed by its
  place and the odometry), so this measures agreement, not truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from factorloc.datasets.rosbag import LaserLog, ScanTrack
from factorloc.errors import InputError
from factorloc.evaluation.relations import Relations
from factorloc.evaluation.relations_report import RelationResult
from factorloc.geometry import Pose2
from factorloc.mapping import MapConfig, MapResult, build_map
from factorloc.mapping.result import PlaceCovariance
from factorloc.odometry_model import CHI2_3SIGMA_2DOF

__all__ = [
    "KidnapRun",
    "KidnapStarts",
    "MapTrack",
    "compare_with_map",
    "hold_back",
    "kidnap_figures",
    "kidnapped_starts",
    "track_in_map",
    "track_relations",
]


@dataclass(frozen=True, eq=False)
class MapTrack:
    """Held-back scans tracked in the map of the rest of the log.

    ``held`` / ``kept`` are indices into the full log's scans; ``map`` the :class:`MapResult` of the kept scans
    (its scan indices are positions in ``kept``); ``results`` one :class:`~factorloc.places.TrackResult` per
    held-back scan in order; ``poses`` (H, 3) and ``covariances`` (H, 3, 3) their pose (map frame, x_m, y_m,
    θ_rad) and world-frame covariance; ``map_seconds`` the wall time of the mapping.
    """

    held: np.ndarray
    kept: np.ndarray
    map: MapResult
    results: tuple
    poses: np.ndarray
    covariances: np.ndarray
    map_seconds: float

    @property
    def flagged(self) -> np.ndarray:
        return np.array([r.flagged for r in self.results], dtype=bool)

    @property
    def lost(self) -> np.ndarray:
        return np.array([r.state.value == "lost" for r in self.results], dtype=bool)

    @property
    def seconds(self) -> np.ndarray:
        return np.array([r.seconds for r in self.results], dtype=np.float64)

    def states(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for r in self.results:
            out[r.state.value] = out.get(r.state.value, 0) + 1
        return out


def hold_back(log: LaserLog, every: int) -> tuple[LaserLog, np.ndarray, np.ndarray]:
    """The log without every ``every``-th scan (indices ``every-1, 2·every-1, …``), the held and kept indices."""
    if isinstance(every, bool) or not isinstance(every, int) or every < 2:
        raise InputError(f"every must be an integer >= 2, got {every!r}")
    n = len(log.scans)
    idx = np.arange(n)
    held_mask = idx % every == every - 1
    held, kept = idx[held_mask], idx[~held_mask]
    scans = ScanTrack(log.scans.stamps_s[kept], tuple(log.scans.scans[i] for i in kept), log.scans.frame_id)
    return LaserLog(log.odometry, scans, log.source), held, kept


def track_in_map(
    log: LaserLog,
    every: int,
    map_config: MapConfig | None = None,
    tracker_config=None,  # noqa: ANN001 - TrackerConfig (imported lazily: factorloc.places is heavy)
    *,
    place_covariance: PlaceCovariance | bool = "marginal",
    map_result: MapResult | None = None,
) -> MapTrack:
    """Map ``log`` without its held-back scans, then track those through the map (see the module docstring).

    ``tracker_config``'s ``initial_pose`` is replaced by the map's estimate of the first held-back scan;
    ``place_covariance`` what covariance the places carry (:data:`~factorloc.mapping.result.PlaceCovariance`,
    :meth:`~factorloc.mapping.MapResult.place_map`); ``map_result`` a map already built from the same held-back
    log (another tracker run on it; ``map_seconds`` is then NaN).
    """
    import time
    from dataclasses import replace

    from factorloc.places import Tracker, TrackerConfig
    from factorloc.types import Odometry, Query

    rest, held, kept = hold_back(log, every)
    if len(held) == 0:
        raise InputError(f"the log has {len(log.scans)} scans: none held back with every = {every}")
    if map_result is not None:
        if len(map_result.scan_poses) != len(kept):
            raise InputError(f"map_result has {len(map_result.scan_poses)} scans, the held-back log {len(kept)}")
        result, map_seconds = map_result, math.nan
    else:
        t0 = time.perf_counter()
        result = build_map(rest, map_config or MapConfig())
        map_seconds = time.perf_counter() - t0
    stamps = log.scans.stamps_s
    cfg = replace(tracker_config or TrackerConfig(), initial_pose=_map_pose_of_held(result, kept, log, int(held[0])))
    tracker = Tracker(result.place_map(covariance=place_covariance), cfg)
    results = []
    for i in held:
        t = float(stamps[i])
        odo = Odometry(log.odometry.pose_at(t), 1.0, 1.0, 1.0)
        results.append(tracker.update(Query(scan=log.scans.scans[i], odometry=odo, id=f"scan{int(i):05d}")))
    poses = np.array([r.pose.as_array() for r in results], dtype=np.float64).reshape(-1, 3)
    covs = np.array([r.covariance for r in results], dtype=np.float64).reshape(-1, 3, 3)
    return MapTrack(held, kept, result, tuple(results), poses, covs, map_seconds)


def _kept_before(kept: np.ndarray, i: int) -> int:
    """The position in ``kept`` of the kept scan just before held-back scan ``i`` (scan 0 is always kept, so there
    is one)."""
    return int(np.searchsorted(kept, i)) - 1


def _map_pose_of_held(result: MapResult, kept: np.ndarray, log: LaserLog, i: int) -> Pose2:
    """The map's own estimate of held-back scan ``i``: the map's pose of the kept scan just before it composed with
    the odometry between the two."""
    j = _kept_before(kept, i)
    stamps = log.scans.stamps_s
    return Pose2.from_array(result.scan_poses[j]).compose(log.odometry.between(float(stamps[kept[j]]), float(stamps[i])))


def _aligned_pose_of_held(result: MapResult, kept: np.ndarray, log: LaserLog, i: int) -> Pose2:
    """Held-back scan ``i`` posed in the map of the rest by ICP against the kept scan just before it (seeded by the
    odometry between the two, :func:`~factorloc.registration.icp2d.align`): the map's pose of that scan composed
    with the alignment. The odometry alone is up to 19° off over ten scans on MIT CSAIL; the alignment of two scans
    a second apart is good to a centimetre."""
    from factorloc.registration.icp2d import align
    from factorloc.registration.prepared import prepare_target

    j = _kept_before(kept, i)
    stamps = log.scans.stamps_s
    seed = log.odometry.between(float(stamps[kept[j]]), float(stamps[i]))
    fit = align(prepare_target(np.asarray(log.scans.scans[kept[j]].points_m)), np.asarray(log.scans.scans[i].points_m), seed)
    return Pose2.from_array(result.scan_poses[j]).compose(fit.T_target_source)


@dataclass(frozen=True)
class KidnapRun:
    """A tracker started with no pose — a robot switched on, or carried, somewhere in the mapped building — on a run
    of consecutive held-back scans (:func:`kidnapped_starts`).

    ``held`` the run's scans (indices into the full log); ``results`` one
    :class:`~factorloc.places.TrackResult` per scan; ``errors`` (n, 2) each result's position (m) and heading (rad,
    wrapped) difference from the scan's pose in the map it is tracked in (:func:`kidnapped_starts`).
    """

    held: np.ndarray
    results: tuple
    errors: np.ndarray

    def committed(self) -> int | None:
        """The position in the run of the first result the tracker vouches for (not flagged), None if none."""
        for k, r in enumerate(self.results):
            if not r.flagged:
                return k
        return None

    def far(self, max_position_m: float, max_heading_rad: float) -> np.ndarray:
        """(n,) whether each result lies farther than ``max_position_m`` or ``max_heading_rad`` from the map's pose."""
        return (self.errors[:, 0] > max_position_m) | (np.abs(self.errors[:, 1]) > max_heading_rad)


@dataclass(frozen=True)
class KidnapStarts:
    """:func:`kidnapped_starts`' runs, with the map they were tracked in."""

    map: MapResult
    runs: tuple[KidnapRun, ...]


def kidnapped_starts(
    log: LaserLog,
    every: int,
    starts: int = 40,
    run_length: int = 8,
    map_config: MapConfig | None = None,
    tracker_config=None,  # noqa: ANN001 - TrackerConfig (imported lazily: factorloc.places is heavy)
    *,
    place_covariance: PlaceCovariance | bool = "marginal",
    map_result: MapResult | None = None,
) -> KidnapStarts:
    """Place recognition when lost, on a real log: the held-back scans (:func:`hold_back`) cut into ``starts`` runs
    of ``run_length`` consecutive ones, evenly spread over the log, each tracked by a fresh
    :class:`~factorloc.places.Tracker` without an initial pose in the map of the rest (``tracker_config`` with
    ``initial_pose`` removed): it must re-localize by place recognition from the first scan of each run.
    :func:`kidnap_figures` says how soon, and how often it vouches for a wrong pose.

    Each result is judged against the scan's pose in the map it is tracked in: the map's pose of the kept scan
    just before it composed with their ICP alignment (seeded by the odometry; the odometry alone is up to 19° off
    over ten scans on MIT CSAIL, and the map of all scans differs from the map of the rest by metres on ACES).
    ``map_result``: a map already built from the same held-back log.
    """
    from dataclasses import replace

    from factorloc.places import Tracker, TrackerConfig
    from factorloc.types import Odometry, Query

    if not (isinstance(starts, int) and starts >= 1 and isinstance(run_length, int) and run_length >= 1):
        raise InputError(f"starts and run_length must be integers >= 1, got {starts!r}, {run_length!r}")
    rest, held, kept = hold_back(log, every)
    if len(held) < run_length:
        raise InputError(f"{len(held)} scans held back with every = {every}: fewer than run_length = {run_length}")
    if map_result is not None and len(map_result.scan_poses) != len(kept):
        raise InputError(f"map_result has {len(map_result.scan_poses)} scans, the held-back log {len(kept)}")
    result = map_result if map_result is not None else build_map(rest, map_config or MapConfig())
    place_map = result.place_map(covariance=place_covariance)
    cfg = replace(tracker_config or TrackerConfig(), initial_pose=None)
    stamps = log.scans.stamps_s
    runs = []
    for first in np.unique(np.linspace(0, len(held) - run_length, starts).round().astype(int)).tolist():
        tracker = Tracker(place_map, cfg)
        idx = held[first : first + run_length]
        out, err = [], []
        for i in idx.tolist():
            t = float(stamps[i])
            odo = Odometry(log.odometry.pose_at(t), 1.0, 1.0, 1.0)
            r = tracker.update(Query(scan=log.scans.scans[i], odometry=odo, id=f"scan{int(i):05d}"))
            ref = _aligned_pose_of_held(result, kept, log, int(i))
            out.append(r)
            err.append((math.hypot(r.pose.x - ref.x, r.pose.y - ref.y), math.remainder(r.pose.theta - ref.theta, 2 * math.pi)))
        runs.append(KidnapRun(idx, tuple(out), np.array(err, dtype=np.float64).reshape(-1, 2)))
    return KidnapStarts(result, tuple(runs))


def kidnap_figures(
    runs: tuple[KidnapRun, ...],
    *,
    max_position_m: float = 1.0,
    max_heading_rad: float = math.radians(10.0),
    within: int = 3,
) -> dict[str, float]:
    """The figures of :func:`kidnapped_starts`' runs.

    A result is *wrong* when it lies farther than ``max_position_m`` or ``max_heading_rad`` from the scan's pose in
    the map (1 m and 10°: a wrong place, not an inaccuracy of a tracker that is where it should be). Returned:
    ``runs`` the number of runs; ``right_within`` the share of runs whose first vouched-for result
    (:meth:`KidnapRun.committed`) comes within the first ``within`` scans and is not wrong; ``wrong_commit`` the
    share whose first vouched-for result is wrong; ``never`` the share with none; ``unflagged_wrong_rate`` over
    every result of every run, the share of the vouched-for ones that are wrong (what a user would act on
    wrongly); ``median_scans_to_commit`` over the right commits (1 = the first scan).
    """
    if not runs:
        raise InputError("kidnap_figures needs at least one run")
    right, wrong, never, to_commit = 0, 0, 0, []
    unflagged = wrong_unflagged = 0
    for run in runs:
        far = run.far(max_position_m, max_heading_rad)
        flags = np.array([r.flagged for r in run.results], dtype=bool)
        unflagged += int(np.sum(~flags))
        wrong_unflagged += int(np.sum(far & ~flags))
        k = run.committed()
        if k is None:
            never += 1
        elif far[k]:
            wrong += 1
        else:
            to_commit.append(k + 1)
            right += int(k < within)
    n = len(runs)
    return {
        "runs": float(n),
        "right_within": right / n,
        "wrong_commit": wrong / n,
        "never": never / n,
        "unflagged_wrong_rate": wrong_unflagged / unflagged if unflagged else math.nan,
        "median_scans_to_commit": float(np.median(to_commit)) if to_commit else math.nan,
    }


def track_relations(
    track: MapTrack,
    relations: Relations,
    log: LaserLog,
    *,
    local_threshold_m: float = 5.0,
    tolerance_s: float = 2e-3,
) -> list[RelationResult]:
    """The relations metric over the relations with at least one end held back (see the module docstring).

    ``log`` is the full log. Method ``"track"``: both ends held back (both posed by the track); ``"track+map"``:
    one end held back, the other posed by the map of the rest. ``reliable`` = no held-back end flagged by the
    tracker; ``seconds`` the held-back ends' tracking latency (max of the two). A ``"track+map"`` relation is
    *beyond 3σ* (``confidently_wrong``, reliable ones only) when, seen from the kept end (the map's pose, taken as
    exact), the held end's position error has a squared Mahalanobis distance under the tracker's 2×2 position
    covariance (rotated into that frame) above the 2-dof χ² 3σ quantile, 11.83 (``nees_position``: that d²; NaN
    for ``"track"`` relations, never beyond 3σ).
    """
    held_pos = {int(i): k for k, i in enumerate(track.held)}
    kept_pos = {int(i): k for k, i in enumerate(track.kept)}
    flagged = track.flagged
    out: list[RelationResult] = []
    for n in range(len(relations)):
        t1, t2 = float(relations.t1_s[n]), float(relations.t2_s[n])
        try:
            a = log.scans.index_at(t1, tolerance_s)
            b = log.scans.index_at(t2, tolerance_s)
        except InputError:
            continue
        ends = [held_pos.get(a), held_pos.get(b)]
        if ends[0] is None and ends[1] is None:
            continue
        poses = []
        for scan, h in ((a, ends[0]), (b, ends[1])):
            poses.append(Pose2.from_array(track.poses[h] if h is not None else track.map.scan_poses[kept_pos[scan]]))
        true = Pose2.from_array(relations.poses[n])
        e = true.between(poses[0].between(poses[1]))
        dist, _ = log.odometry.distance_between(t1, t2)
        kind = "local" if dist < local_threshold_m else "loop"
        both = ends[0] is not None and ends[1] is not None
        hs = [h for h in ends if h is not None]
        reliable = not any(bool(flagged[h]) for h in hs)
        sec = max(track.results[h].seconds for h in hs)
        d2 = math.nan
        if not both:  # seen from the kept end (the map's pose): the held end's position error in that frame
            h = hs[0]
            ref, held_pose, rel_true = (poses[0], poses[1], true) if ends[1] is not None else (poses[1], poses[0], true.inverse())
            err = rel_true.between(ref.between(held_pose))
            c, s_ = math.cos(ref.theta), math.sin(ref.theta)
            R = np.array([[c, -s_], [s_, c]])
            P = R.T @ track.covariances[h, :2, :2] @ R
            v = np.array([err.x, err.y])
            if np.all(np.isfinite(P)):
                d2 = float(v @ np.linalg.solve(P, v))
        wrong = bool(reliable and d2 > CHI2_3SIGMA_2DOF)
        out.append(
            RelationResult(
                "track" if both else "track+map",
                n,
                kind,
                math.hypot(e.x, e.y),
                abs(math.degrees(e.theta)),
                reliable,
                wrong,
                sec,
                d2,
            )
        )
    return out


def compare_with_map(track: MapTrack, full: MapResult) -> dict[str, float]:
    """The tracked held-back scans against their pose in ``full`` (the map of all scans, same frame).

    Returns ``n``, ``position_rmse_cm``, ``position_median_cm``, ``position_p95_cm``, ``heading_rmse_deg``,
    ``beyond_3sigma`` (count among unflagged results: squared Mahalanobis distance of the position difference
    under the tracker's 2×2 position covariance above the 2-dof χ² 3σ quantile, 11.83), ``unflagged``,
    ``beyond_3sigma_rate`` (of the unflagged), ``sigma_position_median_cm`` (the tracker's largest position σ),
    the same RMSEs over the unflagged only, and ``maps_difference_rmse_cm``: the two maps' position difference on
    the kept scans (how far the map of the rest and the map of all scans disagree by themselves: the part of the
    difference that is not the tracker's).
    """
    ref = np.asarray(full.scan_poses)[track.held]
    d = track.poses[:, :2] - ref[:, :2]
    dist = np.hypot(d[:, 0], d[:, 1])
    dth = np.remainder(track.poses[:, 2] - ref[:, 2] + math.pi, 2 * math.pi) - math.pi
    unflagged = ~track.flagged
    beyond = 0
    sig = []
    for k in range(len(d)):
        P = track.covariances[k, :2, :2]
        if not np.all(np.isfinite(P)):
            continue
        sig.append(math.sqrt(max(float(np.linalg.eigvalsh(P)[-1]), 0.0)))
        if unflagged[k] and float(d[k] @ np.linalg.solve(P, d[k])) > CHI2_3SIGMA_2DOF:
            beyond += 1
    nu = int(unflagged.sum())
    km = np.asarray(track.map.scan_poses)[:, :2] - np.asarray(full.scan_poses)[track.kept, :2]
    return {
        "maps_difference_rmse_cm": 100.0 * math.sqrt(float(np.mean(np.sum(km**2, axis=1)))),
        "unflagged_position_rmse_cm": 100.0 * math.sqrt(float(np.mean(dist[unflagged] ** 2))) if nu else math.nan,
        "unflagged_heading_rmse_deg": math.degrees(math.sqrt(float(np.mean(dth[unflagged] ** 2)))) if nu else math.nan,
        "n": len(d),
        "position_rmse_cm": 100.0 * math.sqrt(float(np.mean(dist**2))),
        "position_median_cm": 100.0 * float(np.median(dist)),
        "position_p95_cm": 100.0 * float(np.percentile(dist, 95)),
        "heading_rmse_deg": math.degrees(math.sqrt(float(np.mean(dth**2)))),
        "unflagged": nu,
        "beyond_3sigma": beyond,
        "beyond_3sigma_rate": beyond / nu if nu else math.nan,
        "sigma_position_median_cm": 100.0 * float(np.median(sig)) if sig else math.nan,
    }
