"""Place recognition on a real laser log: a map of places along the log, recall@k on its loop relations.

The protocol (issue #18): the map holds a place every ``spacing_m`` metres of the log's odometry path (the first
scan at which the path length passes each multiple), placed at its odometry pose. For every *loop* relation
``(t1, t2)`` of the ground truth (odometry path between them ≥ ``local_threshold_m``, the boundary of
:mod:`factorloc.evaluation.relations`), the scan at ``t2`` is the query; the places taken within
``exclude_window_s / 2`` of ``t2`` are left out (the robot's own recent past); a retrieved place is *correct*
when it was built from a scan of the run of scans around ``t1`` whose odometry stays within ``neighbourhood_m``
of ``t1``'s (the scan at ``t1`` and its neighbours in time). recall@k is the share of loop relations with a
correct place among the top k.

A relation none of whose correct places is in the map (a run around ``t1`` shorter than the spacing, or all
within the excluded window) still counts, as a miss: the map is built the same way for every log.

That rule counts a place of *another pass* through the same spot as wrong, even when the ground truth itself
relates that pass to ``t2``. So each relation also gets a second rank (``RecallResult.ranks_related``): the first
retrieved place that is correct for ``(t1, t2)`` *or* for any other loop relation of the scan at ``t2`` in the
ground truth (``(t1', t2)`` or ``(t2, t1')``, its correct places found by the same rule around ``t1'``). It is a
figure beside the issue's, never instead of it: a pass the ground truth does not relate to ``t2`` still counts
as wrong.

Neither rule says whether a *verified* place's pose is right: the protocol judges the place by time, not the
alignment the verifier made. Given ``truth`` (a :class:`~factorloc.evaluation.truth.LogTruth`, the trajectory fitted
to all the relations), :func:`recognition_recall` also judges the first place of each verified ranking — the
answer a user takes — against it (``RecallResult.top_errors``): the error of its estimate of the query pose in the
place's frame, and that error's squared Mahalanobis distance under the estimate's own covariance.

With ``RecognitionConfig(rank_by="submap_match")`` each place holds a local submap: the scans whose odometry path
length lies within ``submap_half_path_m`` of the place's, stitched by odometry into its frame
(:func:`path_submaps`). A place whose submap holds a scan taken within ``exclude_window_s / 2`` of ``t2`` is left
out too, so that no scan of the query's own recent past can be retrieved through a neighbour's submap. The query
is the scan at ``t2`` alone.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from factorloc._validate import positive_int
from factorloc.datasets.rosbag import LaserLog
from factorloc.errors import InputError
from factorloc.estimators.icp import IcpConfig
from factorloc.evaluation.relations import Relations
from factorloc.evaluation.truth import LogTruth
from factorloc.geometry import Pose2, rotate_covariance, wrap_angle
from factorloc.odometry_model import CHI2_3SIGMA_2DOF
from factorloc.places import Place, PlaceMap, PlaceRecognizer, PlaceVerifier, RecognitionConfig, VerifiedPlace
from factorloc.places.recognition import local_submap
from factorloc.types import Odometry, Query, Reference

__all__ = [
    "SUBMAP_AHEAD_M",
    "SUBMAP_BEHIND_M",
    "RecallResult",
    "SimulatedRecall",
    "McTrack",
    "RecognitionEvents",
    "TrackFigures",
    "choice_recall",
    "mcl_track",
    "recognition_events",
    "correct_window_s",
    "path_submaps",
    "places_along_log",
    "recognition_recall",
    "simulated_place_map",
    "simulated_recall",
    "simulated_track",
    "track_figures",
]


#: A log place's local submap (:func:`path_submaps`): the odometry path ahead of the place and behind it (m), chosen
#: leave one log out (``docs/places.md``).
SUBMAP_AHEAD_M = 4.0
SUBMAP_BEHIND_M = 8.0


def places_along_log(log: LaserLog, spacing_m: float = 1.0) -> tuple[PlaceMap, np.ndarray]:
    """A place every ``spacing_m`` of odometry path: the map and the (N,) times of the places' scans.

    Place ``i`` has id ``p<i>`` (zero-padded), the scan at its time as reference, its odometry pose as pose.
    """
    if not (isinstance(spacing_m, (int, float)) and spacing_m > 0):
        raise InputError(f"spacing_m must be > 0, got {spacing_m!r}")
    stamps = log.scans.stamps_s
    inside = (stamps >= log.odometry.stamps_s[0]) & (stamps <= log.odometry.stamps_s[-1])
    idx = np.flatnonzero(inside)
    path = np.asarray(log.odometry.path_length_m(stamps[idx]))
    chosen, next_mark = [], 0.0
    for j, d in zip(idx, path, strict=True):
        if d >= next_mark and len(log.scans.scans[j]) > 0:
            chosen.append(int(j))
            next_mark = (math.floor(d / spacing_m) + 1) * spacing_m
    width = len(str(len(chosen)))
    places = []
    for n, j in enumerate(chosen):
        T = log.odometry.pose_at(float(stamps[j]))
        places.append(
            Place(f"p{n:0{width}d}", Reference(scan=log.scans.scans[j], T_world_reference=T, name=f"t={stamps[j]:.3f}"), T)
        )
    return PlaceMap(places), stamps[chosen]


def path_submaps(
    log: LaserLog,
    place_map: PlaceMap,
    place_t_s: np.ndarray,
    half_path_m: float,
    *,
    behind_m: float | None = None,
    scan_spacing_m: float = 0.25,
    voxel_m: float = 0.1,
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Local submaps along a log: per place, the scans whose odometry path length lies within ``half_path_m``
    ahead of the place's and ``behind_m`` behind it (default ``half_path_m``; one every ``scan_spacing_m`` of path,
    the place's own first), stitched by the odometry into the place's frame
    (:func:`~factorloc.places.recognition.local_submap`). Returns the submaps (place id → N×2 points, m) and the
    (N, 2) time span (s) of the scans each holds.

    The odometry is trusted over a few metres only: neighbours are taken along the path, never by position (a
    later pass through the same spot has drifted). A scanner that looks forward (the logs' 180°) sees the part of
    a place behind it only from the scans taken before it got there: ``behind_m`` longer than ``half_path_m``
    gives a robot coming back the other way more of what it sees.
    """
    behind = half_path_m if behind_m is None else behind_m
    for name, v in (("half_path_m", half_path_m), ("behind_m", behind)):
        if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise InputError(f"{name} must be a finite number >= 0, got {v!r}")
    stamps = log.scans.stamps_s
    inside = np.flatnonzero((stamps >= log.odometry.stamps_s[0]) & (stamps <= log.odometry.stamps_s[-1]))
    s_all = np.asarray(log.odometry.path_length_m(stamps[inside]))
    out: dict[str, np.ndarray] = {}
    spans = np.zeros((len(place_map), 2))
    for n, (place, t) in enumerate(zip(place_map, place_t_s, strict=True)):
        c = log.scans.index_at(float(t), 2e-3)
        s_c = float(log.odometry.path_length_m(float(t)))
        lo, hi = np.searchsorted(s_all, s_c - behind, "left"), np.searchsorted(s_all, s_c + half_path_m, "right")
        chosen, last = [c], -math.inf
        for j, s_j in zip(inside[lo:hi], s_all[lo:hi], strict=True):
            if j != c and len(log.scans.scans[j]) and abs(float(s_j) - last) >= scan_spacing_m:
                chosen.append(int(j))
                last = float(s_j)
        T_c = log.odometry.pose_at(float(stamps[c]))
        out[place.id] = local_submap(
            [log.scans.scans[j].points_m for j in chosen],
            [T_c.between(log.odometry.pose_at(float(stamps[j]))) for j in chosen],
            voxel_m,
        )
        spans[n] = stamps[min(chosen)], stamps[max(chosen)]
    return out, spans


