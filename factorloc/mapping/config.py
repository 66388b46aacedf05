"""The mapping configuration (:func:`factorloc.mapping.build_map`): one frozen dataclass, as :mod:`factorloc.config`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from factorloc.errors import ConfigError
from factorloc.estimators.icp import IcpConfig
from factorloc.odometry_model import OdometryModel
from factorloc.places.recognition import RecognitionConfig

__all__ = ["ROBUST_BACK_ENDS", "MapConfig"]

#: The robust back ends :class:`MapConfig` knows: GTSAM's graduated non-convexity (``"gnc"``, truncated least
#: squares with the odometry chain as known inliers), an M-estimator on every loop closure (``"huber"``,
#: ``"cauchy"``), or plain least squares (``"none"``).
ROBUST_BACK_ENDS = ("gnc", "huber", "cauchy", "none")


@dataclass(frozen=True)
class MapConfig:
    """How a pose graph of places is built from one run (metres, radians).

    Parameters
    ----------
    place_spacing_m
        A new place (keyframe) after this much odometry path since the last one.
    place_turn_rad
        ... or after this much summed absolute rotation.
    min_scan_points
        A scan with fewer points is never a place (its pose still comes from the odometry).
    odometry
        σ of the odometry between-factors (:class:`~factorloc.odometry_model.OdometryModel`, fitted with
        :func:`~factorloc.odometry_model.fit_odometry_model`).
    icp
        The ICP step's configuration (consecutive places and loop closures).
    loop_radius_m
        Loop candidates: places whose current estimate lies within this radius plus 3σ (largest σ of the
        relative position covariance) of the new place.
    loop_max_search_m
        The search radius is capped here (a lost graph would otherwise test every place).
    loop_min_path_m
        A loop candidate is at least this much odometry path behind the new place (nearer ones are the
        consecutive chain's).
    loop_max_heading_rad
        ... and whose heading differs by at most this plus 3σθ (a 180° scanner sees nothing in common looking
        the other way).
    loop_max_candidates
        At most this many candidates (nearest first) are verified per new place.
    loop_every
        Loop closures are searched at every ``loop_every``-th place.
    global_sigma_m
        When the relative position σ of a candidate exceeds this, its ICP runs without the graph's seed (the
        step's global search over the whole circle) instead of seeded by it. The default never does in
        practice: on ACES the seedless proposals at corridor junctions were turned by ~90° (GNC switched them
        off, docs/mapping.md); far closures use the fallback's window instead.
    fallback_sigma_m
        A seeded closure whose relative position σ is at least this falls back to the step's global search in
        the seed's window when the seeded alignment is unreliable (the step's own rule); below it, it does not
        (the seeded basin covers the seed's region, and the search costs ~100× a seeded alignment).
    fallback_inflation
        The seed's covariance given to a closure that may fall back is inflated by this factor squared (σ × it:
        the streaming marginal is over-confident after a long corridor loop), and (with a factor above 1) its
        search stays in the window that seed bounds (the step's ``widen`` off; widened, ACES gained wrong
        closures: loop relations 1.0 m → 5.2 m, docs/mapping.md).
    refine_scans
        Align every scan that is not a place to its place with the ICP step (seeded by the odometry offset) and
        hang it there by the ICP pose and covariance when reliable; otherwise (or False) by the odometry offset
        with the odometry model's σ.
    scan_places
        How many places a refined scan is aligned to: 1, its nearest along the path; 2, also the place on its
        other side in time, the two offsets fused (each covariance × 2, as they share the scan's error; needs
        the marginals, else 1).
    recognition_every
        Every this many places, the place is also a place-recognition query against the older places (at least
        ``loop_min_path_m`` of path behind; :class:`~factorloc.places.PlaceRecognizer` on the streaming
        estimate's places, configured by ``recognition``), and its ``recognition_k`` best candidates not already
        proposed by proximity are verified by the ICP step seeded by the match's pose (its global search in the
        window of ``recognition_sigma_m`` / ``recognition_sigma_rad``) and, when reliable, added before the batch
        back end (whose GNC switches a wrong one off). 0 turns it off (proposals by pose proximity only).
    recognition_k
        Candidates verified per recognition query.
    recognition_sigma_m, recognition_sigma_rad
        σ of the seed a recognized candidate gives its verification (the match's lattice is 0.3 m and 6°).
    recognition
        The place recognition's configuration (a local submap per place from its neighbours within
        ``submap_radius_m``, a D2 shortlist of ``match_shortlist`` places per query).
    robust
        The robust back end (one of :data:`ROBUST_BACK_ENDS`).
    robust_scale
        Scale of the M-estimator on a loop closure's whitened error (``"huber"``, ``"cauchy"``).
    gnc_inlier_probability
        χ² probability of GNC's inlier threshold (``"gnc"``).
    """

    place_spacing_m: float = 0.5
    place_turn_rad: float = math.radians(20.0)
    min_scan_points: int = 30
    odometry: OdometryModel = field(default_factory=OdometryModel)
    icp: IcpConfig = field(default_factory=IcpConfig)
    loop_radius_m: float = 1.0
    loop_max_search_m: float = 8.0
    loop_min_path_m: float = 5.0
    loop_max_heading_rad: float = math.radians(60.0)
    loop_max_candidates: int = 3
    loop_every: int = 2
    global_sigma_m: float = 100.0
    fallback_sigma_m: float = 0.3
    fallback_inflation: float = 3.0
    refine_scans: bool = True
    scan_places: int = 2
    recognition_every: int = 0
    recognition_k: int = 3
    recognition_sigma_m: float = 0.3
    recognition_sigma_rad: float = math.radians(6.0)
    recognition: RecognitionConfig = field(default_factory=lambda: RecognitionConfig(submap_radius_m=3.0, match_shortlist=30))
    robust: str = "gnc"
    robust_scale: float = 3.0
    gnc_inlier_probability: float = 0.99

    def __post_init__(self) -> None:
        positive = ("place_spacing_m", "place_turn_rad", "loop_max_search_m", "loop_max_heading_rad", "global_sigma_m")
        for name in (
            *positive,
            "fallback_sigma_m",
            "fallback_inflation",
            "robust_scale",
            "recognition_sigma_m",
            "recognition_sigma_rad",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0.0 and math.isfinite(v)):
                raise ConfigError(f"mapping.{name} must be a finite number > 0, got {v!r}")
        for name in ("loop_radius_m", "loop_min_path_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and v >= 0.0 and math.isfinite(v)):
                raise ConfigError(f"mapping.{name} must be a finite number >= 0, got {v!r}")
        for name in ("min_scan_points", "loop_max_candidates", "loop_every", "recognition_every", "recognition_k"):
            v = getattr(self, name)
            lo = 0 if name in ("loop_max_candidates", "recognition_every") else 1
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ConfigError(f"mapping.{name} must be an integer >= {lo}, got {v!r}")
        if self.scan_places not in (1, 2) or isinstance(self.scan_places, bool):
            raise ConfigError(f"mapping.scan_places must be 1 or 2, got {self.scan_places!r}")
        if not isinstance(self.refine_scans, bool):
            raise ConfigError(f"mapping.refine_scans must be a bool, got {self.refine_scans!r}")
        if self.robust not in ROBUST_BACK_ENDS:
            raise ConfigError(f"mapping.robust must be one of {ROBUST_BACK_ENDS}, got {self.robust!r}")
        if not 0.0 < self.gnc_inlier_probability < 1.0:
            raise ConfigError(f"mapping.gnc_inlier_probability must be in (0, 1), got {self.gnc_inlier_probability!r}")
        if not isinstance(self.odometry, OdometryModel):
            raise ConfigError(f"mapping.odometry must be an OdometryModel, got {type(self.odometry).__name__}")
        if not isinstance(self.recognition, RecognitionConfig):
            raise ConfigError(f"mapping.recognition must be a RecognitionConfig, got {type(self.recognition).__name__}")
        if not isinstance(self.icp, IcpConfig):
            raise ConfigError(f"mapping.icp must be an IcpConfig, got {type(self.icp).__name__}")
