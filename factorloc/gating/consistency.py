"""The consistency rule (beyond the patent): a reliable estimate that disagrees with the fusion of the others is rejected.

Like the patent's fusion, the test is per axis group: positions against positions (2 degrees of freedom),
headings against headings (1), so a full-pose estimate can lose its position and keep its heading — unless
``full_pose_whole``, where a full pose that loses its position loses its heading too. Each tested group gives
a :class:`~factorloc.verdicts.Check` (``gate.consistency.position`` / ``.heading``: the squared Mahalanobis
distance against the χ² quantile), and a heading dropped with its position a ``gate.consistency.whole_pose``
flag.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from factorloc.errors import FusionError
from factorloc.geometry import wrap_angle
from factorloc.stats import chi2_quantile
from factorloc.types import FULL, HEADING, POSITION, Component, Estimate
from factorloc.verdicts import Check, Comparison, Unit, render_checks

__all__ = ["GROUPS", "WHOLE_POSE", "WHOLE_POSE_POSITION", "Verdict", "consistency_gate", "consistency_code"]

GROUPS: dict[str, tuple[Component, ...]] = {"position": POSITION, "heading": HEADING}

#: Rule code of a heading dropped with its full pose's position.
WHOLE_POSE = "gate.consistency.whole_pose"

#: Rule code of a position dropped with its full pose's heading (``heading_takes_position``).
WHOLE_POSE_POSITION = "gate.consistency.whole_pose_position"


def consistency_code(group: str) -> str:
    """The rule code of the consistency test of ``group`` (``"position"`` or ``"heading"``)."""
    return f"gate.consistency.{group}"


@dataclass(frozen=True)
class Verdict:
    """The consistency gate's verdict on one estimate.

    ``accepted`` lists the components that pass (all, some or none); ``checks`` holds one check per group
    tested (and the whole-pose flag when the heading went with the position); ``mahalanobis_sq`` the last
    d² of each group tested.
    """

    estimate: Estimate
    accepted: tuple[Component, ...]
    checks: tuple[Check, ...] = ()
    mahalanobis_sq: dict[str, float] = field(default_factory=dict)

    @property
    def fully_accepted(self) -> bool:
        return self.accepted == self.estimate.components

    @property
    def tested(self) -> bool:
        """Whether any other step measured the same components (so that something was tested)."""
        return bool(self.checks)

    @property
    def reason(self) -> str:
        """The failed checks rendered, or whether the estimate was consistent / not tested."""
        if any(not c.passed for c in self.checks):
            return render_checks(self.checks)
        if self.checks:
            return "consistent with the other steps"
        return "consistency not tested (no other step measures the same components)"

    def accepted_estimate(self) -> Estimate | None:
        """The part of the estimate that may be fused (None if nothing is left)."""
        if not self.accepted:
            return None
        if self.fully_accepted:
            return self.estimate
        return self.estimate.marginal(self.accepted)


def _inv(m: np.ndarray) -> np.ndarray:
    """Inverses of symmetric 1×1 ``(a,)`` or 2×2 ``(a, b, d)`` (= [[a, b], [b, d]]) matrices, rows of ``m``, same packing.

    Checked before dividing: a matrix whose determinant is not above :data:`MIN_RELATIVE_DET` · a·d (a
    correlation within 5e-13 of ±1) or not finite raises :class:`~factorloc.errors.FusionError`.
    """
    m = np.asarray(m, dtype=np.float64)
    if m.shape[1] == 1:
        if not (np.isfinite(m).all() and (m > 0.0).all()):
            raise FusionError(f"consistency gate: a variance is not positive and finite: {m[:, 0].tolist()[:8]}")
        return 1.0 / m
    a, b, d = m[:, 0], m[:, 1], m[:, 2]
    det = a * d - b * b
    if not (np.isfinite(det).all() and (det > MIN_RELATIVE_DET * a * d).all() and (a > 0.0).all()):
        raise FusionError("consistency gate: a 2×2 covariance or information is singular or not finite")
    return np.stack([d / det, -b / det, a / det], axis=1)


#: The smallest determinant, relative to the product of the diagonal (1 - ρ²), the gate inverts.
MIN_RELATIVE_DET = 1e-12

Packed = tuple[float, ...]


def _others(
    rows: np.ndarray, values: np.ndarray, covariances: np.ndarray, lam: np.ndarray, lam_z: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Means and packed covariances of the products of the active estimates ``rows`` other than each one.

    A single other estimate is used as it is (its covariance, not the inverse of its information: an
    estimate unknown along one direction, 30 m vs 1 cm, loses ~7 digits in the round trip); several are
    summed in information form as the sum before it plus the sum after it (prefix and suffix sums: O(n) for
    all n leave-one-out products, and no cancellation, unlike total − own).
    """
    m = len(rows)
    if m == 2:
        swap = rows[::-1]
        return values[swap], covariances[swap]
    k = values.shape[1]

    def loo(x: np.ndarray) -> np.ndarray:
        zero = np.zeros((1, x.shape[1]))
        before = np.concatenate([zero, np.cumsum(x, axis=0)[:-1]])
        after = np.concatenate([np.cumsum(x[::-1], axis=0)[::-1][1:], zero])
        return before + after

    cov_o = _inv(loo(lam[rows]))
    b = loo(lam_z[rows])
    if k == 1:
        return cov_o * b, cov_o
    mean_o = np.stack([cov_o[:, 0] * b[:, 0] + cov_o[:, 1] * b[:, 1], cov_o[:, 1] * b[:, 0] + cov_o[:, 2] * b[:, 1]], axis=1)
    return mean_o, cov_o