def correct_window_s(log: LaserLog, t1_s: float, neighbourhood_m: float = 1.0, tolerance_s: float = 2e-3) -> tuple[float, float]:
    """The time span of the run of scans around ``t1_s`` whose odometry lies within ``neighbourhood_m`` of t1's."""
    stamps = log.scans.stamps_s
    i = log.scans.index_at(t1_s, tolerance_s)
    p1 = log.odometry.pose_at(float(stamps[i])).translation
    lo = hi = i

    def near(j: int) -> bool:
        t = float(stamps[j])
        if not (log.odometry.stamps_s[0] <= t <= log.odometry.stamps_s[-1]):
            return False
        return bool(np.linalg.norm(log.odometry.pose_at(t).translation - p1) <= neighbourhood_m)

    while lo > 0 and near(lo - 1):
        lo -= 1
    while hi < len(stamps) - 1 and near(hi + 1):
        hi += 1
    return float(stamps[lo]), float(stamps[hi])


@dataclass(frozen=True)
class RecallResult:
    """Place recognition on one log's loop relations.

    ``ranks[i]`` is the 1-based rank of the first correct place retrieved for loop relation ``i`` (``inf``: none
    among the top ``max_k``); ``heading_change_rad[i]`` the relation's |Δθ| (a 180° scanner sees little of a
    place it comes back to facing the other way); ``places`` the size of the map. ``ranks_related[i]`` (≤
    ``ranks[i]``) the rank of the first place correct for this relation or for another loop relation of the same
    query scan in the ground truth (the module docstring); None when not computed.

    ``top_errors`` (with a verified ranking and a :class:`~factorloc.evaluation.truth.LogTruth`; else None): per
    loop relation, the first verified place's estimate of the query pose against the truth, in the place's frame —
    ``[position error m, heading error rad (estimate − truth, wrapped), squared Mahalanobis distance of the
    position error (2 dof), true place–query distance m, 1 when beyond 3σ in position (χ², 2 dof) or heading]``,
    the σ the estimate's covariance plus the truth's (``LogTruth.sigma`` at both ends); a row of NaN when no
    place of the ranking is verified, or the truth cannot pose the pair (``LogTruth.relative``). ``top_verified``
    whether the ranking's first place is verified.
    """

    log: str
    places: int
    ranks: np.ndarray
    heading_change_rad: np.ndarray
    max_k: int
    ranks_related: np.ndarray | None = None
    top_errors: np.ndarray | None = None
    top_verified: np.ndarray | None = None

    def _check_k(self, k: int) -> None:
        if not 1 <= k <= self.max_k:
            raise InputError(f"k must be in [1, {self.max_k}], got {k!r}")

    def recall_at(self, k: int) -> float:
        self._check_k(k)
        return float(np.mean(self.ranks <= k)) if self.ranks.size else math.nan

    def recall_at_related(self, k: int) -> float:
        """recall@k when a place of any pass the ground truth relates to the query scan counts (module docstring)."""
        self._check_k(k)
        if self.ranks_related is None:
            raise InputError("this RecallResult has no ranks_related (computed by recognition_recall)")
        return float(np.mean(self.ranks_related <= k)) if self.ranks_related.size else math.nan

    def recall_at_facing(self, k: int, max_heading_change_rad: float = math.pi / 2) -> float:
        """recall@k over the relations whose heading changed by less than ``max_heading_change_rad``."""
        sel = self.heading_change_rad < max_heading_change_rad
        return float(np.mean(self.ranks[sel] <= k)) if sel.any() else math.nan

    def _judged(self) -> np.ndarray:
        if self.top_errors is None:
            raise InputError("this RecallResult has no top_errors (recognition_recall with verify_shortlist and truth)")
        return self.top_errors[np.isfinite(self.top_errors[:, 0])]

    def top_judged(self) -> int:
        """How many loop relations have a verified first place the truth can pose."""
        return int(self._judged().shape[0])

    def top_wrong_share(self, max_position_m: float = 0.5, max_heading_rad: float = math.radians(5.0)) -> float:
        """Share of the judged verified first places whose estimate is off by more than ``max_position_m`` or
        ``max_heading_rad`` (NaN when none is judged)."""
        e = self._judged()
        return float(np.mean((e[:, 0] > max_position_m) | (np.abs(e[:, 1]) > max_heading_rad))) if e.size else math.nan

    def top_flipped_share(self) -> float:
        """Share of the judged verified first places whose heading is off by more than 90° (a scanner that sees a
        corridor ahead aligned to the place's view the other way)."""
        e = self._judged()
        return float(np.mean(np.abs(e[:, 1]) > math.pi / 2)) if e.size else math.nan

    def top_confidently_wrong_share(self) -> float:
        """Share of the judged verified first places beyond 3σ in position (χ², 2 dof, p = 0.9973) or heading, the
        estimate's covariance plus the truth's (the relations benchmark's rule)."""
        e = self._judged()
        return float(np.mean(e[:, 4] > 0)) if e.size else math.nan

    def to_dict(self) -> dict[str, object]:
        k5 = min(5, self.max_k)
        out: dict[str, object] = {
            "log": self.log,
            "places": self.places,
            "loop_relations": int(self.ranks.size),
            "recall_at_1": self.recall_at(1),
            "recall_at_5": self.recall_at(k5),
            "facing_relations": int(np.sum(self.heading_change_rad < math.pi / 2)),
            "recall_at_1_facing": self.recall_at_facing(1),
            "recall_at_5_facing": self.recall_at_facing(k5),
        }
        if self.ranks_related is not None:
            out |= {"recall_at_1_related": self.recall_at_related(1), "recall_at_5_related": self.recall_at_related(k5)}
        if self.top_errors is not None:
            out |= {
                "top_verified": 0 if self.top_verified is None else int(np.sum(self.top_verified)),
                "top_judged": self.top_judged(),
                "top_wrong_share": self.top_wrong_share(),
                "top_flipped_share": self.top_flipped_share(),
                "top_confidently_wrong_share": self.top_confidently_wrong_share(),
            }
        return out


