"""Tracking a robot through a map of places: odometry between factors, place factors, iSAM2, kidnap recovery.

:class:`Tracker` keeps one ``gtsam.Pose2`` per query in an incremental graph (Kaess et al., *iSAM2*, IJRR 2012):

* **between factors** from the odometry increments ``Δ = T_odom(k-1)⁻¹ T_odom(k)``, σ from the
  :class:`~factorloc.odometry_model.OdometryModel` of the increment (its per-metre and per-radian terms, with per-
  increment floors: :attr:`TrackerConfig.odometry_model`);
* **place factors**: the prediction ``x̂ = x(k-1) ∘ Δ`` (covariance ``F P Fᵀ + G Q Gᵀ``) chooses the places in
  view (:func:`~factorloc.places.places_in_view`), the hierarchy runs against them seeded by the prediction
  (:class:`~factorloc.places.MultiPlaceLocalizer`), and each place factor is **gated against the prediction**: its
  squared Mahalanobis distance to the prediction (covariance ``P̂ + R``) against the χ² quantile of
  :attr:`TrackerConfig.gate_probability` with one degree of freedom per component it measures
  (``tracker.prediction`` check). A rejected factor does not enter the graph;
* **kidnapping**: after :attr:`TrackerConfig.kidnap_after` consecutive queries with places in view but no place
  factor consistent with the prediction (all rejected by the gate, or none reliable), or when the position σ
  grown since the last place factor exceeds :attr:`TrackerConfig.lost_sigma_m`, the tracker re-localizes by place recognition
  (:class:`~factorloc.places.PlaceRecognizer`: top-k places, the hierarchy against each seeded at the pose the
  recognizer gives — the submap match's pose of the query in the place's frame, or the place with the heading of
  the signature's best shift —, their factors gated together and, like the tracking step's, sharing the query's
  error); success — at least :attr:`TrackerConfig.relocalize_min_places` places agreeing — starts a new chain (a
  new pose with no between factor to the old one), failure leaves the tracker ``LOST`` (dead reckoning, flagged).
  The chain goes on instead only when the prediction is one the tracker vouches for (position σ ≤
  :attr:`TrackerConfig.lost_sigma_m`: the re-localization was called by the kidnap rule, not by the lost rule) and
  the recognized pose passes the prediction gate against it. A prediction the lost rule gave up on is never gated
  against: one with a σ of metres "agrees" with any pose along a corridor (the case is in ``docs/places.md``).
  Recognition is already tried after :attr:`TrackerConfig.recognize_after` such queries (default 1: on the first
  such query; 2 = ``kidnap_after``: only when the kidnap rule fires), under the same acceptance rules; when it finds
  nothing there the query stays ``TRACKING`` (flagged) and the kidnap rule fires as before. A pose this early
  recognition puts elsewhere than the prediction does not switch the chain at once
  (:attr:`TrackerConfig.confirm_recognition`, ``tracker.confirmation``): on the next query the old prediction's own
  consistent place factors refute it (an aliased place recognized from one degenerate scan); the recognized pose
  moved by the odometry finding consistent factors of its places in view while the old prediction finds none
  confirms it (a kidnapping: a new chain); neither leaves the kidnap rule to fire as before;
* **ambiguity** (``tracker.unique``, :attr:`TrackerConfig.refuse_ambiguous`): a recognition whose factors fall into
  two groups of at least ``relocalize_min_places`` agreeing places on two different poses (the consistency gate
  keeps the larger) starts no chain: no count of places tells the two readings of a point-symmetric room apart;
* **confirmation of a recognized chain** (``tracker.confirmed``, :attr:`TrackerConfig.confirm_relocalization`): a
  chain recognition started from one scan is flagged until a later query's place factors pass the gate against
  its prediction (the places of one wrong pass agree with each other; the odometry tying a second scan to the
  first does not).

Every result carries its :class:`TrackState` and typed checks: the prediction gate per factor, the kidnap rule,
``tracker.confirmation`` and ``tracker.unique`` when recognition ran, ``tracker.confirmed`` on a chain recognized
from one scan until a later query confirms it,
``tracker.supported`` (failed when places were in view but none gave a factor consistent with the prediction: the
pose rests on the odometry alone, possibly after an unseen kidnapping), and ``tracker.jump`` — the squared
Mahalanobis distance of the new estimate from the prediction (3 dof), which flags any result that moved more than
the prediction's 3σ allows. The tracker never restarts silently: a new chain is always a ``RELOCALIZED`` result
with its reason.

The states, as a rule: ``TRACKING`` — the pose continues the chain from a prediction the tracker vouches for
(position σ ≤ ``lost_sigma_m``) with place factors that passed the gate against it; such a pose moves from the
prediction by no more than the prediction's 3σ region allows (``tracker.jump``, 3 dof, χ² 14.16), or that check
fails and the result is flagged (for one factor, or a recognized pose, the gate bounds the posterior's d² by the
gate's own d², ≤ 16.27; never failed on the simulated tours). ``RELOCALIZED`` — the pose comes from place
recognition and starts a new chain: it may jump by any distance; ``tracker.relocalized`` says why. ``LOST`` — no
pose vouched for.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Any

import gtsam
import numpy as np

from factorloc.config import Config
from factorloc.errors import InputError
from factorloc.fusion.graph import factors_for, noise_model
from factorloc.fusion.sequential import compose_with_covariance
from factorloc.geometry import Pose2, rotate_covariance
from factorloc.odometry_model import CHI2_3SIGMA_2DOF, GAUSSIAN_3SIGMA_TAIL, OdometryModel
from factorloc.pipeline import fuse
from factorloc.places.choose import ChoiceConfig, places_in_view
from factorloc.places.multi import MultiPlaceLocalizer, PlaceLocalization, split_step_name
from factorloc.places.placemap import PlaceMap
from factorloc.places.recognition import PlaceRecognizer, RecognitionConfig
from factorloc.stats import chi2_quantile, largest_sigma
from factorloc.types import FULL, Component, Estimate, Localization, Odometry, Query, StepReport, StepStatus
from factorloc.verdicts import Check, Unit

__all__ = ["TrackResult", "TrackState", "Tracker", "TrackerConfig", "seed_of_prediction"]

_ = CHI2_3SIGMA_2DOF  # the 2-dof 3σ ellipse; the jump check uses the 3-dof quantile of the same tail


class TrackState(StrEnum):
    """What the tracker knows after a query."""

    TRACKING = "tracking"  # the chain continues from a vouched-for prediction: no jump (else tracker.jump fails)
    RELOCALIZED = "relocalized"  # a new chain from place recognition (start-up, kidnapping, lost): the pose may jump
    LOST = "lost"  # no pose the tracker vouches for: dead reckoning from the last one, or nothing yet


def _increment_model() -> OdometryModel:
    return OdometryModel(min_sigma_m=0.005, min_sigma_rad=math.radians(0.2))


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of the :class:`Tracker`.

    Parameters
    ----------
    odometry_model
        σ of an odometry increment from its length and turn. The default keeps the library model's per-metre and
        per-radian terms (20 % of the path; 0.15 rad/rad + 0.08 rad/m, fitted on the Intel and ACES logs) with
        per-increment floors of 5 mm and 0.2° instead of the model's 5 cm and 0.3° *relation* floors (those are the
        disagreement of odometry and truth at rest, not a noise that each increment adds).
    localization
        The hierarchy's configuration (per place).
    choice
        How places are chosen around the prediction.
    recognition
        Place recognition for (re-)localization.
    relocalize_k
        How many recognized places (best by signature first) the hierarchy tries when re-localizing. The factors
        it fuses share the query's error like the tracking step's (``share_query_error``).
    relocalize_min_places
        A re-localization is accepted only when this many recognized places give factors that the consistency gate
        keeps together (one place alone can be a look-alike: measured on seed 1005, a start-up on one wrong place
        5 m off); fewer leaves the tracker ``LOST`` until a later query.
    relocalize_sigma_m, relocalize_sigma_rad
        σ of the seed the hierarchy gets at a recognized place (the pose recognition gives: see the module docstring).
    gate_probability
        Probability of the χ² gate of a place factor against the prediction.
    kidnap_after
        Consecutive queries whose place factors all fail the gate before the tracker re-localizes.
    recognize_after
        Consecutive queries with places in view and no consistent place factor after which place recognition is
        already tried, before the kidnap rule (≤ ``kidnap_after``; equal: only the kidnap rule asks it). Its answer
        is accepted under the same rules (at least ``relocalize_min_places`` agreeing places; a pose that disagrees
        with the prediction waits for the next query's confirmation, ``confirm_recognition``); when it finds nothing
        the query stays ``TRACKING`` (flagged by ``tracker.supported``) and the kidnap rule fires as before. 1 (the
        default) asks it on the very query the evidence runs out (on the kidnapped query itself). Without
        ``confirm_recognition`` 1 was worse than 2 on the real ACES log (aliased corridors re-localized wrongly at
        once); with it, 1 equals 2 there (``docs/places.md``, "Telling a kidnapping from an aliased place").
    confirm_recognition
        A recognized pose that disagrees with the prediction, found by the early recognition of
        ``recognize_after`` (before the kidnap rule fired), does not switch the chain at once: it waits for the next
        query (``tracker.confirmation``). There the old chain's prediction and the recognized pose moved by the same
        odometry increment each choose their places in view; the old chain's own factors passing its gate refute the
        recognized pose (an aliased place: the chain goes on), the recognized pose's factors (at least
        ``confirm_min_places`` passing the gate against it) with none for the old chain confirm it (a kidnapping:
        a new chain, ``RELOCALIZED``, from the recognized pose moved by the odometry and those factors); neither:
        the kidnap rule as before. A confirmation needs the place factors of a second scan taken from a pose the
        odometry ties to the first — an aliased corridor place recognized from one degenerate scan is refuted by the
        next scan, which the true pose still explains. False: the early recognition switches at once (as before).
        The kidnap rule's own recognition (after ``kidnap_after`` queries) is never held back. An early recognition
        that agrees with the prediction moves nothing either (its factors, from places chosen by appearance, do not
        enter the graph): the query goes on unsupported and the kidnap rule is left as it was.
    confirm_min_places
        How many of the recognized pose's places in view must give a factor passing the gate against it on the next
        query for ``confirm_recognition`` to confirm it.
    refuse_ambiguous
        A recognition whose dropped factors agree among themselves on a second pose (at least
        ``relocalize_min_places`` places: ``tracker.unique``) starts no chain: the majority of a handful of places is
        no evidence between the two readings of a point-symmetric room or an aliased corridor. The tracker stays
        ``LOST`` (or, for the early recognition, ``TRACKING`` flagged) and tries again on the next query. A
        recognized pose that passes the gate against a vouched-for prediction is not refused (the prediction decides).
    recognition_whole_pose
        When the recognized places' factors are gated together, a factor whose heading disagrees with the others'
        loses its position too (:attr:`~factorloc.gating.GatingConfig.heading_takes_position`): a place that read
        the query the other way along a corridor has a position of that reading, vague along the corridor, which
        would pass the position test and lend the fused pose its position under the other reading's heading.
        Dropped whole, such factors are a rival group for ``tracker.unique``.
    confirm_relocalization
        A chain that place recognition started from one scan (at start-up, by the kidnap rule, when lost, after a
        broken odometry) is flagged (``tracker.confirmed`` failed) until a later query's place factors pass the
        gate against its prediction; the first such query passes it and the chain is vouched for from there. Places
        of one wrong pass agree with each other (a corridor seen the other way), so the agreement of
        ``relocalize_min_places`` places on one scan is no confirmation; the odometry tying a second scan to the
        first is. Measured on the real logs (kidnapped starts in a map of the rest, ``docs/places.md``): every
        wrong start-up pose the tracker vouched for on its first scan found no consistent factor on the next. A
        chain started by ``confirm_recognition``'s confirmation rests on two scans already and is not held.
    lost_sigma_m
        Position σ (largest axis, m) *grown since the last query whose pose rests on place factors* beyond which
        the tracker re-localizes by place recognition. The σ the place factors themselves carry does not count:
        a map's places with their marginal covariance (σ growing with the distance from the first place, 1.5–2 m
        at the far end of ACES) would otherwise declare the tracker lost on the query after every re-localization
        there, and it would re-localize, never gated, on every query. A chain recognized from one scan and not
        confirmed yet (``confirm_relocalization``) counts its whole σ: a vague recognized pose nothing has
        confirmed is re-localized as soon as its σ exceeds the limit.
    initial_pose
        A known start (world frame); None: the first query is localized by place recognition.
    initial_covariance
        3×3 covariance of ``initial_pose`` (world frame); None: 5 cm and 2°.
    share_query_error
        The n place factors of one query share the error of the query's own scan (its pose error, its noise): with
        True (default) each one's covariance is multiplied by n before they enter the graph (tracking and
        re-localization alike), so that together they weigh as much as one (covariance intersection with equal
        weights, Julier and Uhlmann 1997: consistent whatever their correlation). False treats them as independent
        (over-confident when they are not).
    widen_when_tracking
        Whether the hierarchy's runs against the places in view of a prediction (tracking, and the confirmation of a
        recognized pose) may widen ICP's global search to every heading and the whole search radius
        (``localization.icp.global_init.widen``) when the window their seed bounds holds no reliable solution. False
        (default): such a solution lies outside the seed's window, which is the prediction's 3σ region plus a
        margin, so the gate against the prediction would drop it anyway (the searches were about a third of the
        tracker's CPU; the figures with and without: ``docs/places.md``). Re-localization at recognized places keeps
        ``localization`` as it is (a recognized heading can be far off).
    """

    odometry_model: OdometryModel = field(default_factory=_increment_model)
    localization: Config = field(default_factory=Config)
    choice: ChoiceConfig = field(default_factory=ChoiceConfig)
    recognition: RecognitionConfig = field(default_factory=RecognitionConfig)
    relocalize_k: int = 5
    relocalize_min_places: int = 2
    relocalize_sigma_m: float = 0.5
    relocalize_sigma_rad: float = 0.3
    gate_probability: float = 0.999
    kidnap_after: int = 2
    recognize_after: int = 1
    confirm_recognition: bool = True
    refuse_ambiguous: bool = True
    confirm_min_places: int = 1
    confirm_relocalization: bool = True
    recognition_whole_pose: bool = True
    lost_sigma_m: float = 1.5
    initial_pose: Pose2 | None = None
    initial_covariance: np.ndarray | None = None
    share_query_error: bool = True
    widen_when_tracking: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.odometry_model, OdometryModel):
            raise InputError(f"TrackerConfig.odometry_model must be an OdometryModel, got {type(self.odometry_model).__name__}")
        if not isinstance(self.localization, Config):
            raise InputError(f"TrackerConfig.localization must be a factorloc.Config, got {type(self.localization).__name__}")
        if not 0.0 < self.gate_probability < 1.0:
            raise InputError(f"TrackerConfig.gate_probability must be in (0, 1), got {self.gate_probability!r}")
        for name in ("relocalize_k", "kidnap_after", "recognize_after", "relocalize_min_places", "confirm_min_places"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise InputError(f"TrackerConfig.{name} must be an integer >= 1, got {v!r}")
        for name in ("relocalize_sigma_m", "relocalize_sigma_rad", "lost_sigma_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"TrackerConfig.{name} must be a finite number > 0, got {v!r}")
        if isinstance(self.recognize_after, int) and self.recognize_after > self.kidnap_after:
            raise InputError(
                f"TrackerConfig.recognize_after ({self.recognize_after}) must be <= kidnap_after ({self.kidnap_after})"
            )
        if self.initial_pose is not None and not isinstance(self.initial_pose, Pose2):
            raise InputError(f"TrackerConfig.initial_pose must be a Pose2 or None, got {type(self.initial_pose).__name__}")


@dataclass(frozen=True, eq=False)
class TrackResult:
    """The tracker's answer for one query.

    ``localization`` is a :class:`~factorloc.Localization` of the tracker's pose (world frame) and marginal
    covariance, its step reports those of the place factors tried (and ``fused_with = "tracker"``); ``state`` the
    :class:`TrackState` (the rule in the module docstring: only ``RELOCALIZED`` may jump); ``places_used`` the
    places whose factors entered the graph; ``checks`` the tracker's typed verdicts (prediction gate per factor,
    ``tracker.kidnap``, ``tracker.relocalized``, ``tracker.jump``); ``flagged`` whether any of them failed or the
    state is ``LOST``.
    """

    query_id: str
    state: TrackState
    localization: Localization
    places_used: tuple[str, ...]
    checks: tuple[Check, ...]
    predicted: Pose2 | None
    seconds: float

    @property
    def pose(self) -> Pose2:
        return self.localization.pose

    @property
    def covariance(self) -> np.ndarray:
        return self.localization.covariance

    @property
    def flagged(self) -> bool:
        """Whether the tracker vouches for no pose (``LOST``) or one of its checks failed."""
        return self.state is TrackState.LOST or any(not c.passed for c in self.checks)

    def to_dict(self) -> dict[str, Any]:
        loc = self.localization.to_dict()
        return {
            "query": self.query_id,
            "state": self.state.value,
            "pose": loc["pose"],
            "covariance": loc["covariance"],
            "sigmas": loc["sigmas"],
            "places_used": list(self.places_used),
            "flagged": self.flagged,
            "checks": [c.to_dict() for c in self.checks],
            "steps": [{"name": s["name"], "status": s["status"], "reason": s["reason"]} for s in loc["steps"]],
            "seconds": self.seconds,
        }


@dataclass(frozen=True, eq=False)
class _Candidate:
    """A recognized pose held for confirmation (:attr:`TrackerConfig.confirm_recognition`): the query it was
    recognized on, its pose and covariance there (world frame; the covariance of the inflated factors), its places
    and its distance from that query's prediction (m)."""

    query_id: str
    pose: Pose2
    covariance: np.ndarray
    places: tuple[str, ...]
    offset_m: float


def _without_widening(config: Config) -> Config:
    """``config`` with ICP's global search kept to the window its seed bounds (``global_init.widen`` off)."""
    icp = config.icp
    if not icp.global_init.widen:
        return config
    return replace(config, icp=replace(icp, global_init=replace(icp.global_init, widen=False)))


def _refuted_check(candidate: _Candidate, n_consistent: int) -> Check:
    """``tracker.confirmation`` passed: the old chain's own places gave consistent factors on the query after an early
    recognition that disagreed with it; the recognized pose was an aliased place and is dropped."""
    return Check.flag(
        "tracker.confirmation",
        "a recognized pose that disagrees with the prediction is confirmed before the chain switches",
        True,
        note=f"refuted: the prediction's places gave {n_consistent} consistent factor(s); the pose recognized at "
        f"{candidate.query_id} on {list(candidate.places)}, {candidate.offset_m:.2f} m off, is dropped as an aliased place",
    )


def _gate_check(estimate: Estimate, pred: Pose2, pred_cov: np.ndarray, probability: float) -> Check:
    idx = [{Component.X: 0, Component.Y: 1, Component.THETA: 2}[c] for c in estimate.components]
    p = pred.as_array()[idx]
    nu = np.asarray(estimate.values, dtype=np.float64) - p
    if Component.THETA in estimate.components:
        nu[-1] = math.remainder(float(nu[-1]), 2 * math.pi)
    S = pred_cov[np.ix_(idx, idx)] + estimate.covariance
    d2 = float(nu @ np.linalg.solve(S, nu))
    k = len(idx)
    return Check.at_most(
        "tracker.prediction",
        f"{estimate.step} d² against the prediction",
        d2,
        chi2_quantile(probability, k),
        Unit.SQUARED,
        note=f"χ² quantile, {k} dof, p = {probability:g}",
    )


class Tracker:
    """Follows a robot through a :class:`PlaceMap` along a stream of queries (see the module docstring).

    ``Tracker(place_map, config).update(query) -> TrackResult``, one call per query, in time order. Queries carry
    their odometry (``Query.odometry.T_world_robot``, any frame: only the increments are used); a query without
    odometry breaks the chain (the tracker re-localizes). ``chains`` counts the chains started (the start-up
    included), ``recognitions`` the place-recognition runs (each: top-k places and the hierarchy on each).
    """

    def __init__(self, place_map: PlaceMap, config: TrackerConfig | None = None) -> None:
        if not isinstance(place_map, PlaceMap):
            raise InputError(f"Tracker needs a PlaceMap, got {type(place_map).__name__}")
        if len(place_map) == 0:
            raise InputError("Tracker needs a PlaceMap with at least one place")
        self.place_map = place_map
        self.config = config or TrackerConfig()
        loc = self.config.localization
        #: The hierarchy at recognized places (re-localization): ``localization`` as given.
        self.relocalizer = MultiPlaceLocalizer(place_map, loc)
        #: The hierarchy against the places in view of a prediction (``widen_when_tracking``), on the same
        #: prepared references.
        self.multi = self.relocalizer if self.config.widen_when_tracking else self.relocalizer.sharing(_without_widening(loc))
        self._recognizer: PlaceRecognizer | None = None
        p = gtsam.ISAM2Params()
        p.setRelinearizeThreshold(0.01)
        p.relinearizeSkip = 1
        self._isam = gtsam.ISAM2(p)
        self._k = -1
        self._last: tuple[Pose2, np.ndarray] | None = None
        self._last_odometry: Pose2 | None = None
        self._rejected_run = 0
        self._candidate: _Candidate | None = None
        #: Largest position variance (m²) of the pose at the last query whose pose rests on place factors (0 for a
        #: chain started from ``initial_pose``): the part of the prediction's σ the lost rule does not count.
        self._supported_var = 0.0
        #: The query a chain started by recognition from one scan was recognized on, until a later query's place
        #: factors confirm it (``confirm_relocalization``); None for a confirmed chain.
        self._unconfirmed: str | None = None
        self.chains = 0
        self.recognitions = 0

    @property
    def recognizer(self) -> PlaceRecognizer:
        if self._recognizer is None:
            self._recognizer = PlaceRecognizer(self.place_map, self.config.recognition)
        return self._recognizer

    # --- the update ----------------------------------------------------------------------
    def update(self, query: Query) -> TrackResult:
        """Add ``query`` to the track; its :class:`TrackResult`."""
        if not isinstance(query, Query):
            raise InputError(f"query must be a factorloc.Query, got {type(query).__name__}")
        t0 = time.perf_counter()
        cfg = self.config
        odo = query.odometry.T_world_robot if query.odometry is not None else None
        delta = None if (odo is None or self._last_odometry is None) else self._last_odometry.between(odo)
        self._last_odometry = odo
        checks: list[Check] = []
        if self._last is None and cfg.initial_pose is not None and self._k < 0:
            cov0 = (
                np.diag([0.05**2, 0.05**2, math.radians(2.0) ** 2]) if cfg.initial_covariance is None else cfg.initial_covariance
            )
            prior = Estimate("initial", FULL, cfg.initial_pose.as_array(), cov0)
            return self._new_chain(query, [prior], (), (), TrackState.TRACKING, checks, t0)
        if self._last is None or delta is None:
            self._candidate = None
            return self._relocalize(query, None, checks, t0, "no pose yet" if self._last is None else "the odometry broke")
        Q = self._increment_covariance(delta)
        pred, pred_cov = compose_with_covariance(*self._last, delta, Q)
        in_view, accepted, reports, gates = self._place_factors(query, pred, pred_cov)
        checks.extend(gates)
        candidate, self._candidate = self._candidate, None
        if candidate is not None and accepted:
            checks.append(_refuted_check(candidate, len(accepted)))
        if self._unconfirmed is not None:
            checks.append(self._confirmed_check(len(accepted)))
            if accepted:
                self._unconfirmed = None
        if accepted:
            self._rejected_run = 0
        elif in_view:
            # places in view, nothing consistent with the prediction: rejected factors, or none reliable (the
            # hierarchy seeded at a wrong prediction often finds nothing)
            self._rejected_run += 1
        if in_view and not accepted:
            checks.append(
                Check.flag(
                    "tracker.supported",
                    "a place in view gave a factor consistent with the prediction",
                    False,
                    note=f"places in view {in_view}",
                    failure="the pose rests on the odometry since the last place factor",
                )
            )
        if candidate is not None and not accepted:
            confirmed = self._confirm(query, candidate, delta, Q, checks, t0)
            if confirmed is not None:
                return confirmed
        sigma_pos = largest_sigma(pred_cov)
        var_pos = sigma_pos * sigma_pos
        # a chain recognized from one scan and not confirmed yet vouches for none of its σ: all of it counts
        supported_var = 0.0 if self._unconfirmed is not None else self._supported_var
        sigma_grown = math.sqrt(max(var_pos - supported_var, 0.0))
        kidnap = self._rejected_run >= cfg.kidnap_after
        lost = sigma_grown > cfg.lost_sigma_m
        if kidnap or lost:
            checks.append(
                self._kidnap_check("kidnapping suspected: re-localizing by place recognition")
                if kidnap
                else Check.flag(
                    "tracker.kidnap",
                    "place factors consistent with the prediction",
                    False,
                    note=f"position σ grown since the last place factor {sigma_grown:.2f} m > {cfg.lost_sigma_m} m "
                    f"(σ {sigma_pos:.2f} m)",
                    failure="lost: re-localizing",
                )
            )
            why = "kidnapping" if kidnap else "lost"
            # lost: the prediction is one the tracker no longer vouches for, never gated against
            return self._relocalize(query, (pred, pred_cov, delta, Q), checks, t0, why, vouched=not lost)
        if in_view and not accepted and self._rejected_run >= cfg.recognize_after:
            # tried at once, before the kidnap rule: accepted under the same rules (>= relocalize_min_places agreeing
            # places; a pose that passes the gate against the prediction continues the chain)
            why = f"{self._rejected_run} query(ies) without a consistent place factor"
            tried = self._relocalize(query, (pred, pred_cov, delta, Q), checks, t0, why, tentative=True)
            if tried is not None:
                return tried
        accepted, _ = _sharing_query_error(accepted, cfg.share_query_error)
        return self._continue(query, pred, pred_cov, delta, Q, accepted, reports, checks, t0)

    def _continue(
        self,
        query: Query,
        pred: Pose2,
        pred_cov: np.ndarray,
        delta: Pose2,
        Q: np.ndarray,
        accepted: list[Estimate],
        reports: tuple[StepReport, ...],
        checks: list[Check],
        t0: float,
    ) -> TrackResult:
        """The chain goes on: the between factor, the accepted place factors, the jump check."""
        k = self._k + 1
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        graph.add(gtsam.BetweenFactorPose2(k - 1, k, delta.to_gtsam(), noise_model(Q)))
        values.insert(k, pred.to_gtsam())
        for e in accepted:
            for f in factors_for(e, k):
                graph.add(f)
        pose, cov = self._solve(graph, values, k)
        if accepted:
            self._supported_var = largest_sigma(cov) ** 2
        checks.append(_jump_check(pose, pred, pred_cov))
        used = tuple(dict.fromkeys(p for e in accepted if (p := split_step_name(e.step)[1]) is not None))
        return self._result(query, TrackState.TRACKING, pose, cov, reports, used, checks, pred, t0)

    def _place_factors(
        self, query: Query, pred: Pose2, pred_cov: np.ndarray
    ) -> tuple[list[str], list[Estimate], tuple[StepReport, ...], list[Check]]:
        """The places in view of ``pred``, the hierarchy against them seeded there, each factor gated against it:
        (places in view, factors that passed, the step reports, the gate checks)."""
        cfg = self.config
        scan = None if query.scan is None else query.scan.points_m
        in_view = [pid for pid, _ in places_in_view(self.place_map, pred, pred_cov, cfg.choice, scan)]
        accepted: list[Estimate] = []
        gates: list[Check] = []
        reports: tuple[StepReport, ...] = ()
        if in_view:
            seeded = replace(query, odometry=seed_of_prediction(pred, pred_cov))
            pl = self.multi.localize(seeded, in_view, use_odometry=False)
            reports = pl.localization.steps
            for r in reports:
                if r.status is not StepStatus.FUSED or r.estimate is None:
                    continue
                check = _gate_check(r.estimate, pred, pred_cov, cfg.gate_probability)
                gates.append(check)
                if check.passed:
                    accepted.append(r.estimate)
        return in_view, accepted, reports, gates

    def _confirm(
        self, query: Query, candidate: _Candidate, delta: Pose2, Q: np.ndarray, checks: list[Check], t0: float
    ) -> TrackResult | None:
        """``tracker.confirmation`` on the query after an early recognition that disagreed with the prediction (the
        old chain's prediction found no consistent factor on this query either): the recognized pose moved by the
        odometry increment, its places in view, their factors gated against it. Enough of them: a new chain
        (``RELOCALIZED``); else None (the caller goes on to the kidnap rule) with the failed check added."""
        cfg = self.config
        cpred, cpred_cov = compose_with_covariance(candidate.pose, candidate.covariance, delta, Q)
        in_view, accepted, reports, _ = self._place_factors(query, cpred, cpred_cov)
        check = Check.at_least(
            "tracker.confirmation",
            "places in view of the recognized pose (moved by the odometry) giving a factor consistent with it",
            len(accepted),
            cfg.confirm_min_places,
            note=f"recognized at {candidate.query_id} on {list(candidate.places)}, {candidate.offset_m:.2f} m from that "
            f"query's prediction; this query's prediction found no consistent factor; places in view of the "
            f"recognized pose {in_view}",
        )
        checks.append(check)
        if not check.passed:
            return None
        checks.append(
            self._kidnap_check("a recognized pose that disagreed with the prediction is confirmed by the next query: kidnapping")
        )
        checks.append(
            Check.flag(
                "tracker.relocalized",
                "re-localized by place recognition",
                True,
                note=f"recognized at {candidate.query_id}, confirmed by {len(accepted)} place(s) of this query",
            )
        )
        accepted, _ = _sharing_query_error(accepted, cfg.share_query_error)
        prior = Estimate("recognition", FULL, cpred.as_array(), cpred_cov)
        used = tuple(dict.fromkeys(p for e in accepted if (p := split_step_name(e.step)[1]) is not None))
        return self._new_chain(query, [prior, *accepted], reports, used, TrackState.RELOCALIZED, checks, t0)

    # --- helpers --------------------------------------------------------------------------
    def _confirmed_check(self, n_consistent: int) -> Check:
        """``tracker.confirmed`` on a query of a chain recognized from one scan and not confirmed yet: passed when this
        query's places gave ``n_consistent`` ≥ 1 factor(s) passing the gate against the prediction."""
        return Check.at_least(
            "tracker.confirmed",
            _CONFIRMED_RULE,
            n_consistent,
            1,
            note=f"recognized at {self._unconfirmed}",
        )

    def _kidnap_check(self, failure: str) -> Check:
        """``tracker.kidnap`` failed: ``_rejected_run`` consecutive queries gave no place factor consistent with the
        prediction; ``failure`` says what the tracker does about it."""
        return Check.flag(
            "tracker.kidnap",
            "place factors consistent with the prediction",
            False,
            note=f"{self._rejected_run} consecutive queries without a consistent place factor",
            failure=failure,
        )

    def _increment_covariance(self, delta: Pose2) -> np.ndarray:
        m = self.config.odometry_model
        d = math.hypot(delta.x, delta.y)
        s = float(m.sigma_position_m(d))
        st = float(m.sigma_heading_rad(d, abs(delta.theta)))
        return np.diag([s * s, s * s, st * st])

    def _solve(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, key: int) -> tuple[Pose2, np.ndarray]:
        self._isam.update(graph, values)
        pose = Pose2.from_gtsam(self._isam.calculateEstimatePose2(key))
        cov = rotate_covariance(np.asarray(self._isam.marginalCovariance(key)), pose.theta)
        self._k = key
        self._last = (pose, 0.5 * (cov + cov.T))
        return self._last

    def _new_chain(
        self,
        query: Query,
        factors: list[Estimate],
        reports: tuple[StepReport, ...],
        used: tuple[str, ...],
        state: TrackState,
        checks: list[Check],
        t0: float,
    ) -> TrackResult:
        k = self._k + 1
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        start = fuse(factors).pose if len(factors) > 1 else Pose2.from_array(factors[0].values)
        values.insert(k, start.to_gtsam())
        for e in factors:
            for f in factors_for(e, k):
                graph.add(f)
        self.chains += 1
        self._rejected_run = 0
        self._candidate = None
        self._unconfirmed = None
        pose, cov = self._solve(graph, values, k)
        self._supported_var = largest_sigma(cov) ** 2 if used else 0.0
        return self._result(query, state, pose, cov, reports, used, checks, None, t0)

    def _relocalize(
        self,
        query: Query,
        prediction: tuple[Pose2, np.ndarray, Pose2, np.ndarray] | None,
        checks: list[Check],
        t0: float,
        why: str,
        *,
        vouched: bool = True,
        tentative: bool = False,
    ) -> TrackResult | None:
        """Place recognition; ``prediction`` (pose, covariance, odometry increment and its covariance) is None at
        start-up or after a broken odometry; ``vouched`` is False when the lost rule called this (the prediction's
        position σ exceeds :attr:`TrackerConfig.lost_sigma_m`): the chain is then never continued. ``tentative``:
        called by :attr:`TrackerConfig.recognize_after` before the kidnap rule fired — the same acceptance rules,
        but a failure returns None (the caller goes on tracking, flagged by ``tracker.supported``) instead of a
        ``LOST`` result."""
        cfg = self.config
        self.recognitions += 1
        found = self._recognize(query)
        unique = None
        if found is not None and len(found.places_used) >= cfg.relocalize_min_places and cfg.refuse_ambiguous:
            unique = self._unique_check(found)
            checks.append(unique)
        if found is not None and len(found.places_used) >= cfg.relocalize_min_places:
            factors = [r.estimate for r in found.localization.steps if r.status is StepStatus.FUSED and r.estimate is not None]
            factors, n = _sharing_query_error(factors, cfg.share_query_error)
            note = f"{why}; places {list(found.places_used)}"
            if prediction is not None:
                pred, pred_cov, delta, Q = prediction
                if vouched:
                    # the recognized pose with the covariance of the inflated factors (the fused one × n)
                    fused = Estimate("recognition", FULL, found.pose.as_array(), found.covariance * float(max(n, 1)))
                    agree = _gate_check(fused, pred, pred_cov, cfg.gate_probability)
                    checks.append(agree)
                    if agree.passed and tentative and cfg.confirm_recognition:
                        # the early recognition agrees: it moves nothing by itself (its places were chosen by
                        # appearance, not by the prediction); the query goes on as unsupported, the kidnap rule intact
                        return None
                    if agree.passed:  # recognition confirms the prediction: the chain goes on, with these factors
                        self._rejected_run = 0
                        return self._continue(query, pred, pred_cov, delta, Q, factors, found.localization.steps, checks, t0)
                    if unique is not None and not unique.passed:
                        return self._refused(query, prediction, checks, t0, why, tentative)
                    if tentative and cfg.confirm_recognition:
                        # an early recognition that disagrees: held until the next query confirms or refutes it
                        self._candidate = _Candidate(
                            query.id,
                            found.pose,
                            found.covariance * float(max(n, 1)),
                            found.places_used,
                            math.hypot(found.pose.x - pred.x, found.pose.y - pred.y),
                        )
                        checks.append(
                            Check.flag(
                                "tracker.confirmation",
                                "a recognized pose that disagrees with the prediction is confirmed before the chain switches",
                                False,
                                note=f"{note}; {self._candidate.offset_m:.2f} m from the prediction",
                                failure="waiting for the next query's place factors around the recognized pose",
                            )
                        )
                        return None
                    note += "; the recognized pose disagrees with the prediction: a new chain"
                else:
                    note += f"; the prediction (position σ > {cfg.lost_sigma_m:g} m) is not vouched for: a new chain"
            if unique is not None and not unique.passed:
                return self._refused(query, prediction, checks, t0, why, tentative)
            if tentative:
                checks.append(
                    self._kidnap_check("place recognition on the first such query disagrees with the prediction: kidnapping")
                )
            checks.append(Check.flag("tracker.relocalized", "re-localized by place recognition", True, note=note))
            if cfg.confirm_relocalization:
                # one tracker.confirmed per result, about the chain it belongs to: the abandoned chain's is moot
                checks[:] = [c for c in checks if c.code != "tracker.confirmed"]
                checks.append(
                    Check.flag(
                        "tracker.confirmed",
                        _CONFIRMED_RULE,
                        False,
                        note=f"recognized on {list(found.places_used)}",
                        failure="unconfirmed: the next query's places must give a factor consistent with it",
                    )
                )
            result = self._new_chain(
                query, factors, found.localization.steps, found.places_used, TrackState.RELOCALIZED, checks, t0
            )
            if cfg.confirm_relocalization:
                self._unconfirmed = query.id
            return result
        return self._refused(query, prediction, checks, t0, why, tentative)

    def _refused(
        self,
        query: Query,
        prediction: tuple[Pose2, np.ndarray, Pose2, np.ndarray] | None,
        checks: list[Check],
        t0: float,
        why: str,
        tentative: bool,
    ) -> TrackResult | None:
        """Recognition gave no pose to start a chain from (too few agreeing places, or an ambiguous answer): None
        when ``tentative`` (the caller goes on tracking), else ``LOST`` — dead reckoning from the prediction, or no
        pose at all without one."""
        cfg = self.config
        if tentative:
            return None
        checks.append(
            Check.flag(
                "tracker.relocalized",
                "re-localized by place recognition",
                False,
                note=why,
                failure=f"no {cfg.relocalize_min_places} recognized places gave one consistent, unambiguous pose: lost",
            )
        )
        if prediction is None:  # nothing to dead-reckon from
            seed = query.odometry.T_world_robot if query.odometry is not None else Pose2()
            loc = Localization(seed, np.diag([math.inf] * 3), (), "tracker", FULL, cfg.localization, tuple(checks))
            self._last = None
            return TrackResult(query.id, TrackState.LOST, loc, (), tuple(checks), None, time.perf_counter() - t0)
        pred, pred_cov, delta, Q = prediction
        k = self._k + 1
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        graph.add(gtsam.BetweenFactorPose2(k - 1, k, delta.to_gtsam(), noise_model(Q)))
        values.insert(k, pred.to_gtsam())
        pose, cov = self._solve(graph, values, k)
        return self._result(query, TrackState.LOST, pose, cov, (), (), checks, pred, t0)

    def _unique_check(self, found: PlaceLocalization) -> Check:
        """``tracker.unique``: the recognized places whose factors the consistency gate dropped must not agree on a
        second pose among themselves (at least ``relocalize_min_places`` places again, fused by the same gate): a
        rival of that support is the other reading of a symmetric or aliased building, and the count of places is
        no evidence for either."""
        cfg = self.config
        rivals = [r.estimate for r in found.localization.steps if r.status is StepStatus.INCONSISTENT and r.estimate is not None]
        n_rival, where = 0, ""
        if len({split_step_name(e.step)[1] for e in rivals}) >= cfg.relocalize_min_places:
            alt = fuse(rivals, gating=cfg.localization.gating)
            if alt.determined:
                places = {split_step_name(r.name)[1] for r in alt.steps if r.status is StepStatus.FUSED}
                n_rival = len(places - {None})
                d = math.hypot(alt.pose.x - found.pose.x, alt.pose.y - found.pose.y)
                dth = math.degrees(math.remainder(alt.pose.theta - found.pose.theta, 2 * math.pi))
                where = f"; the rival pose {d:.2f} m and {dth:.0f}° from the recognized one, on {sorted(places - {None})}"
        return Check.at_most(
            "tracker.unique",
            "places agreeing on a second pose among the recognized ones",
            n_rival,
            cfg.relocalize_min_places - 1,
            note=f"recognized on {list(found.places_used)}{where}",
        )

    def _recognize(self, query: Query) -> PlaceLocalization | None:
        """Top-k places by signature, the hierarchy against each seeded there, the factors gated together."""
        cfg = self.config
        if query.scan is None and query.cloud is None and query.panorama is None:
            return None
        cands = self.recognizer.candidates(query, cfg.relocalize_k)
        factors: list[Estimate] = []
        for c in cands:
            place = self.place_map[c.place_id]
            # the match's pose of the query in the place's frame when recognition gives one (submap match), else
            # the place's position with the signature's heading
            T_place_query = c.T_place_query or Pose2(0.0, 0.0, c.theta_place_query_rad or 0.0)
            seed_pose = place.T_world_reference.compose(T_place_query)
            s = cfg.relocalize_sigma_m
            seeded = replace(query, odometry=Odometry(seed_pose, s, s, cfg.relocalize_sigma_rad))
            run = self.relocalizer.run_place(seeded, c.place_id)
            if run.localization.determined:
                factors.extend(run.factors)
        if not factors:
            return None
        gating = cfg.localization.gating
        if cfg.recognition_whole_pose:
            gating = replace(gating, heading_takes_position=True)
        loc = fuse(factors, gating=gating)
        if not loc.determined:
            return None
        used = tuple(dict.fromkeys(p for r in loc.steps if r.status is StepStatus.FUSED and (p := split_step_name(r.name)[1])))
        return PlaceLocalization(loc, used, (), ())

    def _result(
        self,
        query: Query,
        state: TrackState,
        pose: Pose2,
        cov: np.ndarray,
        reports: tuple[StepReport, ...],
        used: tuple[str, ...],
        checks: list[Check],
        pred: Pose2 | None,
        t0: float,
    ) -> TrackResult:
        loc = Localization(pose, cov, reports, "tracker", (), self.config.localization, tuple(checks))
        return TrackResult(query.id, state, loc, used, tuple(checks), pred, time.perf_counter() - t0)


#: What ``tracker.confirmed`` checks (:attr:`TrackerConfig.confirm_relocalization`).
_CONFIRMED_RULE = "a pose recognized from one scan is confirmed by a later query's place factors"


#: The 3-dof χ² quantile of the 3σ tail probability (the jump check).
def _jump_limit() -> float:
    return chi2_quantile(1.0 - GAUSSIAN_3SIGMA_TAIL, 3)


def _jump_check(pose: Pose2, pred: Pose2, pred_cov: np.ndarray) -> Check:
    """``tracker.jump``: the squared Mahalanobis distance of ``pose`` from the prediction (covariance ``pred_cov``
    alone, world frame, heading wrapped) against the 3-dof χ² quantile of the Gaussian 3σ tail (14.16): whether
    ``pose`` lies inside the prediction's own 3σ region."""
    nu = pose.as_array() - pred.as_array()
    nu[2] = math.remainder(float(nu[2]), 2 * math.pi)
    d2 = float(nu @ np.linalg.solve(pred_cov, nu))
    return Check.at_most(
        "tracker.jump",
        "d² of the estimate from the odometry's prediction",
        d2,
        _jump_limit(),
        Unit.SQUARED,
        note="3σ tail, 3 dof",
    )


def _sharing_query_error(factors: list[Estimate], share: bool) -> tuple[list[Estimate], int]:
    """The factors one query gave, each covariance × n when ``share`` and n > 1 (they share the query scan's error:
    fused, they count it once), and that factor n (1 when unchanged)."""
    n = len(factors) if share else 1
    if n <= 1:
        return factors, 1
    return [replace(e, covariance=e.covariance * float(n)) for e in factors], n


def seed_of_prediction(pose: Pose2, cov: np.ndarray) -> Odometry:
    """The prediction as the hypothesis the hierarchy is seeded with (per-axis σ: the covariance's diagonal)."""
    s = np.sqrt(np.maximum(np.diag(cov), 1e-12))
    return Odometry(pose, max(float(s[0]), 1e-3), max(float(s[1]), 1e-3), max(float(s[2]), 1e-3))