def _d2(z: np.ndarray, c: np.ndarray, mean_o: np.ndarray, cov_o: np.ndarray, is_heading: bool) -> np.ndarray:
    """Squared Mahalanobis distances of estimates (values ``z``, packed covariances ``c``) from the others' products."""
    if z.shape[1] == 1:
        err = z[:, 0] - mean_o[:, 0]
        if is_heading:
            err = np.asarray(wrap_angle(err), dtype=np.float64).reshape(-1)
        return err * err / (c[:, 0] + cov_o[:, 0])
    ex, ey = z[:, 0] - mean_o[:, 0], z[:, 1] - mean_o[:, 1]
    s = _inv(c + cov_o)
    return ex * (s[:, 0] * ex + s[:, 1] * ey) + ey * (s[:, 1] * ex + s[:, 2] * ey)


def _gate_group(
    values: list[tuple[float, ...]], covariances: list[tuple[float, ...]], is_heading: bool, threshold: float
) -> tuple[dict[int, float], dict[int, float]]:
    """Worst-first rejection inside one group of estimates of the same components.

    ``values`` are k-tuples (k = 1: θ; k = 2: x, y) and ``covariances`` their packed symmetric covariances
    (see :func:`_inv`). Leave-one-out products in information form over the other active estimates
    (headings unwrapped around the most certain one). Ties (within 1e-6 relative) reject the earliest.
    Each round is O(n) (:func:`_others`), vectorized over the active estimates.

    Returns
    -------
    rejected, d2s
        Local index → d² at its rejection; local index → d² of the last complete round (survivors) or at
        rejection.
    """
    rejected: dict[int, float] = {}
    d2s: dict[int, float] = {}
    n = len(values)
    if n < 2:
        return rejected, d2s
    vals = np.array(values, dtype=np.float64)
    covs = np.array(covariances, dtype=np.float64)
    k = vals.shape[1]
    if is_heading:
        anchor = vals[int(np.argmin(covs[:, 0])), 0]  # first of the most certain
        vals = anchor + np.asarray(wrap_angle(vals - anchor), dtype=np.float64).reshape(n, 1)
    lam = _inv(covs)
    if k == 1:
        lam_z = lam * vals
    else:
        lam_z = np.stack(
            [lam[:, 0] * vals[:, 0] + lam[:, 1] * vals[:, 1], lam[:, 1] * vals[:, 0] + lam[:, 2] * vals[:, 1]], axis=1
        )
    alive = np.ones(n, dtype=bool)
    last: tuple[np.ndarray, np.ndarray] | None = None  # (rows, d²) of the last complete round
    while alive.sum() >= 2:
        rows = np.flatnonzero(alive)
        mean_o, cov_o = _others(rows, vals, covs, lam, lam_z)
        d2 = _d2(vals[rows], covs[rows], mean_o, cov_o, is_heading)
        worst, worst_d2 = None, threshold
        # the scan below keeps worst_d2 ≥ (max so far) / (1 + 1e-6), so only a strict new maximum of the prefix can
        # replace it: scanning just those (O(log m) for a random order) gives the same pick as scanning all
        before = np.concatenate([[-np.inf], np.maximum.accumulate(d2)[:-1]])
        for j in np.flatnonzero((d2 > before) & (d2 > threshold * (1.0 + 1e-6))).tolist():
            if d2[j] > worst_d2 * (1.0 + 1e-6):  # strictly worse (beyond rounding): ties keep the earliest
                worst, worst_d2 = int(rows[j]), float(d2[j])
        if worst is None:
            last = (rows, d2)
            break
        rejected[worst] = worst_d2
        d2s[worst] = worst_d2
        alive[worst] = False
    round_d2 = {} if last is None else dict(zip(last[0].tolist(), last[1].tolist(), strict=True))
    d2s.update(round_d2)  # the last complete round's distances of the survivors
    return rejected, d2s


def _members(estimates: Sequence[Estimate], is_heading: bool) -> list[int]:
    # components are (θ), (x, y) or (x, y, θ): position = the first two, heading = the last
    return [i for i, e in enumerate(estimates) if (len(e.values) != 2 if is_heading else len(e.values) >= 2)]


def _packed(estimates: Sequence[Estimate], members: list[int], is_heading: bool) -> tuple[list, list]:
    if is_heading:
        return [(float(estimates[i].values[-1]),) for i in members], [(float(estimates[i].covariance[-1, -1]),) for i in members]
    vals = [(float(estimates[i].values[0]), float(estimates[i].values[1])) for i in members]
    covs = [(float(c[0, 0]), 0.5 * float(c[0, 1] + c[1, 0]), float(c[1, 1])) for c in (estimates[i].covariance for i in members)]
    return vals, covs