def _ranked(
    recognizer: PlaceRecognizer,
    verifier: PlaceVerifier | None,
    query: Query,
    k: int,
    shortlist: int,
    exclude: Callable[[str], bool] | None = None,
) -> tuple[list[str], VerifiedPlace | None]:
    """The ids of the top ``k`` places for ``query`` (retrieved, or with a verifier retrieved and verified) and the
    first of the verified ranking (None without a verifier)."""
    if verifier is None:
        return [c.place_id for c in recognizer.candidates(query, k, exclude=exclude)], None
    ranked = verifier.rank(recognizer, query, k, shortlist=shortlist, exclude=exclude)
    return [v.place_id for v in ranked], (ranked[0] if ranked else None)


def _top_error(top: VerifiedPlace | None, place_map: PlaceMap, truth: LogTruth, t_place_s: float, t_query_s: float) -> np.ndarray:
    """``RecallResult.top_errors``' row for a verified ranking's first place (NaN when unverified or unposed)."""
    nan = np.full(5, np.nan)
    if top is None or not top.verified or top.estimate is None:
        return nan
    T_true = truth.relative(t_place_s, t_query_s)
    if T_true is None:
        return nan
    est = top.estimate.marginal(("x", "y", "theta"))
    T_wr = place_map[top.place_id].T_world_reference
    T_est = T_wr.between(Pose2(*est.values))
    d = T_est.translation - T_true.translation
    dth = float(wrap_angle(T_est.theta - T_true.theta))
    # the estimate's covariance in the place's frame, plus the truth's own (both ends, LogTruth.sigma)
    cov = rotate_covariance(est.covariance, -T_wr.theta)[:2, :2] + 2.0 * np.diag(truth.sigma[:2] ** 2)
    var_th = float(est.covariance[2, 2]) + 2.0 * float(truth.sigma[2]) ** 2
    d2 = float(d @ np.linalg.solve(cov, d))
    beyond = d2 > CHI2_3SIGMA_2DOF or abs(dth) > 3.0 * math.sqrt(var_th)
    return np.array([float(np.hypot(*d)), dth, d2, float(np.hypot(*T_true.translation)), float(beyond)])


