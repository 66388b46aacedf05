"""The ICP step's configuration: one frozen root of a few nested groups (metres, radians).

Layout after kiss-icp's config: each group holds the knobs of one part of the step, and the root composes
them. Every value is validated where it is defined and a bad one raises :class:`~factorloc.errors.ConfigError`
naming its key (``icp.<group>.<field>``). YAML (``factorloc.config.Config.from_yaml``) nests the same way::

    icp:
      reliability: {min_fitness: 0.3}
      global_init: {enabled: false}

How each default was measured is in ``docs/calibration/icp.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from factorloc.errors import ConfigError, InputError
from factorloc.registration.global_search import GlobalSearchParams
from factorloc.registration.icp2d import IcpParams
from factorloc.registration.kernels import kernel_from_name
from factorloc.registration.scan2d import ScanExtraction

__all__ = [
    "AlignmentConfig",
    "CovarianceConfig",
    "GlobalInitConfig",
    "IcpConfig",
    "ReliabilityConfig",
    "SeedConfig",
]

COVARIANCE_MODELS = ("censi", "hessian", "chamfer")


def _positive(group: str, obj: object, *names: str) -> None:
    for name in names:
        v = getattr(obj, name)
        if not v > 0.0:
            raise ConfigError(f"icp.{group}.{name} must be > 0, got {v!r}")


def _non_negative(group: str, obj: object, *names: str) -> None:
    for name in names:
        v = getattr(obj, name)
        if not v >= 0.0:
            raise ConfigError(f"icp.{group}.{name} must be >= 0, got {v!r}")


def _unit(group: str, obj: object, *names: str, open_low: bool = False) -> None:
    for name in names:
        v = getattr(obj, name)
        ok = (0.0 < v <= 1.0) if open_low else (0.0 <= v <= 1.0)
        if not ok:
            raise ConfigError(f"icp.{group}.{name} must be in {'(0' if open_low else '[0'}, 1], got {v!r}")


def _seeded_icp() -> IcpParams:
    return IcpParams(min_correspondence_m=0.1, convergence_translation_m=1e-3, convergence_rotation_rad=3e-4, reassociate_m=0.01)


def _global_icp() -> IcpParams:
    return IcpParams(min_correspondence_m=0.1)


@dataclass(frozen=True)
class AlignmentConfig:
    """How a query scan is aligned to the reference (point-to-line ICP, :func:`factorloc.registration.icp2d.align`).

    Parameters
    ----------
    icp
        ICP parameters of the seeded alignment.
    global_icp
        ICP parameters refining the global-initialization candidates (converged more tightly: the candidates
        are ranked by their scores at the solution).
    kernel
        Robust kernel (``"cauchy"``, ``"huber"``, ``"tukey"``, ``"l2"``).
    kernel_scale_m
        The kernel's scale (m).
    seed_gate_margin_m
        The seeded alignment's first correspondence gate is ``3σ_seed + margin`` (m; σ_seed combines the
        position σ and the heading σ times the median range), clipped to ``icp``'s gates.
    gap_free_m
        Bearings without a return inside a scan's field of view count as seen free up to this range (m; 0 =
        unknown), see :func:`~factorloc.registration.scan2d.polar_profile`.
    """

    icp: IcpParams = field(default_factory=_seeded_icp)
    global_icp: IcpParams = field(default_factory=_global_icp)
    kernel: str = "cauchy"
    kernel_scale_m: float = 0.05
    seed_gate_margin_m: float = 0.1
    gap_free_m: float = 2.0

    def __post_init__(self) -> None:
        try:
            kernel_from_name(self.kernel, self.kernel_scale_m)
        except InputError as exc:
            raise ConfigError(f"icp.alignment.kernel: {exc}") from exc
        _non_negative("alignment", self, "seed_gate_margin_m", "gap_free_m")


@dataclass(frozen=True)
class CovarianceConfig:
    """The covariance of an ICP solution (:mod:`factorloc.estimators.icp.covariance`).

    ``Σ = inflation · (scale · Σ_white + D Σ_bias D) + diag(f_m², f_m², f_rad²)``.

    Parameters
    ----------
    model
        ``Σ_white``: ``"censi"`` (Censi, ICRA 2007, with the residual sandwich), ``"hessian"`` (Bengtsson &
        Baerveldt 2003) or ``"chamfer"`` (the patent's isotropic σ from the Chamfer distance).
    scale
        Factor on ``Σ_white``.
    inflation
        Factor on the sum of the two terms (before the floors).
    bias_rmse_ratio
        σ_b of the correlated per-point error term ``Σ_bias = σ_b² (H/Σw)⁻¹``
        (:func:`~factorloc.registration.covariance.bias_covariance`) as a multiple of the fit's inlier RMSE,
        for a laser scan query.
    bias_rmse_ratio_cloud
        The same for a query that is the cut of a depth cloud.
    bias_heading_scale
        ``D = diag(1, 1, k)``: the heading σ of the correlated term times ``k``.
    bias_fitness_ref
        When > 0, σ_b is multiplied by ``max(1, bias_fitness_ref / fitness)`` (0: off).
    weak_exponent
        ``p``: along the weakest direction of the position (the smallest eigenvalue λ of the normal scatter,
        :func:`~factorloc.estimators.icp.constraint_strength`) the correlated term's variance is ``σ_b² / λ^p``
        instead of ``σ_b² / λ`` (1: off). A direction few features constrain is where a seeded ICP stays near its
        seed: its estimate there is partly the seed's, and a fusion with that seed must not count it twice.
    sigma_floor_m, sigma_floor_rad
        Floors ``f`` added in quadrature: the error no statistic of the pair shows (the ground truth's own error,
        the sensor's motion during the sweep, its mounting).
    chamfer_scale
        σ = ``chamfer_scale`` · Chamfer distance for the ``"chamfer"`` model.
    """

    model: str = "censi"
    scale: float = 1.0
    inflation: float = 1.0
    bias_rmse_ratio: float = 0.75
    bias_rmse_ratio_cloud: float = 0.2
    bias_heading_scale: float = 0.85
    bias_fitness_ref: float = 0.0
    weak_exponent: float = 1.25
    sigma_floor_m: float = 0.0075
    sigma_floor_rad: float = 0.004
    chamfer_scale: float = 0.5

    def __post_init__(self) -> None:
        if self.model not in COVARIANCE_MODELS:
            raise ConfigError(f"icp.covariance.model must be one of {COVARIANCE_MODELS}, got {self.model!r}")
        _positive("covariance", self, "scale", "inflation", "chamfer_scale", "bias_heading_scale")
        if not 1.0 <= self.weak_exponent <= 3.0:
            raise ConfigError(f"icp.covariance.weak_exponent must be in [1, 3], got {self.weak_exponent!r}")
        _non_negative(
            "covariance", self, "bias_rmse_ratio", "bias_rmse_ratio_cloud", "bias_fitness_ref", "sigma_floor_m", "sigma_floor_rad"
        )


@dataclass(frozen=True)
class ReliabilityConfig:
    """The limits of the reliability rules every solution is judged by (:mod:`factorloc.estimators.icp.rules`).

    Parameters
    ----------
    min_fitness
        A seeded solution in degenerate geometry that fits at least this fraction of the query points within
        ``fitness_distance_m`` is not searched for elsewhere (the scan is the same there), and a seeded solution
        that left its seed "fits on its own" when it reaches it.
    max_sigma_position_m
        Largest σ across the walls of a solution unknown along them (``seed.across_walls``).
    min_inliers
        Fewest query points the step accepts.
    max_violation
        Largest fraction of either scan in space the other scan's sensor saw empty
        (:func:`~factorloc.registration.scan2d.alignment_violation`).
    min_score, violation_weight
        The score ``fitness − violation_weight · violation`` must reach ``min_score``.
    min_constraint
        Smallest eigenvalue of the mean normal scatter (:func:`~factorloc.estimators.icp.constraint_strength`,
        in [0, 0.5]); below it the scan sees essentially one direction of walls.
    debias_constraint
        Whether that eigenvalue is measured without the part the normals' own estimation noise adds (a noisier
        laser's normals scatter more, which makes a corridor look constrained). With it the limit is 0.025: on
        the three logs' folds 0.02–0.03 do alike (0.03 loses one ACES loop, 0.015 and below let an ACES corridor
        loop through), and with 1 cm of range noise added to the logs 0.025 keeps MIT CSAIL's loops below 1 %
        confidently wrong where 0.02 and the raw eigenvalue at 0.03 do not (``docs/calibration/icp.md``).
    min_heading_strength
        Smallest heading strength (:func:`~factorloc.estimators.icp.covariance.heading_strength`, in [0, 1]) at
        which the scan constrains the heading: below it (a round room seen from its centre) a reliable estimate
        is position only, with a waived ``icp.constraint.heading`` check. 0 switches the rule off. Fitted leave
        one log out on the real laser logs (``docs/calibration/icp.md``, "The heading half of the constraint rule").
    """

    min_fitness: float = 0.25
    max_sigma_position_m: float = 0.25
    min_inliers: int = 10
    max_violation: float = 0.12
    min_score: float = 0.4
    violation_weight: float = 1.0
    min_constraint: float = 0.025
    debias_constraint: bool = True
    min_heading_strength: float = 0.005

    def __post_init__(self) -> None:
        _unit("reliability", self, "min_fitness", "min_heading_strength")
        if not 0.0 <= self.min_constraint <= 0.5:
            raise ConfigError(f"icp.reliability.min_constraint must be in [0, 0.5], got {self.min_constraint!r}")
        if self.min_inliers < 3:
            raise ConfigError(f"icp.reliability.min_inliers must be >= 3, got {self.min_inliers!r}")
        _positive("reliability", self, "max_sigma_position_m")
        _non_negative("reliability", self, "max_violation", "violation_weight")


@dataclass(frozen=True)
class SeedConfig:
    """How a seeded alignment is tied to its seed (the latest reliable position and heading of the earlier steps).

    Parameters
    ----------
    consistency_probability
        A seeded solution outside the seed's region at this probability (χ², 2 dof, seed and ICP covariances
        summed) is inconsistent with it, where the geometry lets ICP slide (constraint below
        ``check_max_constraint``) or where it lies farther than ``3σ + jump_margin_m`` from the seed.
    check_max_constraint, jump_margin_m
        See above.
    heading_window_rad
        Heading half-window of the global search around a reliable heading (at least this, or 3σ).
    radius_margin_m
        The global search window around a reliable position is ``min(radius_m, margin + 3σ)``.
    across_walls
        A seeded solution that fails only the position-degeneracy rules (one wall, a corridor) and whose
        heading agrees with the heading seed within 3σ is returned reliable, with
        :data:`~factorloc.estimators.icp.UNCONSTRAINED_SIGMA_M` along the walls.
    across_walls_min_score
        The score floor of that solution (instead of ``reliability.min_score``).
    """

    consistency_probability: float = 0.999
    check_max_constraint: float = 0.12
    jump_margin_m: float = 0.25
    heading_window_rad: float = math.radians(10.0)
    radius_margin_m: float = 0.5
    across_walls: bool = True
    across_walls_min_score: float = 0.3

    def __post_init__(self) -> None:
        if not 0.0 < self.consistency_probability < 1.0:
            raise ConfigError(f"icp.seed.consistency_probability must be in (0, 1), got {self.consistency_probability!r}")
        _positive("seed", self, "heading_window_rad")
        _non_negative("seed", self, "check_max_constraint", "jump_margin_m", "radius_margin_m")
        _unit("seed", self, "across_walls_min_score")


@dataclass(frozen=True)
class GlobalInitConfig:
    """Global initialization: a correlative search (Olson, ICRA 2009) whose best candidates ICP refines.

    It runs when no reliable position and heading seed exists or the seeded solution is unreliable (and not
    merely degenerate).

    Parameters
    ----------
    enabled
        Run it at all.
    widen
        When nothing reliable lies in the window bounded by the seeds, search again over the full
        ``search.radius_m`` and the full circle of headings.
    search
        The correlative search's grid (:class:`~factorloc.registration.global_search.GlobalSearchParams`).
    refine
        How many candidates ICP refines.
    distinct_m, distinct_rad
        Two solutions farther apart than either are distinct (rivals).
    ambiguity_ratio
        A distinct rival scoring this fraction of the best makes it ambiguous.
    seed_contradiction_ambiguity_ratio
        The ambiguity ratio of a solution outside the region of a reliable position seed.
    degenerate_ratio, degenerate_min_score
        Without a position seed, a degenerate solution that scores at least ``degenerate_min_score`` and whose
        rivals all score below ``degenerate_ratio`` × its score is not rejected for its geometry.
    low_min_score, low_score_ratio
        Without a position seed, a non-degenerate solution scoring in [``low_min_score``,
        ``reliability.min_score``) whose rivals score below ``low_score_ratio`` × its score is not rejected
        for its score.
    overlap_min_fitness, overlap_min_score, overlap_rival_ratio, overlap_rival_margin
        Without a position seed, a non-degenerate solution whose overlap fitness (fitness over what both
        sensors could see) reaches ``overlap_min_fitness``, scoring at least ``overlap_min_score``, with rivals
        below ``overlap_rival_ratio`` × and either below ``low_score_ratio`` × or explaining their own overlap
        worse by ``overlap_rival_margin``, is not rejected for its score or fitness.
    ambiguity_overlap_ratio
        Without a position seed, a solution with a rival at this fraction of its score must reach
        ``overlap_min_fitness``.
    ignore_degenerate_rivals
        Without a position seed, a non-degenerate solution reaching ``overlap_min_fitness`` is compared only
        with non-degenerate rivals.
    weak_prior
        Without a reliable position seed, the latest weak prior (an earlier step's estimate too broad to seed,
        :meth:`~factorloc.estimators.base.Hypotheses.weak_pose`) is held against a global solution as a
        reliable seed is: the search first covers the window it bounds, whose best solution stands for the
        prior's alignment (a rival, never the result), and a solution outside its χ² region overturns it only
        when that alignment is not free-space consistent (``icp.global.seed_refuted``), with the stricter
        ambiguity ratio. It is never a seed the audit reads (no :class:`~factorloc.verdicts.SeedEvidence`). Off:
        no held-out log or simulator seed gains, one kidnapped recovery is lost (``docs/calibration/icp.md``).
    """

    enabled: bool = True
    widen: bool = True
    search: GlobalSearchParams = field(default_factory=GlobalSearchParams)
    refine: int = 10
    distinct_m: float = 0.3
    distinct_rad: float = math.radians(5.0)
    ambiguity_ratio: float = 0.9
    seed_contradiction_ambiguity_ratio: float = 0.7
    degenerate_ratio: float = 0.85
    degenerate_min_score: float = 0.8
    low_min_score: float = 0.3
    low_score_ratio: float = 0.5
    overlap_min_fitness: float = 0.9
    overlap_min_score: float = 0.2
    overlap_rival_ratio: float = 0.8
    overlap_rival_margin: float = 0.05
    ambiguity_overlap_ratio: float = 0.75
    ignore_degenerate_rivals: bool = True
    weak_prior: bool = False

    def __post_init__(self) -> None:
        if self.refine < 1:
            raise ConfigError(f"icp.global_init.refine must be >= 1, got {self.refine!r}")
        _positive("global_init", self, "distinct_m", "distinct_rad")
        _unit("global_init", self, "ambiguity_ratio", "seed_contradiction_ambiguity_ratio", open_low=True)
        _unit(
            "global_init",
            self,
            "degenerate_ratio",
            "degenerate_min_score",
            "low_min_score",
            "low_score_ratio",
            "overlap_min_fitness",
            "overlap_min_score",
            "overlap_rival_ratio",
            "overlap_rival_margin",
            "ambiguity_overlap_ratio",
        )


@dataclass(frozen=True)
class IcpConfig:
    """Configuration of the ICP step.

    Parameters
    ----------
    enabled
        Whether :func:`factorloc.pipeline.default_steps` runs the step.
    scan
        How a 2D scan is cut out of a 3D cloud (query and reference).
    alignment
        The alignment group (:class:`AlignmentConfig`).
    covariance
        The covariance group (:class:`CovarianceConfig`).
    reliability
        The reliability rules' limits (:class:`ReliabilityConfig`).
    seed
        The seeded attempt and its seed tests (:class:`SeedConfig`).
    global_init
        The global initialization (:class:`GlobalInitConfig`).
    ablate
        Codes of rules (``icp.<rule>``, :mod:`factorloc.estimators.icp.rules`) and waivers (``icp.waiver.*``)
        left out: for measuring what each buys (the leave-one-rule-out table of ``docs/calibration/icp.md``);
        empty in use.
    """

    enabled: bool = True
    scan: ScanExtraction = field(default_factory=ScanExtraction)
    alignment: AlignmentConfig = field(default_factory=AlignmentConfig)
    covariance: CovarianceConfig = field(default_factory=CovarianceConfig)
    reliability: ReliabilityConfig = field(default_factory=ReliabilityConfig)
    seed: SeedConfig = field(default_factory=SeedConfig)
    global_init: GlobalInitConfig = field(default_factory=GlobalInitConfig)
    ablate: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "ablate", tuple(self.ablate))
        bad = [c for c in self.ablate if not (isinstance(c, str) and c.startswith("icp."))]
        if bad:
            raise ConfigError(f"icp.ablate must hold rule codes 'icp.<rule>', got {bad!r}")
        for name, kind in (
            ("scan", ScanExtraction),
            ("alignment", AlignmentConfig),
            ("covariance", CovarianceConfig),
            ("reliability", ReliabilityConfig),
            ("seed", SeedConfig),
            ("global_init", GlobalInitConfig),
        ):
            if not isinstance(getattr(self, name), kind):
                raise ConfigError(f"icp.{name} must be a {kind.__name__}, got {type(getattr(self, name)).__name__}")
