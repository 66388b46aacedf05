"""Place recognition without a pose hypothesis: rotation-invariant signatures of scans and panoramas, top-k places.

Two signatures, each with a cheap rotation-invariant key for retrieval and, for scans, a finer distance that
searches the rotation:

* **Scan Context** (G. Kim and A. Kim, "Scan Context: Egocentric spatial descriptor for place recognition within
  3D point cloud map", IROS 2018), for a 2D scan: a polar grid of ``n_rings`` rings out to ``max_range_m`` by
  ``n_sectors`` azimuth sectors, a cell 1 when a point falls in it (a planar scan has no height, the paper's cell
  value). A rotation of the robot is a circular shift of the columns. The *key* is per ring the magnitudes of the
  azimuthal DFT of the ring (shift-invariant, like the paper's ring key but keeping the ring's structure); the
  *distance* is the paper's: one minus the mean cosine similarity of corresponding columns, over the columns
  occupied in both, minimized over the column shifts. Unlike the 360° lidar of the paper a 2D laser often sees
  180° only: the empty columns of either scan are left out of the mean (the paper's rule too), so a half-view
  matches the same half of a full one.
* **Scan-to-submap correlative matching** (``rank_by="submap_match"``), the global localization of Cartographer
  (W. Hess, D. Kohler, H. Rapp and D. Andor, "Real-time loop closure in 2D LIDAR SLAM", ICRA 2016: a scan is
  matched against every submap over a window of translations and the full circle of headings; the correlative
  score of E. Olson, "Real-time correlative scan matching", ICRA 2009): each place holds a *local submap* — the
  scans taken within a few metres of it stitched into its frame (:func:`local_submap`), so that a place is seen
  from all sides even by a 180° laser — turned into a likelihood field; the query scan's score against a place is
  the best mean field value under its points over a lattice of headings (the full circle) and translations
  (± ``match_radius_m``). A query seen facing the other way than the place's own scan still finds the half of the
  place it sees. The best pose gives the query's heading (and offset) relative to the place.
* **Panorama Fourier signature**, for a 360° panorama: the image reduced to a low-resolution grey strip about the
  horizon (``strip_rows`` × ``strip_columns``); per row the magnitudes of the azimuthal DFT (coefficients 1 to
  ``n_coefficients``), normalized. A rotation is a column shift, which changes only the DFT's phases
  (the classical Fourier signature of omnidirectional images, e.g. Menegatti, Maeda and Ishiguro,
  "Image-based memory for robot navigation using properties of omnidirectional images", RAS 2004).

:class:`PlaceRecognizer` computes the places' signatures once; :meth:`PlaceRecognizer.candidates` returns the
top-k places for a query, best first, each with its distance and, from the best column shift, the query's
heading relative to the place.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from factorloc._validate import nonnegative_float, positive_float, positive_int
from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.places.placemap import PlaceMap
from factorloc.registration.global_search import LikelihoodField, build_field, score_lattice
from factorloc.registration.scan2d import voxel_downsample_2d
from factorloc.types import Panorama, Query

__all__ = [
    "PlaceCandidate",
    "PlaceRecognizer",
    "RecognitionConfig",
    "local_submap",
    "neighbour_submaps",
    "panorama_signature",
    "scan_context",
    "scan_context_distance",
    "scan_context_key",
    "shape_distribution",
    "submap_match",
]


#: The scan signatures places can be ranked by (:attr:`RecognitionConfig.rank_by`).
RANKINGS = ("shape_distribution", "scan_context", "submap_match")


@dataclass(frozen=True)
class RecognitionConfig:
    """Parameters of place recognition.

    Parameters
    ----------
    n_rings
        Scan Context rings (radial bins).
    n_sectors
        Scan Context sectors (azimuth bins); the heading resolution is 2π / n_sectors.
    max_range_m
        Radius of the Scan Context grid (m); farther points are left out.
    n_key_coefficients
        DFT magnitudes per ring in the retrieval key (coefficients 0 … n-1).
    n_candidates
        With ``rank_by="scan_context"``: how many places the ring key retrieves before the shift-searching
        distance ranks them.
    fill_free_space
        Scan Context cells: with True (default) every cell of a sector up to its farthest return is 1 (the seen
        free space and the hit: the column is the sector's range profile, so that the cosine of two columns varies
        smoothly with the range); with False only the cells holding a return (the paper's occupancy).
    rank_by
        ``"submap_match"`` (default): ranked by the correlative score of the query scan against each place's local
        submap (the module docstring); ``"shape_distribution"``: ranked by the D2 shape distribution, Scan Context
        only gives the heading of the top k (and a query with a scan and a panorama is ranked by both signatures);
        ``"scan_context"``: ranked by Scan Context (key, then distance).
    d2_max_range_m
        The D2 shape distribution takes the points within this range of the robot (m); its bins span
        ``[0, 2·d2_max_range_m]``.
    d2_bins
        Number of bins of the D2 histogram.
    d2_voxel_m
        The D2 points are thinned to one per grid cell of this size (m).
    submap_radius_m
        With ``rank_by="submap_match"`` and no submaps given to :class:`PlaceRecognizer`: a place's local submap is
        the scans of the places within this distance of it (m, the map's world poses), stitched into its frame
        (:func:`neighbour_submaps`); 0 keeps each place's own scan.
    submap_voxel_m
        Local submaps are thinned to one point per grid cell of this size (m).
    match_shortlist
        With ``rank_by="submap_match"``: how many places the D2 shape distribution shortlists for matching; 0
        (default) matches every place (Cartographer's rule: every submap is searched).
    match_resolution_m
        Cell of the likelihood fields and step of the translation lattice of the match (m).
    match_sigma_m
        Blur σ of the likelihood field ``exp(−d²/2σ²)`` (m).
    match_angle_step_rad
        Heading step of the match over the full circle (rad).
    match_radius_m
        Half-width of the square translation window of the match about the place (m): a query this far from a
        place's own pose can still score fully against it.
    match_offset_sigma_m
        The match's score at translation ``t`` from the place is weighted by ``exp(−|t|²/2σ²)`` with this σ (m),
        so that of the places that all see the query's surroundings the nearest ranks first (Cartographer's
        translation cost on its correlative matcher's candidates); 0 (default) weights none.
    match_max_range_m
        Query points farther than this from the robot are left out of the match (m); submap points farther than
        ``match_max_range_m + match_radius_m`` from the place are left out of its field.
    strip_rows, strip_columns
        Size of the panorama strip the Fourier signature is taken from (px).
    strip_fov_rad
        Vertical extent of the strip about the horizon (rad).
    n_coefficients
        Azimuthal DFT magnitudes per strip row (coefficients 1 … n).
    """

    n_rings: int = 20
    n_sectors: int = 60
    max_range_m: float = 10.0
    n_key_coefficients: int = 8
    n_candidates: int = 50
    fill_free_space: bool = True
    rank_by: str = "submap_match"
    d2_max_range_m: float = 15.0
    d2_bins: int = 60
    d2_voxel_m: float = 0.1
    submap_radius_m: float = 0.0
    submap_voxel_m: float = 0.1
    match_shortlist: int = 0
    match_resolution_m: float = 0.3
    match_sigma_m: float = 0.3
    match_angle_step_rad: float = math.radians(6.0)
    match_radius_m: float = 1.5
    match_offset_sigma_m: float = 0.0
    match_max_range_m: float = 12.0
    strip_rows: int = 8
    strip_columns: int = 64
    strip_fov_rad: float = math.radians(30.0)
    n_coefficients: int = 16

    def __post_init__(self) -> None:
        for name in (
            "n_rings",
            "n_sectors",
            "n_key_coefficients",
            "n_candidates",
            "strip_rows",
            "strip_columns",
            "n_coefficients",
        ):
            object.__setattr__(self, name, positive_int(f"RecognitionConfig.{name}", getattr(self, name)))
        object.__setattr__(self, "max_range_m", positive_float("RecognitionConfig.max_range_m", self.max_range_m))
        object.__setattr__(self, "d2_max_range_m", positive_float("RecognitionConfig.d2_max_range_m", self.d2_max_range_m))
        object.__setattr__(self, "d2_voxel_m", positive_float("RecognitionConfig.d2_voxel_m", self.d2_voxel_m))
        object.__setattr__(self, "d2_bins", positive_int("RecognitionConfig.d2_bins", self.d2_bins))
        for name in (
            "submap_voxel_m",
            "match_resolution_m",
            "match_sigma_m",
            "match_angle_step_rad",
            "match_radius_m",
            "match_max_range_m",
        ):
            object.__setattr__(self, name, positive_float(f"RecognitionConfig.{name}", getattr(self, name)))
        for name in ("submap_radius_m", "match_offset_sigma_m"):
            object.__setattr__(self, name, nonnegative_float(f"RecognitionConfig.{name}", getattr(self, name)))
        object.__setattr__(self, "match_shortlist", positive_int("RecognitionConfig.match_shortlist", self.match_shortlist, 0))
        if self.rank_by not in RANKINGS:
            raise InputError(f"RecognitionConfig.rank_by must be one of {RANKINGS}, got {self.rank_by!r}")
        object.__setattr__(self, "strip_fov_rad", positive_float("RecognitionConfig.strip_fov_rad", self.strip_fov_rad))
        if self.n_key_coefficients > self.n_sectors // 2 + 1:
            raise InputError(
                f"RecognitionConfig.n_key_coefficients must be <= n_sectors // 2 + 1 = {self.n_sectors // 2 + 1}, "
                f"got {self.n_key_coefficients}"
            )
        if self.n_coefficients > self.strip_columns // 2:
            raise InputError(
                f"RecognitionConfig.n_coefficients must be <= strip_columns // 2 = {self.strip_columns // 2}, "
                f"got {self.n_coefficients}"
            )


# --------------------------------------------------------------------------
# Scan Context
# --------------------------------------------------------------------------
def scan_context(points_m: np.ndarray, config: RecognitionConfig = RecognitionConfig()) -> np.ndarray:
    """The Scan Context of a 2D scan: (n_rings, n_sectors) occupancy (0/1, float64).

    ``points_m`` is N×2 in the robot frame. Ring ``i`` covers ranges ``[i, i+1)·max_range_m/n_rings``; sector
    ``j`` covers azimuths ``[-π + j·w, -π + (j+1)·w)`` with ``w = 2π / n_sectors`` (counter-clockwise).
    """
    pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    r = np.hypot(pts[:, 0], pts[:, 1])
    a = np.arctan2(pts[:, 1], pts[:, 0])
    keep = r > 0.0
    ring = np.minimum((r[keep] / config.max_range_m * config.n_rings).astype(np.int64), config.n_rings - 1)
    sector = np.mod(((a[keep] + math.pi) / (2.0 * math.pi) * config.n_sectors).astype(np.int64), config.n_sectors)
    sc = np.zeros((config.n_rings, config.n_sectors))
    if config.fill_free_space:
        reach = np.full(config.n_sectors, -1, dtype=np.int64)
        np.maximum.at(reach, sector, ring)
        sc[:, :] = (np.arange(config.n_rings)[:, None] <= reach[None, :]).astype(np.float64)
    else:
        inside = r[keep] < config.max_range_m
        sc[ring[inside], sector[inside]] = 1.0
    return sc


def scan_context_key(sc: np.ndarray, n_coefficients: int) -> np.ndarray:
    """Rotation-invariant key of a Scan Context: per ring |DFT| over the sectors (coefficients 0 … n-1),
    flattened and scaled to unit norm (zeros for an empty context)."""
    mags = np.abs(np.fft.rfft(sc, axis=1))[:, :n_coefficients] / sc.shape[1]
    key = mags.ravel()
    n = float(np.linalg.norm(key))
    return key / n if n > 0.0 else key


def _column_unit(sc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    norms = np.linalg.norm(sc, axis=0)
    valid = norms > 0.0
    unit = np.where(valid[None, :], sc / np.where(valid, norms, 1.0)[None, :], 0.0)
    return unit, valid


def scan_context_distance(query_sc: np.ndarray, place_sc: np.ndarray) -> tuple[float, int]:
    """Kim & Kim's distance between two Scan Contexts and the column shift that attains it.

    ``d = min over m of 1 − mean_j cos(place[:, j], query[:, j − m])`` over the columns ``j`` occupied in both;
    1 when no column is occupied in both at any shift. The shift ``m`` (sectors) is the query's heading
    relative to the place: ``θ_place_query ≈ m · 2π / n_sectors`` (see :meth:`PlaceRecognizer.candidates`).
    """
    d, m = _distances(query_sc, place_sc[None])
    return float(d[0]), int(m[0])


def _distances(query_sc: np.ndarray, place_scs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scan Context distances from one query (R, S) to P places (P, R, S): (P,) distances and shifts."""
    q_unit, q_valid = _column_unit(query_sc)
    n_s = query_sc.shape[1]
    # all column shifts of the query at once: shifted[m][:, j] = query[:, j - m]
    idx = (np.arange(n_s)[None, :] - np.arange(n_s)[:, None]) % n_s  # (M, S)
    q_shift = q_unit[:, idx]  # (R, M, S)
    qv_shift = q_valid[idx]  # (M, S)
    norms = np.linalg.norm(place_scs, axis=1)  # (P, S)
    p_valid = norms > 0.0
    p_unit = place_scs / np.where(p_valid, norms, 1.0)[:, None, :]
    sims = np.einsum("prs,rms->pms", p_unit, q_shift)  # (P, M, S) cosine of matching columns
    both = p_valid[:, None, :] & qv_shift[None, :, :]
    either = (p_valid[:, None, :] | qv_shift[None, :, :]).sum(axis=2)
    mean = np.where(either > 0, (sims * both).sum(axis=2) / np.maximum(either, 1), 0.0)  # (P, M)
    dist = 1.0 - mean
    best = np.argmin(dist, axis=1)
    return dist[np.arange(len(best)), best], best


# --------------------------------------------------------------------------
# D2 shape distribution
# --------------------------------------------------------------------------
def shape_distribution(points_m: np.ndarray, config: RecognitionConfig = RecognitionConfig()) -> np.ndarray:
    """The D2 shape distribution of a 2D scan (Osada, Funkhouser, Chazelle and Dobkin, "Shape distributions",
    ACM TOG 2002): the histogram of the distances between all pairs of its points.

    Invariant to rotation *and* translation of the points (not of the viewpoint: what a scan sees changes as the
    robot moves, slowly in a room). Points within ``d2_max_range_m`` of the robot, thinned to one per
    ``d2_voxel_m`` grid cell (a laser samples near walls densely: the thinning makes the histogram a property of
    the walls, not of the range); ``d2_bins`` bins over ``[0, 2·d2_max_range_m]``; the square roots of the bin
    shares (unit norm), so that the Euclidean distance of two signatures is √2 times their Hellinger distance.
    Zeros for fewer than 3 points.
    """
    from scipy.spatial.distance import pdist

    pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    pts = pts[np.hypot(pts[:, 0], pts[:, 1]) < config.d2_max_range_m]
    if len(pts):
        cells = np.floor(pts / config.d2_voxel_m).astype(np.int64)
        _, first = np.unique(cells, axis=0, return_index=True)
        pts = pts[np.sort(first)]
    if len(pts) < 3:
        return np.zeros(config.d2_bins)
    hist, _ = np.histogram(pdist(pts), bins=config.d2_bins, range=(0.0, 2.0 * config.d2_max_range_m))
    return np.sqrt(hist / hist.sum())


# --------------------------------------------------------------------------
# Local submaps and the correlative match (Hess et al. 2016; Olson 2009)
# --------------------------------------------------------------------------
def local_submap(scans_m: Sequence[np.ndarray], T_center_scan: Sequence[Pose2], voxel_m: float = 0.1) -> np.ndarray:
    """Scans stitched into one frame: (M, 2) points (m) of ``scans_m[i]`` (N_i×2, each in its robot frame) mapped
    by ``T_center_scan[i]`` (the pose of scan i's robot in the submap's frame, e.g. from odometry), thinned to one
    point per ``voxel_m`` grid cell (the first in the given order)."""
    if len(scans_m) != len(T_center_scan):
        raise InputError(f"local_submap: {len(scans_m)} scans for {len(T_center_scan)} poses")
    if len(scans_m) == 0:
        raise InputError("local_submap needs at least one scan")
    voxel_m = positive_float("voxel_m", voxel_m)
    parts = []
    for pts, T in zip(scans_m, T_center_scan, strict=True):
        if not isinstance(T, Pose2):
            raise InputError(f"local_submap poses must be Pose2, got {type(T).__name__}")
        p = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        c, s = math.cos(T.theta), math.sin(T.theta)
        parts.append(np.column_stack([c * p[:, 0] - s * p[:, 1] + T.x, s * p[:, 0] + c * p[:, 1] + T.y]))
    pts = np.concatenate(parts)
    if len(pts) == 0:
        return pts
    _, first = np.unique(np.floor(pts / voxel_m).astype(np.int64), axis=0, return_index=True)
    return pts[np.sort(first)]


def neighbour_submaps(place_map: PlaceMap, radius_m: float, voxel_m: float = 0.1) -> dict[str, np.ndarray]:
    """Per place, the :func:`local_submap` of the scans of every place within ``radius_m`` of it (itself
    included), stitched by the map's world poses into the place's frame. For maps whose poses are consistent (a
    mapped or simulated building); a log's odometry poses drift between passes: stitch along the path instead
    (:func:`factorloc.evaluation.places.places_along_log`)."""
    radius_m = nonnegative_float("radius_m", radius_m)
    places = [p for p in place_map if p.planar_points_m() is not None]
    pos = np.array([p.position_m for p in places]).reshape(-1, 2)
    out: dict[str, np.ndarray] = {}
    for p in places:
        near = np.flatnonzero(np.hypot(*(pos - p.position_m).T) <= radius_m)
        near = sorted(near, key=lambda j: places[j].id != p.id)  # its own scan first
        out[p.id] = local_submap(
            [places[j].planar_points_m() for j in near],  # type: ignore[misc]
            [p.T_world_reference.between(places[j].T_world_reference) for j in near],
            voxel_m,
        )
    return out


def _match_field(points_m: np.ndarray, config: RecognitionConfig) -> LikelihoodField | None:
    """The likelihood field of a place's submap for the match (None when no point lies within reach)."""
    pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= config.match_max_range_m + config.match_radius_m]
    if len(pts) == 0:
        return None
    return build_field(pts, config.match_resolution_m, config.match_sigma_m, 3.0 * config.match_sigma_m)


def _match_query(points_m: np.ndarray, config: RecognitionConfig) -> np.ndarray:
    pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
    pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= config.match_max_range_m]
    return voxel_downsample_2d(pts, config.match_resolution_m)


def submap_match(
    query_m: np.ndarray, field: LikelihoodField, config: RecognitionConfig = RecognitionConfig()
) -> tuple[float, Pose2]:
    """The correlative score of a query scan against a place's field and the pose attaining it.

    ``query_m`` (N×2, robot frame, already thinned: see :meth:`PlaceRecognizer.candidates`) is scored at every
    heading ``k · match_angle_step_rad`` of the full circle and every translation of the ``match_resolution_m``
    lattice within ± ``match_radius_m`` of the place: the mean field value under the moved points (Olson 2009), in
    [0, 1], weighted by the translation's cost when ``match_offset_sigma_m`` > 0. Returns the best score and
    ``T_place_query`` (to within about a lattice cell and a heading step; 0 and the identity for an empty query).
    """
    if len(query_m) == 0:
        return 0.0, Pose2()
    n_theta = max(1, int(math.ceil(2.0 * math.pi / config.match_angle_step_rad)))
    thetas = np.arange(n_theta) * (2.0 * math.pi / n_theta)
    res = config.match_resolution_m
    n = int(math.ceil(config.match_radius_m / res))
    t_lo = np.array([-n * res, -n * res])
    scores = score_lattice(field, query_m, thetas, t_lo, (2 * n + 1, 2 * n + 1))
    if config.match_offset_sigma_m > 0.0:
        t = t_lo[0] + np.arange(2 * n + 1) * res
        scores = scores * np.exp(-0.5 * (t[:, None] ** 2 + t[None, :] ** 2) / config.match_offset_sigma_m**2)[None]
    a, kx, ky = np.unravel_index(int(np.argmax(scores)), scores.shape)
    return float(scores[a, kx, ky]), Pose2(float(t_lo[0] + kx * res), float(t_lo[1] + ky * res), float(thetas[a]))


# --------------------------------------------------------------------------
# Panorama Fourier signature
# --------------------------------------------------------------------------
def panorama_signature(panorama: Panorama, config: RecognitionConfig = RecognitionConfig()) -> np.ndarray:
    """Rotation-invariant signature of a 360° panorama: (strip_rows · n_coefficients,) unit-norm vector.

    The grey image's rows within ``strip_fov_rad / 2`` of the horizon (row H/2) are averaged down to
    ``strip_rows`` × ``strip_columns`` (area averaging); per row, the magnitudes of the DFT along the columns,
    coefficients 1 … n_coefficients (the mean, coefficient 0, is left out: it carries the exposure), divided by
    the row's standard deviation (contrast); unseen columns (``Panorama.seen_columns``) are filled with the
    row's mean of the seen ones.
    """
    import cv2

    img = panorama.image_bgr
    grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(np.float64)
    h = grey.shape[0]
    f = (h / 2.0) / math.tan(panorama.fov_v_rad / 2.0)
    half = min(h / 2.0, f * math.tan(min(config.strip_fov_rad, panorama.fov_v_rad) / 2.0))
    top, bottom = int(round(h / 2.0 - half)), int(round(h / 2.0 + half))
    band = grey[max(0, top) : max(bottom, top + 1)]
    if panorama.seen_columns is not None:
        seen = panorama.seen_columns
        fill = band[:, seen].mean(axis=1, keepdims=True)
        band = np.where(seen[None, :], band, fill)
    strip = cv2.resize(band, (config.strip_columns, config.strip_rows), interpolation=cv2.INTER_AREA)
    spec = np.abs(np.fft.rfft(strip, axis=1))[:, 1 : config.n_coefficients + 1]
    std = strip.std(axis=1, keepdims=True)
    spec = spec / np.where(std > 0, std, 1.0) / config.strip_columns
    sig = spec.ravel()
    n = float(np.linalg.norm(sig))
    return sig / n if n > 0.0 else sig


# --------------------------------------------------------------------------
# The recognizer
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class PlaceCandidate:
    """One place retrieved for a query.

    ``distance`` is the signature distance (smaller is more alike; Scan Context distance in [0, 1], or the
    panorama signatures' Euclidean distance when ``signature == "panorama"``). ``theta_place_query_rad`` is the
    query's heading relative to the place from the best column shift (None for the panorama signature, which
    keeps no phase). With ``signature == "submap_match"``, ``distance`` is one minus the correlative score (in
    [0, 1]) and ``T_place_query`` the best pose of the match (the query's pose in the place's frame, to within
    about one cell and one heading step of the match's lattice); None otherwise.
    """

    place_id: str
    distance: float
    signature: str
    theta_place_query_rad: float | None = None
    T_place_query: Pose2 | None = None

    def to_dict(self) -> dict[str, object]:
        return {
            "place_id": self.place_id,
            "distance": self.distance,
            "signature": self.signature,
            "theta_place_query_rad": self.theta_place_query_rad,
            "T_place_query": None if self.T_place_query is None else self.T_place_query.as_array().tolist(),
        }


class PlaceRecognizer:
    """Top-k places of a :class:`PlaceMap` for a query, from rotation-invariant signatures.

    The places' signatures are computed once, here. A query with a scan is matched against the places with a
    scan or cloud (a cloud is cut to its planar projection; ranked by :attr:`RecognitionConfig.rank_by`); a query
    with a panorama and no scan by the Fourier signature against the places with a panorama; a query with both
    and ``rank_by="shape_distribution"``, against the places with both, by the sum of the D2 and panorama
    distances each divided by its median over the places.

    With ``rank_by="submap_match"`` each place's likelihood field is built here from its local submap:
    ``submaps[place_id]`` (N×2 points in the place's frame, m: e.g. the scans along a log's path around it,
    stitched by odometry) when given, else :func:`neighbour_submaps` of the map at
    :attr:`RecognitionConfig.submap_radius_m` (0: the place's own scan). The query is one scan: what a lost robot
    has now.
    """

    def __init__(
        self,
        place_map: PlaceMap,
        config: RecognitionConfig = RecognitionConfig(),
        *,
        submaps: dict[str, np.ndarray] | None = None,
    ) -> None:
        if not isinstance(place_map, PlaceMap):
            raise InputError(f"PlaceRecognizer needs a PlaceMap, got {type(place_map).__name__}")
        if not isinstance(config, RecognitionConfig):
            raise InputError(f"config must be a RecognitionConfig, got {type(config).__name__}")
        if submaps is not None and not isinstance(submaps, dict):
            raise InputError(f"submaps must be a dict of place id to N×2 points, got {type(submaps).__name__}")
        self.place_map = place_map
        self.config = config
        self._scan_ids: list[str] = []
        scs, keys, d2s = [], [], []
        self._pano_ids: list[str] = []
        panos = []
        for p in place_map:
            pts = p.planar_points_m()
            if pts is not None:
                sc = scan_context(pts, config)
                self._scan_ids.append(p.id)
                scs.append(sc)
                keys.append(scan_context_key(sc, config.n_key_coefficients))
                d2s.append(shape_distribution(pts, config))
            if p.reference.panorama is not None:
                self._pano_ids.append(p.id)
                panos.append(panorama_signature(p.reference.panorama, config))
        self._scs = np.array(scs).reshape(-1, config.n_rings, config.n_sectors)
        self._d2 = np.array(d2s).reshape(len(scs), config.d2_bins)
        self._keys = np.array(keys).reshape(len(scs), config.n_rings * config.n_key_coefficients)
        pano_index = {pid: i for i, pid in enumerate(self._pano_ids)}
        self._both_scan = [i for i, pid in enumerate(self._scan_ids) if pid in pano_index]
        self._both_pano = [pano_index[self._scan_ids[i]] for i in self._both_scan]
        self._both = bool(self._both_scan)
        self._pano_sigs = np.array(panos).reshape(len(panos), config.strip_rows * config.n_coefficients)
        self._fields: list[LikelihoodField | None] = []
        if config.rank_by == "submap_match":
            self._fields = self._submap_fields(place_map, submaps)

    def _submap_fields(self, place_map: PlaceMap, submaps: dict[str, np.ndarray] | None) -> list[LikelihoodField | None]:
        cfg = self.config
        if submaps is None:
            if cfg.submap_radius_m > 0.0:
                submaps = neighbour_submaps(place_map, cfg.submap_radius_m, cfg.submap_voxel_m)
            else:
                submaps = {pid: place_map[pid].planar_points_m() for pid in self._scan_ids}  # type: ignore[misc]
        fields = []
        for pid in self._scan_ids:
            if pid not in submaps:
                raise InputError(f"submaps has no entry for place {pid!r}")
            pts = np.asarray(submaps[pid], dtype=np.float64)
            if pts.ndim != 2 or pts.shape[1] != 2:
                raise InputError(f"submaps[{pid!r}] must be N×2 points, got shape {pts.shape}")
            fields.append(_match_field(pts, cfg))
        return fields

    def candidates(self, query: Query, k: int = 5, *, exclude: Callable[[str], bool] | None = None) -> tuple[PlaceCandidate, ...]:
        """The ``k`` places most alike ``query``, best first (fewer when the map holds fewer).

        ``exclude(place_id)`` leaves places out (e.g. those taken just before the query in a benchmark).
        Raises :class:`InputError` when the query has neither a scan/cloud nor a panorama to match.
        """
        k = positive_int("k", k)
        has_scan = query.scan is not None or query.cloud is not None
        if has_scan and query.panorama is not None and self.config.rank_by == "shape_distribution" and self._both:
            return self._by_both(query, k, exclude)
        if has_scan:
            pts = query.scan.points_m if query.scan is not None else query.cloud.points_m[:, :2]  # type: ignore[union-attr]
            return self._by_scan(pts, k, exclude)
        if query.panorama is not None:
            return self._by_panorama(query.panorama, k, exclude)
        raise InputError(f"query {query.id!r} has no scan, cloud or panorama: nothing to recognize a place from")

    def _by_both(self, query: Query, k: int, exclude: Callable[[str], bool] | None) -> tuple[PlaceCandidate, ...]:
        """Places holding a scan and a panorama, ranked by the sum of the two signature distances, each divided by
        its median over the places (so that neither scale dominates)."""
        cfg = self.config
        ids = [self._scan_ids[i] for i in self._both_scan]
        allowed = np.flatnonzero(self._allowed(ids, exclude))
        if allowed.size == 0:
            return ()
        pts = query.scan.points_m if query.scan is not None else query.cloud.points_m[:, :2]  # type: ignore[union-attr]
        si, pi = np.asarray(self._both_scan)[allowed], np.asarray(self._both_pano)[allowed]
        d_scan = np.linalg.norm(self._d2[si] - shape_distribution(pts, cfg)[None], axis=1)
        d_pano = np.linalg.norm(self._pano_sigs[pi] - panorama_signature(query.panorama, cfg)[None], axis=1)  # type: ignore[arg-type]
        score = d_scan / max(float(np.median(d_scan)), 1e-12) + d_pano / max(float(np.median(d_pano)), 1e-12)
        top = np.argsort(score, kind="stable")[:k]
        _, shift = _distances(scan_context(pts, cfg), self._scs[si[top]])
        w = 2.0 * math.pi / cfg.n_sectors
        return tuple(
            PlaceCandidate(
                ids[allowed[j]], float(score[j]), "shape_distribution+panorama", float(math.remainder(int(m) * w, 2 * math.pi))
            )
            for j, m in zip(top, shift, strict=True)
        )

    def _allowed(self, ids: Sequence[str], exclude: Callable[[str], bool] | None) -> np.ndarray:
        return np.array([exclude is None or not exclude(i) for i in ids], dtype=bool)

    def _by_scan(self, points_m: np.ndarray, k: int, exclude: Callable[[str], bool] | None) -> tuple[PlaceCandidate, ...]:
        cfg = self.config
        allowed = np.flatnonzero(self._allowed(self._scan_ids, exclude))
        if allowed.size == 0:
            return ()
        sc = scan_context(points_m, cfg)
        w = 2.0 * math.pi / cfg.n_sectors
        if cfg.rank_by == "submap_match":
            return self._by_match(points_m, k, allowed)
        if cfg.rank_by == "shape_distribution":
            d2 = np.linalg.norm(self._d2[allowed] - shape_distribution(points_m, cfg)[None], axis=1)
            top = np.argsort(d2, kind="stable")[:k]
            chosen, dist = allowed[top], d2[top]
            _, shift = _distances(sc, self._scs[chosen])
        else:
            key = scan_context_key(sc, cfg.n_key_coefficients)
            kd = np.linalg.norm(self._keys[allowed] - key[None], axis=1)
            pre = allowed[np.argsort(kd, kind="stable")[: max(cfg.n_candidates, k)]]
            dist_all, shift_all = _distances(sc, self._scs[pre])
            top = np.argsort(dist_all, kind="stable")[:k]
            chosen, dist, shift = pre[top], dist_all[top], shift_all[top]
        return tuple(
            PlaceCandidate(
                self._scan_ids[chosen[i]],
                float(dist[i]),
                cfg.rank_by,
                float(math.remainder(int(shift[i]) * w, 2.0 * math.pi)),
            )
            for i in range(len(chosen))
        )

    def _by_match(self, points_m: np.ndarray, k: int, allowed: np.ndarray) -> tuple[PlaceCandidate, ...]:
        """The allowed places (shortlisted by D2 when ``match_shortlist`` > 0) ranked by their submap match."""
        cfg = self.config
        if cfg.match_shortlist and cfg.match_shortlist < allowed.size:
            d2 = np.linalg.norm(self._d2[allowed] - shape_distribution(points_m, cfg)[None], axis=1)
            allowed = allowed[np.argsort(d2, kind="stable")[: cfg.match_shortlist]]
        q = _match_query(points_m, cfg)
        scores = np.zeros(allowed.size)
        poses: list[Pose2] = []
        for j, i in enumerate(allowed):
            field = self._fields[i]
            score, T = (0.0, Pose2()) if field is None else submap_match(q, field, cfg)
            scores[j] = score
            poses.append(T)
        order = np.argsort(-scores, kind="stable")
        top = order[:k]
        return tuple(
            PlaceCandidate(
                self._scan_ids[allowed[j]],
                float(1.0 - scores[j]),
                "submap_match",
                float(math.remainder(poses[j].theta, 2.0 * math.pi)),
                poses[j],
            )
            for j in top
        )

    def _by_panorama(self, panorama: Panorama, k: int, exclude: Callable[[str], bool] | None) -> tuple[PlaceCandidate, ...]:
        allowed = np.flatnonzero(self._allowed(self._pano_ids, exclude))
        if allowed.size == 0:
            return ()
        sig = panorama_signature(panorama, self.config)
        d = np.linalg.norm(self._pano_sigs[allowed] - sig[None], axis=1)
        order = np.argsort(d, kind="stable")[:k]
        return tuple(PlaceCandidate(self._pano_ids[allowed[i]], float(d[i]), "panorama") for i in order)