def recognition_recall(
    log: LaserLog,
    relations: Relations,
    config: RecognitionConfig = RecognitionConfig(),
    *,
    name: str = "",
    spacing_m: float = 1.0,
    neighbourhood_m: float = 1.0,
    exclude_window_s: float = 30.0,
    local_threshold_m: float = 5.0,
    max_k: int = 5,
    tolerance_s: float = 2e-3,
    indices: Sequence[int] | None = None,
    submap_half_path_m: float = SUBMAP_AHEAD_M,
    related: Relations | None = None,
    submap_behind_m: float | None = SUBMAP_BEHIND_M,
    verify_shortlist: int = 0,
    icp_config: IcpConfig | None = None,
    truth: LogTruth | None = None,
) -> RecallResult:
    """recall@k of :class:`~factorloc.places.PlaceRecognizer` on the loop relations of ``log`` (see the module).

    ``indices`` restricts to those relations (a subset for tests); only loop relations are scored.
    ``submap_half_path_m``: the length (m of odometry path) ahead of the place of its local submap when the config
    ranks by ``"submap_match"`` (:func:`path_submaps`), ``submap_behind_m`` its length behind the place (None: the
    same); the defaults, 4 m ahead and 8 m behind, were chosen leave one log out (``docs/places.md``); unused
    otherwise. ``related``: the ground truth searched for the other loop relations of each query scan
    (``RecallResult.ranks_related``); default ``relations`` — pass the whole file when ``relations`` is a subset.
    ``verify_shortlist``: when > 0, the ranks are those after geometric verification
    (:meth:`~factorloc.places.PlaceVerifier.rank`: that many places retrieved, each verified by the ICP step
    without a hypothesis, with ``icp_config`` (default the library's), the verified first); the excluded places
    are left out before the shortlist is taken. ``truth``: with a verified ranking, the first place of each is judged
    against it (``RecallResult.top_errors``; build it with :func:`~factorloc.evaluation.truth.log_truth` from the
    whole relations file).
    """
    if truth is not None and not isinstance(truth, LogTruth):
        raise InputError(f"truth must be a LogTruth, got {type(truth).__name__}")
    if truth is not None and not verify_shortlist:
        raise InputError("truth judges the verified ranking: pass verify_shortlist > 0 with it")
    place_map, place_t = places_along_log(log, spacing_m)
    spans = np.column_stack([place_t, place_t])
    submaps = None
    if config.rank_by == "submap_match":
        submaps, spans = path_submaps(
            log, place_map, place_t, submap_half_path_m, behind_m=submap_behind_m, voxel_m=config.submap_voxel_m
        )
    recognizer = PlaceRecognizer(place_map, config, submaps=submaps)
    verify_shortlist = positive_int("verify_shortlist", verify_shortlist, minimum=0)
    verifier = PlaceVerifier(place_map, icp_config or IcpConfig()) if verify_shortlist else None
    time_of = dict(zip(place_map.ids, place_t.tolist(), strict=True))
    span_of = dict(zip(place_map.ids, spans.tolist(), strict=True))
    half = exclude_window_s / 2

    def excluded(pid: str, t2: float) -> bool:
        a, b = span_of[pid]
        return abs(time_of[pid] - t2) <= half or (a <= t2 + half and b >= t2 - half)

    rel_all = relations if related is None else related
    ends = np.concatenate([np.asarray(rel_all.t1_s, dtype=np.float64), np.asarray(rel_all.t2_s, dtype=np.float64)])
    others = np.concatenate([np.asarray(rel_all.t2_s, dtype=np.float64), np.asarray(rel_all.t1_s, dtype=np.float64)])

    def first_within(ids: Sequence[str], windows: Sequence[tuple[float, float]]) -> float:
        for r, pid in enumerate(ids, start=1):
            t = time_of[pid]
            if any(lo <= t <= hi for lo, hi in windows):
                return float(r)
        return math.inf

    t_lo, t_hi = float(log.odometry.stamps_s[0]), float(log.odometry.stamps_s[-1])
    ranks, ranks_related, dth, top_errors, top_verified = [], [], [], [], []
    for i in range(len(relations)) if indices is None else indices:
        t1, t2 = float(relations.t1_s[i]), float(relations.t2_s[i])
        if log.odometry.distance_between(t1, t2)[0] < local_threshold_m:
            continue
        window = correct_window_s(log, t1, neighbourhood_m, tolerance_s)
        query = Query(scan=log.scans.at(t2, tolerance_s), id=f"t2={t2:.6f}")
        cands, top = _ranked(recognizer, verifier, query, max_k, verify_shortlist, lambda pid, t2=t2: excluded(pid, t2))
        ranks.append(first_within(cands, [window]))
        if truth is not None:
            top_verified.append(top is not None and top.verified)
            top_errors.append(_top_error(top, place_map, truth, time_of[top.place_id] if top else math.nan, t2))
        windows = [window]
        for t_other in np.unique(others[np.abs(ends - t2) <= tolerance_s]).tolist():
            if abs(t_other - t1) <= tolerance_s or not t_lo <= t_other <= t_hi:
                continue
            if log.odometry.distance_between(t_other, t2)[0] >= local_threshold_m:
                windows.append(correct_window_s(log, t_other, neighbourhood_m, tolerance_s))
        ranks_related.append(first_within(cands, windows))
        dth.append(abs(math.remainder(float(relations.poses[i, 2]), 2 * math.pi)))
    return RecallResult(
        name or log.source,
        len(place_map),
        np.array(ranks, dtype=np.float64),
        np.array(dth),
        max_k,
        np.array(ranks_related, dtype=np.float64),
        None if truth is None else np.array(top_errors, dtype=np.float64).reshape(-1, 5),
        None if truth is None else np.array(top_verified, dtype=bool),
    )


