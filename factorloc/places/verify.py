"""Geometric verification of retrieved places: the ICP step run without a hypothesis against each place's own scan.

Retrieval by a signature or a coarse match ranks look-alikes together (the corridors of a floor, the rooms of one
plan). Retrieval then verification is how image localization (P.-E. Sarlin, C. Cadena, R. Siegwart and M.
Dymczyk, "From coarse to fine: robust hierarchical localization at large scale", CVPR 2019) and laser SLAM's loop
closures (W. Hess et al., "Real-time loop closure in 2D LIDAR SLAM", ICRA 2016: a candidate is accepted by its
scan match) handle it. Here a shortlist of the places :class:`~factorloc.places.PlaceRecognizer` retrieves is
verified by the ICP step of the hierarchy (:mod:`factorloc.estimators.icp`) with no hypothesis at all: its
global initialization (the correlative search over the whole window and the full circle of headings, refined by
ICP) and its reliability rules, against the place's own scan or cloud cut. A place is *verified*
(``places.verified``) when that estimate is reliable and fixes a full pose (:func:`~factorloc.gating.fixes_full_pose`,
the gating layer's undetermined-position rule): what the rules accept for a loop closure, including their
free-space test and their ambiguity tests against the distinct rivals.

:meth:`PlaceVerifier.rank` orders the shortlist: verified places first, by the score the ICP rules judged
(``icp.score``: fitness − violation weight × the share in seen-free space), then the others in retrieval order. The
shortlist's length, :data:`VERIFY_SHORTLIST`, was chosen leave one log out on the three laser logs
(``docs/places.md``, *Verifying the shortlist*). It costs one global ICP per shortlisted place (9–14 ms on a
laser scan): what a lost robot pays once per re-localization.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from factorloc._validate import positive_int
from factorloc.errors import InputError, UnusableInputError
from factorloc.estimators.base import Hypotheses
from factorloc.estimators.icp import IcpConfig, IcpReference, IcpStep
from factorloc.gating import GatingConfig, fixes_full_pose
from factorloc.places.placemap import PlaceMap
from factorloc.places.recognition import PlaceCandidate, PlaceRecognizer
from factorloc.types import Estimate, Query
from factorloc.verdicts import Check

__all__ = ["VERIFY_SHORTLIST", "PlaceVerifier", "VerifiedPlace"]

#: How many retrieved places :meth:`PlaceVerifier.rank` verifies (chosen leave one log out over 10 / 20 / 30 / 40
#: on the three laser logs, the best worst held-out log, ties to the shorter: ``docs/places.md``).
VERIFY_SHORTLIST = 20


@dataclass(frozen=True)
class VerifiedPlace:
    """One retrieved place after verification.

    ``candidate``: what retrieval returned. ``check``: ``places.verified``, passed when the ICP step's estimate
    without a hypothesis is reliable and fixes a full pose. ``estimate``: that estimate of the query pose in the
    map's world frame (the place's pose composed with the alignment), None when the place holds no scan or cloud
    or its scan is unusable (the check's note says which). ``score``: the value the ``icp.score`` rule judged
    (fitness − violation weight × the share in seen-free space, dimensionless; NaN without an estimate).
    """

    candidate: PlaceCandidate
    check: Check
    estimate: Estimate | None
    score: float

    @property
    def place_id(self) -> str:
        return self.candidate.place_id

    @property
    def verified(self) -> bool:
        return self.check.passed


def _score(est: Estimate) -> float:
    """The value the ``icp.score`` rule judged (NaN when the rules stopped before it)."""
    for c in est.checks:
        if c.code == "icp.score":
            return float(c.value)
    return math.nan


class PlaceVerifier:
    """Verifies retrieved places of ``place_map`` by the ICP step without a hypothesis (see the module).

    Each place's reference is prepared once, on first use (its KD-tree, normals and likelihood fields).

    Parameters
    ----------
    place_map
        The places (their scans or clouds are what a query is verified against).
    config
        The ICP step's configuration (default: the library's).
    """

    def __init__(self, place_map: PlaceMap, config: IcpConfig = IcpConfig()) -> None:
        if not isinstance(place_map, PlaceMap):
            raise InputError(f"place_map must be a PlaceMap, got {type(place_map).__name__}")
        if not isinstance(config, IcpConfig):
            raise InputError(f"config must be an IcpConfig, got {type(config).__name__}")
        self.place_map = place_map
        self.step = IcpStep(config)
        self._prepared: dict[str, IcpReference | UnusableInputError | None] = {}

    def _prepare(self, place_id: str) -> IcpReference | UnusableInputError | None:
        if place_id not in self._prepared:
            self._prepared[place_id] = self.step.prepare(self.place_map[place_id].reference)
        return self._prepared[place_id]

    def verify_one(self, query: Query, candidate: PlaceCandidate) -> VerifiedPlace:
        """``candidate`` verified against ``query`` (its scan, or the cut of its cloud)."""
        if not isinstance(candidate, PlaceCandidate):
            raise InputError(f"candidate must be a PlaceCandidate, got {type(candidate).__name__}")
        if candidate.place_id not in self.place_map:
            raise InputError(f"candidate place {candidate.place_id!r} is not in the place map")
        prepared = self._prepare(candidate.place_id)
        label = "the ICP step without a hypothesis fixes a reliable full pose"
        if isinstance(prepared, UnusableInputError):
            check = Check.flag("places.verified", label, False, note=f"place scan: {prepared}")
            return VerifiedPlace(candidate, check, None, math.nan)
        est = self.step.estimate(prepared, query, Hypotheses())
        if est is None:
            note = "the place holds no scan or cloud" if prepared is None else "the query holds no scan or cloud"
            return VerifiedPlace(candidate, Check.flag("places.verified", label, False, note=note), None, math.nan)
        ok = fixes_full_pose(est, GatingConfig().undetermined_sigma_m)
        note = "" if ok else ("ICP: " + est.reason if not est.reliable else "ICP does not fix the full pose")
        return VerifiedPlace(candidate, Check.flag("places.verified", label, ok, note=note), est, _score(est))

    def verify(self, query: Query, candidates: Sequence[PlaceCandidate]) -> tuple[VerifiedPlace, ...]:
        """Every candidate verified, re-ranked: the verified ones first, by their ``icp.score`` (best first; ties in
        retrieval order), then the others in retrieval order.

        Raises :class:`~factorloc.errors.InputError` when ``query`` holds neither a scan nor a cloud, or a candidate
        names a place the map does not hold."""
        if not isinstance(query, Query):
            raise InputError(f"query must be a Query, got {type(query).__name__}")
        if query.scan is None and query.cloud is None:
            raise InputError(f"query {query.id!r} has no scan or cloud: nothing to verify a place with")
        out = [self.verify_one(query, c) for c in candidates]
        order = sorted(range(len(out)), key=lambda i: (not out[i].verified, -out[i].score if out[i].verified else 0.0, i))
        return tuple(out[i] for i in order)

    def rank(
        self,
        recognizer: PlaceRecognizer,
        query: Query,
        k: int = 5,
        *,
        shortlist: int = VERIFY_SHORTLIST,
        exclude: Callable[[str], bool] | None = None,
    ) -> tuple[VerifiedPlace, ...]:
        """The ``shortlist`` places ``recognizer`` retrieves for ``query`` (``exclude`` as in
        :meth:`~factorloc.places.PlaceRecognizer.candidates`), verified and re-ranked (:meth:`verify`); the first
        ``k``. ``recognizer`` must be built over this verifier's place map."""
        k = positive_int("k", k)
        shortlist = positive_int("shortlist", shortlist)
        if recognizer.place_map is not self.place_map:
            raise InputError("recognizer and verifier must be built over the same PlaceMap")
        return self.verify(query, recognizer.candidates(query, max(k, shortlist), exclude=exclude))[:k]