def consistency_gate(
    estimates: Sequence[Estimate],
    probability: float = 0.999,
    full_pose_whole: bool = True,
    heading_takes_position: bool = False,
) -> list[Verdict]:
    """Reject the parts of reliable estimates that disagree with the others.

    For each group (position, heading), every estimate measuring it is tested against the product of the
    others in that group: if some exceed the χ² quantile of ``probability``, the one with the largest d² is
    rejected — between equal ones (two that disagree with each other only), the *earliest*, i.e. the
    cheaper and less exact step of the hierarchy — and the round repeats until the rest agree.

    Positions are tested first. With ``full_pose_whole`` (the default), a full-pose estimate that loses its
    position also loses its heading before the headings are tested: its x, y and θ are one measurement with
    one cause of failure (the odometry of a robot carried away and turned), and a heading step seeded by
    that heading would otherwise vote with it; when no other estimate measures the heading, it keeps it
    (there is nothing to vote against). ``full_pose_whole=False`` tests the two groups independently (the
    patent's per-axis view). The measurement that set this default is in ``docs/calibration/gating.md``.

    ``heading_takes_position`` (off) is the converse for full poses of one kind, such as the ICP solutions of
    several places: a full pose that loses its heading loses its position too, and the positions are tested
    again without it (until no such pose is left). A solution turned by 180° (a corridor read the other way)
    has a position of that reading; when its position is vague along the corridor it passes the position test
    and, without this, the fused pose would take the position of one reading with the heading of the other.
    """
    excluded: dict[int, tuple[list[Check], dict[str, float]]] = {}  # turned full poses: their checks and d² then
    while True:
        accepted, checks, d2_all = _gate_once(estimates, probability, full_pose_whole, set(excluded))
        if not heading_takes_position:
            break
        turned = [
            i
            for i, e in enumerate(estimates)
            if len(e.values) == 3 and i not in excluded and Component.THETA not in accepted[i] and Component.X in accepted[i]
        ]
        if not turned:
            break
        excluded.update({i: (checks[i], d2_all[i]) for i in turned})
    for i, (turned_checks, turned_d2) in sorted(excluded.items()):
        accepted[i] -= {Component.X, Component.Y, Component.THETA}
        checks[i], d2_all[i] = list(turned_checks), dict(turned_d2)
        checks[i].append(
            Check.flag(
                WHOLE_POSE_POSITION,
                "position kept with its heading",
                False,
                note="one measurement of the whole pose: its heading disagrees with the other steps'",
                failure="position dropped with its heading",
            )
        )
    return [Verdict(e, tuple(c for c in FULL if c in accepted[i]), tuple(checks[i]), d2_all[i]) for i, e in enumerate(estimates)]


def _gate_once(
    estimates: Sequence[Estimate], probability: float, full_pose_whole: bool, excluded: set[int]
) -> tuple[list[set], list[list[Check]], list[dict[str, float]]]:
    """One pass of :func:`consistency_gate` over the estimates not in ``excluded`` (a full pose whose heading was
    rejected, left out of both tests): the accepted components, the checks and the d² of each estimate."""
    accepted = [set(e.components) for e in estimates]
    checks: list[list[Check]] = [[] for _ in estimates]
    d2_all: list[dict[str, float]] = [{} for _ in estimates]
    for group, comps in GROUPS.items():  # position first: a full pose that loses it is out of the heading test
        is_heading = comps == HEADING
        members = [i for i in _members(estimates, is_heading) if i not in excluded]
        if is_heading and full_pose_whole:
            dropped = [i for i in members if len(estimates[i].values) == 3 and Component.X not in accepted[i]]
            if len(dropped) == len(members):  # no other step measures the heading: the only one there is stays
                dropped = []
            for i in dropped:
                accepted[i].discard(Component.THETA)
                checks[i].append(
                    Check.flag(
                        WHOLE_POSE,
                        "heading kept with its position",
                        False,
                        note="one measurement of the whole pose",
                        failure="heading dropped with its position",
                    )
                )
            members = [i for i in members if i not in dropped]
        vals, covs = _packed(estimates, members, is_heading)
        k = 1 if is_heading else 2
        threshold = chi2_quantile(probability, k)
        rejected, d2s = _gate_group(vals, covs, is_heading, threshold)
        for local, i in enumerate(members):
            if local not in d2s:
                continue
            d2_all[i][group] = d2s[local]
            if local in rejected:
                accepted[i] -= set(comps)
            checks[i].append(
                Check(
                    consistency_code(group),
                    f"{group} d² against the other steps",
                    local not in rejected,
                    d2s[local],
                    threshold,
                    Comparison.AT_MOST,
                    Unit.SQUARED,
                    note=f"χ² quantile, {k} dof, p = {probability:g}",
                )
            )
    return accepted, checks, d2_all