# --------------------------------------------------------------------------
# The simulator
# --------------------------------------------------------------------------
def simulated_place_map(
    world: object,
    spacing_m: float = 1.0,
    seed: int = 0,
    clearance_m: float = 0.3,
    *,
    panorama_width_px: int = 0,
    cover_m: float | None = None,
) -> PlaceMap:
    """A place on every free node of a ``spacing_m`` grid of a simulated world, and with ``cover_m`` the places that
    bring every free pose within ``cover_m`` of one: :func:`factorloc.sim.track.grid_places` (kept here for the
    callers of the first version; :func:`factorloc.sim.track.room_places` puts places in rooms)."""
    from factorloc.sim.track import grid_places

    return grid_places(world, spacing_m, seed, clearance_m, panorama_width_px=panorama_width_px, cover_m=cover_m)  # type: ignore[arg-type]


@dataclass(frozen=True)
class SimulatedRecall:
    """Place recognition on simulated queries: ``ranks`` of the first correct place (``inf``: not in the top
    ``max_k``); a place is correct when it lies within ``neighbourhood_m`` of the query's true position.
    ``covered[i]``: whether any place of the map is correct for query ``i`` at all (a query with none is a miss
    of the map's coverage, not of the recognizer)."""

    ranks: np.ndarray
    max_k: int
    seed: int
    covered: np.ndarray | None = None

    def recall_at(self, k: int) -> float:
        return float(np.mean(self.ranks <= k)) if self.ranks.size else math.nan

    @property
    def coverage(self) -> float:
        """The share of queries with a correct place in the map."""
        if self.covered is None:
            raise InputError("this SimulatedRecall has no coverage (computed by simulated_recall)")
        return float(np.mean(self.covered)) if self.covered.size else math.nan

    def recall_at_covered(self, k: int) -> float:
        """recall@k over the queries with a correct place in the map."""
        if self.covered is None:
            raise InputError("this SimulatedRecall has no coverage (computed by simulated_recall)")
        return float(np.mean(self.ranks[self.covered] <= k)) if self.covered.any() else math.nan


def simulated_recall(
    world: object,
    place_map: PlaceMap,
    n_queries: int,
    seed: int,
    config: RecognitionConfig = RecognitionConfig(),
    *,
    neighbourhood_m: float = 1.0,
    max_k: int = 5,
    clearance_m: float = 0.3,
    panorama_width_px: int = 0,
    with_scan: bool = False,
    verify_shortlist: int = 0,
    icp_config: IcpConfig | None = None,
) -> SimulatedRecall:
    """recall@k of :class:`~factorloc.places.PlaceRecognizer` on ``n_queries`` random free poses (random
    headings) of a simulated world, each sensed by a 360° laser scan — or, with ``panorama_width_px`` > 0, by a
    rendered panorama (the places must hold panoramas), and a scan too with ``with_scan``; reproducible from
    ``seed``. ``verify_shortlist`` > 0: the ranks after geometric verification of that many retrieved places
    (:meth:`~factorloc.places.PlaceVerifier.rank`, the ICP step with ``icp_config``); the queries need a scan."""
    from factorloc.sim import render_panorama, render_scan
    from factorloc.sim.motion import sample_free_pose

    verify_shortlist = positive_int("verify_shortlist", verify_shortlist, minimum=0)
    if verify_shortlist and panorama_width_px > 0 and not with_scan:
        raise InputError("verify_shortlist needs queries with a scan (with_scan=True, or no panorama)")
    rng = np.random.default_rng(seed)
    recognizer = PlaceRecognizer(place_map, config)
    verifier = PlaceVerifier(place_map, icp_config or IcpConfig()) if verify_shortlist else None
    pos = place_map.positions_m()
    ranks, covered = [], []
    for i in range(n_queries):
        T = sample_free_pose(world, rng, clearance_m)  # type: ignore[arg-type]
        if panorama_width_px > 0:
            pano = render_panorama(world, T, width_px=panorama_width_px)  # type: ignore[arg-type]
            scan = render_scan(world, T, rng=rng) if with_scan else None  # type: ignore[arg-type]
            q = Query(panorama=pano, scan=scan, id=f"q{i}")
        else:
            q = Query(scan=render_scan(world, T, rng=rng), id=f"q{i}")  # type: ignore[arg-type]
        ok = {pid for pid, d in zip(place_map.ids, np.hypot(*(pos - T.translation).T), strict=True) if d <= neighbourhood_m}
        covered.append(bool(ok))
        rank = math.inf
        for r, pid in enumerate(_ranked(recognizer, verifier, q, max_k, verify_shortlist)[0], start=1):
            if pid in ok:
                rank = r
                break
        ranks.append(rank)
    return SimulatedRecall(np.array(ranks, dtype=np.float64), max_k, seed, np.array(covered, dtype=bool))


def simulated_track(
    world: object,
    place_map: PlaceMap,
    n_queries: int,
    seed: int,
    *,
    kidnaps: int = 0,
    spacing_m: float = 0.25,
    clearance_m: float = 0.35,
) -> object:
    """A robot driving random legs through a simulated world: :func:`factorloc.sim.track.random_track` (kept here for
    the callers of the first version; :func:`factorloc.sim.track.generate_track` tours the rooms)."""
    from factorloc.sim.track import random_track

    return random_track(world, place_map, n_queries, seed, kidnaps=kidnaps, spacing_m=spacing_m, clearance_m=clearance_m)  # type: ignore[arg-type]


# --------------------------------------------------------------------------
# Tracking figures
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class TrackFigures:
    """How a tracker did on a scenario with ground truth.

    ``rmse_position_m`` / ``rmse_heading_deg``: over the results the tracker vouches for (not flagged: see
    :attr:`~factorloc.places.TrackResult.flagged`); ``rmse_position_all_m``: over every result that has a pose.
    ``confidently_wrong``: share of the unflagged results whose position error lies beyond the 3σ ellipse of their
    covariance (2-dof χ² 11.83) or whose heading error exceeds 3σθ. ``flagged``: share flagged. ``kidnaps`` and
    ``recovered_within_3``: kidnappings (queries tagged ``kidnapped``) and those after which a ``relocalized``
    result within 10 cm and 1° of the truth came within 3 queries (the kidnapped query and the two after it).
    ``median_seconds``: median wall time of an update.
    """

    queries: int
    rmse_position_m: float
    rmse_heading_deg: float
    rmse_position_all_m: float
    confidently_wrong: float
    flagged: float
    kidnaps: int
    recovered_within_3: int
    median_seconds: float

    def to_dict(self) -> dict[str, float]:
        return dict(self.__dict__)


@dataclass(frozen=True)
class RecognitionEvents:
    """How often the tracker's recognition rules acted over a run of results (counts of queries): ``held`` — an early
    recognition disagreed with the prediction and waited for confirmation; ``refuted`` — the next query's own place
    factors refuted it (an aliased place); ``confirmed`` — the next query confirmed it (a new chain);
    ``unconfirmed`` — neither (the kidnap rule went on); ``ambiguous`` — ``tracker.unique`` refused a recognition;
    ``relocalized`` — new chains."""

    held: int
    refuted: int
    confirmed: int
    unconfirmed: int
    ambiguous: int
    relocalized: int

    def to_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


def recognition_events(results: Sequence[object]) -> RecognitionEvents:
    """The :class:`RecognitionEvents` of ``results`` (:class:`~factorloc.places.TrackResult`, any order), read from
    their typed checks."""
    from factorloc.places import TrackState
    from factorloc.verdicts import Comparison

    held = refuted = confirmed = unconfirmed = ambiguous = relocalized = 0
    for r in results:
        relocalized += r.state is TrackState.RELOCALIZED  # type: ignore[attr-defined]
        for c in r.checks:  # type: ignore[attr-defined]
            if c.code == "tracker.unique" and not c.passed:
                ambiguous += 1
            elif c.code == "tracker.confirmation" and c.comparison is Comparison.FLAG:
                held += not c.passed
                refuted += c.passed
            elif c.code == "tracker.confirmation":
                confirmed += c.passed
                unconfirmed += not c.passed
    return RecognitionEvents(held, refuted, confirmed, unconfirmed, ambiguous, relocalized)


def track_figures(scenario: object, results: Sequence[object]) -> TrackFigures:
    """The :class:`TrackFigures` of ``results`` (one :class:`~factorloc.places.TrackResult` per query of
    ``scenario``, in order)."""
    from factorloc.odometry_model import CHI2_3SIGMA_2DOF
    from factorloc.places import TrackState

    qs = scenario.queries  # type: ignore[attr-defined]
    if len(qs) != len(results):
        raise InputError(f"{len(results)} results for {len(qs)} queries")
    pos_ok, th_ok, pos_all, wrong, flagged, secs = [], [], [], 0, 0, []
    good: list[bool] = []
    for q, r in zip(qs, results, strict=True):
        secs.append(r.seconds)  # type: ignore[attr-defined]
        e = np.array([r.pose.x - q.truth.x, r.pose.y - q.truth.y])  # type: ignore[attr-defined]
        eth = abs(math.remainder(r.pose.theta - q.truth.theta, 2 * math.pi))  # type: ignore[attr-defined]
        good.append(bool(np.hypot(*e) < 0.1 and eth < math.radians(1.0)))
        if r.state is TrackState.LOST and r.localization.undetermined:  # type: ignore[attr-defined]
            flagged += 1
            continue
        pos_all.append(float(e @ e))
        if r.flagged:  # type: ignore[attr-defined]
            flagged += 1
            continue
        pos_ok.append(float(e @ e))
        th_ok.append(eth * eth)
        cov = r.covariance  # type: ignore[attr-defined]
        d2 = float(e @ np.linalg.solve(cov[:2, :2], e))
        if d2 > CHI2_3SIGMA_2DOF or eth > 3.0 * math.sqrt(cov[2, 2]):
            wrong += 1
    kid = [i for i, q in enumerate(qs) if "kidnapped" in q.faults]
    recovered = sum(
        any(results[j].state is TrackState.RELOCALIZED and good[j] for j in range(i, min(i + 3, len(qs))))  # type: ignore[attr-defined]
        for i in kid
    )
    n_ok = len(pos_ok)
    return TrackFigures(
        len(qs),
        math.sqrt(np.mean(pos_ok)) if n_ok else math.nan,
        math.degrees(math.sqrt(np.mean(th_ok))) if n_ok else math.nan,
        math.sqrt(np.mean(pos_all)) if pos_all else math.nan,
        wrong / n_ok if n_ok else math.nan,
        flagged / len(qs),
        len(kid),
        int(recovered),
        float(np.median(secs)),
    )


def choice_recall(scenario: object, results: Sequence[object], place_map: PlaceMap, config: object = None) -> tuple[int, float]:
    """Place choice with a reliable hypothesis: among the queries whose true view overlaps a place (the true
    position within that place's :attr:`~factorloc.places.Place.footprint_m`) and that the tracker predicted from
    the previous pose, the share for which :func:`~factorloc.places.places_in_view` around the prediction (with the
    result's covariance) chose at least one such place. Returns (queries counted, share)."""
    from factorloc.places import ChoiceConfig, places_in_view

    cfg = config or ChoiceConfig()
    pos = place_map.positions_m()
    reach = np.array([p.footprint_m for p in place_map])
    hits, n = 0, 0
    for q, r in zip(scenario.queries, results, strict=True):  # type: ignore[attr-defined]
        if r.predicted is None or "kidnapped" in q.faults:  # type: ignore[attr-defined]
            continue
        overlapping = {
            pid for pid, d, rr in zip(place_map.ids, np.hypot(*(pos - q.truth.translation).T), reach, strict=True) if d <= rr
        }
        if not overlapping:
            continue
        n += 1
        chosen = {pid for pid, _ in places_in_view(place_map, r.predicted, r.covariance, cfg)}  # type: ignore[attr-defined]
        hits += bool(chosen & overlapping)
    return n, (hits / n if n else math.nan)


# --------------------------------------------------------------------------
# The Monte Carlo baseline along a track
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class McTrack:
    """The Monte Carlo baseline along a scenario's queries.

    ``poses`` (N×3, world frame) and ``covariances`` (N×3×3) of its belief after each query (NaN where the belief
    was undetermined: ``determined[i]`` False); ``cpu_s`` the ``time.process_time`` of each query, hierarchy runs
    included. ``rmse_position_m`` / ``rmse_heading_deg`` over the determined results (it has no flag);
    ``recovered_within_3``: kidnappings after which a determined result within 10 cm and 1° of the truth came within
    3 queries (as :class:`TrackFigures`).
    """

    poses: np.ndarray
    covariances: np.ndarray
    determined: np.ndarray
    cpu_s: np.ndarray
    rmse_position_m: float
    rmse_heading_deg: float
    kidnaps: int
    recovered_within_3: int

    def to_dict(self) -> dict[str, float]:
        return {
            "rmse_position_m": self.rmse_position_m,
            "rmse_heading_deg": self.rmse_heading_deg,
            "kidnaps": self.kidnaps,
            "recovered_within_3": self.recovered_within_3,
            "cpu_s_per_query": float(np.mean(self.cpu_s)),
            "determined": float(np.mean(self.determined)),
        }


def _mcl_reports(q: object, belief: object, tracker: object, place_map: PlaceMap, starved: int) -> list:
    """The evidence the baseline gets for query ``q``: the tracker's policy (see :func:`mcl_track`)."""
    from dataclasses import replace

    from factorloc.places import places_in_view, seed_of_prediction

    multi, relocalizer = tracker.multi, tracker.relocalizer  # type: ignore[attr-defined]
    recognizer, cfg = tracker.recognizer, tracker.config  # type: ignore[attr-defined]
    reports: list = []
    if belief is not None and starved < 2:
        ids = [pid for pid, _ in places_in_view(place_map, belief.pose, belief.covariance, cfg.choice)]  # type: ignore[attr-defined]
        if ids:
            seeded = replace(q.query, odometry=seed_of_prediction(belief.pose, belief.covariance))  # type: ignore[attr-defined]
            reports = list(multi.localize(seeded, ids, use_odometry=False).localization.steps)
    if not any(r.estimate is not None and r.estimate.reliable for r in reports):
        for c in recognizer.candidates(q.query, cfg.relocalize_k):  # type: ignore[attr-defined]
            p = place_map[c.place_id]
            T = p.T_world_reference.compose(Pose2(0.0, 0.0, c.theta_place_query_rad or 0.0))
            odo = Odometry(T, cfg.relocalize_sigma_m, cfg.relocalize_sigma_m, cfg.relocalize_sigma_rad)
            run = relocalizer.run_place(replace(q.query, odometry=odo), c.place_id)  # type: ignore[attr-defined]
            reports.extend(run.localization.steps[1:])  # the place's steps, not its (made-up) odometry seed
    return reports


def mcl_track(
    scenario: object,
    place_map: PlaceMap,
    bounds_xy: Sequence[float],
    *,
    particles: int = 2000,
    seed: int = 0,
    tracker: object = None,
) -> McTrack:
    """Run the Monte Carlo baseline (:class:`factorloc.baselines.mcl.MonteCarloLocalization`, ``particles``
    particles drawn uniformly over ``bounds_xy`` = (x0, y0, x1, y1)) along ``scenario``'s queries with the tracker's
    evidence-gathering policy: each query, the hierarchy against the places in view of its belief (seeded by it);
    when the belief is undetermined or two queries went without a reliable estimate, against the top
    ``relocalize_k`` recognized places (seeded there, heading from Scan Context). ``tracker`` (a
    :class:`~factorloc.places.Tracker` on ``place_map``, default a new one) lends its hierarchy, recognizer and
    settings; it is not updated."""
    import time

    from factorloc.baselines.mcl import MonteCarloLocalization
    from factorloc.places import Tracker, TrackerConfig

    tr = tracker if tracker is not None else Tracker(place_map, TrackerConfig())
    mcl = MonteCarloLocalization(particles, bounds_xy=tuple(bounds_xy), seed=seed)
    qs = scenario.queries  # type: ignore[attr-defined]
    n = len(qs)
    poses, covs = np.full((n, 3), np.nan), np.full((n, 3, 3), np.nan)
    determined, cpu, good = np.zeros(n, bool), np.zeros(n), np.zeros(n, bool)
    belief, starved = None, 2
    for i, q in enumerate(qs):
        c0 = time.process_time()
        reports = _mcl_reports(q, belief, tr, place_map, starved)
        belief = mcl.update(q.query, reports)
        cpu[i] = time.process_time() - c0
        starved = 0 if any(r.estimate is not None and r.estimate.reliable for r in reports) else starved + 1
        if belief.undetermined:
            belief = None
            continue
        determined[i] = True
        poses[i], covs[i] = belief.pose.as_array(), belief.covariance
        e = math.hypot(belief.pose.x - q.truth.x, belief.pose.y - q.truth.y)
        eth = abs(math.remainder(belief.pose.theta - q.truth.theta, 2 * math.pi))
        good[i] = e < 0.1 and eth < math.radians(1.0)
    truth = np.array([q.truth.as_array() for q in qs])
    err = poses[determined, :2] - truth[determined, :2]
    eth = np.remainder(poses[determined, 2] - truth[determined, 2] + math.pi, 2 * math.pi) - math.pi
    kid = [i for i, q in enumerate(qs) if "kidnapped" in q.faults]
    return McTrack(
        poses,
        covs,
        determined,
        cpu,
        math.sqrt(float(np.mean(np.sum(err**2, axis=1)))) if len(err) else math.nan,
        math.degrees(math.sqrt(float(np.mean(eth**2)))) if len(err) else math.nan,
        len(kid),
        int(sum(bool(good[i : i + 3].any()) for i in kid)),
    )
