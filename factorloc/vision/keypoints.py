"""Points of interest with azimuths, descriptor matching and the vote consensus of the virtual compass.

Keypoints of a 360° panorama are detected on a copy padded with its own
columns (wrap-around), so that corners straddling azimuth ±π are found once
and described with their true neighbourhood. Each keypoint's azimuth comes
from its column (:class:`~factorloc.vision.strips.Grid` / :class:`~factorloc.vision.strips.Strip`).
"""

from __future__ import annotations

import math
from functools import lru_cache

import cv2
import numpy as np

from factorloc.errors import ConfigError, InputError
from factorloc.geometry import wrap_angle

DETECTORS = ("orb", "sift")
#: A query point with a single (L2) candidate is matched to it only below this distance (no ratio test possible).
_MAX_SINGLE_L2 = 250.0
#: Where OpenCV's SIFT (``enable_precise_upscale=False``) reports a keypoint, relative to the true position (px).
_SIFT_UPSCALE_OFFSET_PX = 0.25


def make_detector(
    kind: str,
    n_features: int,
    fast_threshold: int = 12,
    contrast_threshold: float = 0.02,
    sift_sigma: float = 1.6,
    octave_layers: int = 3,
) -> cv2.Feature2D:
    """An OpenCV detector-descriptor: ``"orb"`` (binary, Hamming) or ``"sift"`` (float, L2).

    SIFT's ``contrast_threshold``, ``sift_sigma`` (the blur assumed at its first octave) and
    ``octave_layers`` are OpenCV's ``contrastThreshold``, ``sigma`` and ``nOctaveLayers``.
    """
    if kind == "orb":
        return cv2.ORB_create(nfeatures=int(n_features), fastThreshold=int(fast_threshold), edgeThreshold=15, patchSize=15)
    if kind == "sift":
        return cv2.SIFT_create(
            nfeatures=int(n_features),
            contrastThreshold=float(contrast_threshold),
            sigma=float(sift_sigma),
            nOctaveLayers=int(octave_layers),
        )
    raise ConfigError(f"detector must be one of {DETECTORS}, got {kind!r}")


def norm_of(kind: str) -> int:
    """The descriptor distance of ``kind``."""
    return cv2.NORM_HAMMING if kind == "orb" else cv2.NORM_L2


def detect(
    gray: np.ndarray,
    detector: cv2.Feature2D,
    *,
    wrap_pad_px: int = 0,
    scale: float = 1.0,
    one_per_location: bool = False,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Keypoint positions (N×2 float64, x = column, y = row) and descriptors of a grey image.

    With ``wrap_pad_px > 0`` the image is treated as horizontally periodic:
    it is padded by that many of its own columns on each side and only the
    keypoints whose column lies in [0, W) are kept. With ``scale < 1`` the
    (padded) image is area-downsampled by ``scale`` before detection and the
    positions are mapped back to the input's pixels (``x = (x' + ½)/s − ½``).
    SIFT doubles its input internally (its first octave), so ``scale = 0.5``
    drops only that octave — the finest, costliest one: about 5× faster on a
    160×320 strip, keypoints at scales ≥ 2 px of the input.

    With ``one_per_location`` a location reported several times keeps one keypoint
    (:func:`one_per_location_index`): SIFT gives a keypoint one copy per orientation-histogram peak within 80 % of the
    highest (Lowe 2004, §5), each with its own descriptor, so a pair matched twice would count as two bearings.
    """
    img = np.clip(gray, 0, 255).astype(np.uint8)
    pad = int(wrap_pad_px)
    if pad > 0:
        img = cv2.copyMakeBorder(img, 0, 0, pad, pad, cv2.BORDER_WRAP)
    sx = sy = 1.0
    if scale != 1.0:
        h, w = img.shape
        nw, nh = max(8, int(round(w * scale))), max(8, int(round(h * scale)))
        img = cv2.resize(img, (nw, nh), interpolation=cv2.INTER_AREA)
        sx, sy = nw / w, nh / h
    kps, desc = detector.detectAndCompute(img, None)
    if desc is None or len(kps) == 0:
        return np.zeros((0, 2)), None
    xy = cv2.KeyPoint_convert(kps).astype(np.float64).reshape(-1, 2)  # the (x, y) of each keypoint, as kp.pt
    if one_per_location:
        keep = one_per_location_index(xy, np.array([k.angle for k in kps], dtype=np.float64))
        xy, desc = xy[keep], desc[keep]
    if isinstance(detector, cv2.SIFT):
        # OpenCV's SIFT doubles its input for the first octave (pixel i of the double at (i + ½)/2 − ½) but reports
        # positions as i/2: ¼ px right of and below the truth, for every octave. Harmless when both images share it,
        # a bias of ¼ px · (1/s − 1) when they are detected at different scales s.
        xy -= _SIFT_UPSCALE_OFFSET_PX
    if scale != 1.0:
        xy[:, 0] = (xy[:, 0] + 0.5) / sx - 0.5
        xy[:, 1] = (xy[:, 1] + 0.5) / sy - 0.5
    if pad > 0:
        xy[:, 0] -= pad
        keep = (xy[:, 0] >= 0.0) & (xy[:, 0] < gray.shape[1])
        xy, desc = xy[keep], desc[keep]
    return xy, desc


def one_per_location_index(xy_px: np.ndarray, angle_deg: np.ndarray) -> np.ndarray:
    """Indices (ascending) of one keypoint per distinct position: of those at one ``xy_px``, the smallest ``angle_deg``.

    Positions are compared exactly (a detector's copies of one keypoint share its position bit for bit).
    The smallest angle (OpenCV's in [0, 360)) is an arbitrary but view-independent choice: two views of
    a patch with the same two orientation peaks keep the same one.
    """
    xy = np.asarray(xy_px, dtype=np.float64).reshape(-1, 2)
    if len(xy) < 2:
        return np.arange(len(xy))
    order = np.lexsort((np.asarray(angle_deg, dtype=np.float64), xy[:, 1], xy[:, 0]))
    s = xy[order]
    first = np.ones(len(s), dtype=bool)
    first[1:] = np.any(s[1:] != s[:-1], axis=1)
    return np.sort(order[first])


def match(
    query_desc: np.ndarray,
    ref_desc: np.ndarray,
    norm: int,
    ratio: float,
    allowed: np.ndarray | None = None,
    *,
    ref_sq_norms: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest-neighbour matches passing Lowe's ratio test, optionally among allowed pairs only.

    Parameters
    ----------
    query_desc, ref_desc
        Descriptors (Nq×D, Nr×D).
    norm
        ``cv2.NORM_HAMMING`` or ``cv2.NORM_L2``.
    ratio
        Keep a match when its distance < ``ratio`` × the second-best distance.
    allowed
        Optional Nq×Nr boolean mask: the candidate reference points of each
        query point (the seeded search window). A query point with a single
        candidate is matched to it only if the distance is small (no ratio test possible).
    ref_sq_norms
        Optional squared L2 norms of ``ref_desc``'s rows (float32, :func:`sq_norms`; float descriptors only),
        when the caller keeps them (a reference's are the same for every query).

    Returns
    -------
    (query_index, ref_index)
        Integer arrays of equal length.
    """
    if query_desc is None or ref_desc is None or len(query_desc) == 0 or len(ref_desc) == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    max_single = 0.2 * 8 * query_desc.shape[1] if norm == cv2.NORM_HAMMING else _MAX_SINGLE_L2
    if norm == cv2.NORM_L2:
        return _match_l2(query_desc, ref_desc, ratio, allowed, max_single, ref_sq_norms)
    matcher = cv2.BFMatcher(norm, crossCheck=False)
    mask = None if allowed is None else np.ascontiguousarray(allowed, dtype=np.uint8)
    k = 2 if len(ref_desc) > 1 else 1
    if mask is None:
        knn = matcher.knnMatch(query_desc, ref_desc, k=k)
    else:
        knn = matcher.knnMatch(query_desc, ref_desc, k=k, mask=mask)
    qi, ri = [], []
    for pair in knn:  # one short list per query point (not a pixel loop)
        if not pair:
            continue
        if len(pair) == 1:
            ok = pair[0].distance < max_single
        else:
            ok = pair[0].distance < ratio * pair[1].distance
        if ok:
            qi.append(pair[0].queryIdx)
            ri.append(pair[0].trainIdx)
    return np.asarray(qi, dtype=int), np.asarray(ri, dtype=int)


def match_in_window(
    query_desc: np.ndarray,
    query_az_rad: np.ndarray,
    ref_desc: np.ndarray,
    ref_az_rad: np.ndarray,
    offset_rad: float,
    reach_rad: float,
    ratio: float,
    *,
    ref_sq_norms: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`match` of float (L2) descriptors among the pairs of a circular window of azimuths.

    The same pairs as ``match(query_desc, ref_desc, cv2.NORM_L2, ratio, allowed, ref_sq_norms=...)`` with
    ``allowed = circular_abs_diff(ref_az_rad, query_az_rad, offset_rad) <= reach_rad`` (a reference point is a
    candidate of a query point when ``|wrap(az_ref − az_query − offset)| ≤ reach``): the mask, the squared norms
    and the two smallest distances per query point in one compiled pass over the product
    (:func:`factorloc.vision._kernels.two_nearest_in_window`, the same float32 operations).

    Parameters
    ----------
    query_desc, ref_desc
        Float descriptors (Nq×D, Nr×D).
    query_az_rad, ref_az_rad
        Their azimuths (rad), (Nq,) and (Nr,).
    offset_rad, reach_rad
        The window's centre offset and half-width (rad).
    ratio
        Lowe's ratio (see :func:`match`).
    ref_sq_norms
        Optional squared norms of ``ref_desc``'s rows (:func:`sq_norms`).

    Returns
    -------
    (query_index, ref_index)
        Integer arrays of equal length, in ascending query order.
    """
    if query_desc is None or ref_desc is None or len(query_desc) == 0 or len(ref_desc) == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    if np.shape(query_az_rad) != (len(query_desc),) or np.shape(ref_az_rad) != (len(ref_desc),):
        raise InputError(
            f"match_in_window needs one azimuth per descriptor: query_az_rad {np.shape(query_az_rad)} for "
            f"{len(query_desc)} query descriptors, ref_az_rad {np.shape(ref_az_rad)} for {len(ref_desc)}"
        )
    from factorloc.vision._kernels import two_nearest_in_window

    q = np.ascontiguousarray(query_desc, dtype=np.float32)
    r = np.ascontiguousarray(ref_desc, dtype=np.float32)
    d2 = _product(q, r)
    norms = sq_norms(r) if ref_sq_norms is None else np.ascontiguousarray(ref_sq_norms, dtype=np.float32)
    # the operands of circular_abs_diff, rounded to float32 as it rounds them
    b = (np.asarray(query_az_rad, dtype=np.float64) + offset_rad).astype(np.float32)
    a = np.ascontiguousarray(ref_az_rad, dtype=np.float32)
    best_j, best, second = two_nearest_in_window(
        np.ascontiguousarray(d2), norms, a, b, np.float32(reach_rad), np.float32(2.0 * math.pi)
    )
    ok = _ratio_passes(best, second, sq_norms(q), ratio, _MAX_SINGLE_L2)
    return np.flatnonzero(ok), best_j[ok].astype(int)


def _product(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``−2 q·rᵀ`` (Nq×Nr float32): numpy's product on one BLAS thread.

    One thread, set around this product only (:func:`_one_blas_thread`): numpy's OpenBLAS threads busy-wait after
    a threaded product, and on a loaded 2-core machine that made the matching, and the next steps, 2.5–3× slower
    in wall time. On one thread it takes 0.25–0.3 of the CPU of OpenCV's gemm, used before (125 × 1682 × 128:
    0.57 against 2.33 ms; `docs/calibration/vision.md`). The descriptors are integer-valued (OpenCV's SIFT), so
    every product is exact in float32 whichever kernel computes it, and so is its double.
    """
    with _one_blas_thread():
        out = np.matmul(q, r.T)
    out *= np.float32(-2.0)
    return out


@lru_cache(maxsize=1)
def _blas_controller():  # noqa: ANN202 - threadpoolctl's controller
    """threadpoolctl's view of the BLAS libraries loaded (made once, on the first product)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def _one_blas_thread():  # noqa: ANN202 - threadpoolctl's context manager
    """A context in which numpy's BLAS runs on one thread, its thread count restored on leaving."""
    return _blas_controller().limit(limits=1, user_api="blas")


def _ratio_passes(best: np.ndarray, second: np.ndarray, q_sq_norms: np.ndarray, ratio: float, max_single: float) -> np.ndarray:
    """Lowe's ratio test on the two smallest ``‖r‖² − 2 q·r`` of each row (``‖q‖²`` added here); one candidate: ``max_single``."""
    best = np.maximum(best + q_sq_norms, 0.0)
    second = np.maximum(second + q_sq_norms, 0.0)
    with np.errstate(invalid="ignore"):
        return np.where(
            np.isfinite(second),
            np.sqrt(best) < ratio * np.sqrt(second),
            np.sqrt(best) < max_single,
        ) & np.isfinite(best)


def sq_norms(desc: np.ndarray) -> np.ndarray:
    """Squared L2 norms (float32) of the rows of float descriptors (N×D), as :func:`match` uses them."""
    d = np.ascontiguousarray(desc, dtype=np.float32)
    return np.einsum("ij,ij->i", d, d)


def _match_l2(
    query_desc: np.ndarray,
    ref_desc: np.ndarray,
    ratio: float,
    allowed: np.ndarray | None,
    max_single: float,
    ref_sq_norms: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`match` for float descriptors: squared L2 distances by one matrix product.

    ``‖q − r‖² = ‖q‖² + ‖r‖² − 2·q·r`` (float32, OpenCV's gemm), the disallowed pairs set
    to ∞, then the two smallest per row: the same decisions as OpenCV's
    brute-force ``knnMatch`` with a mask, about 3–5× faster (no per-match objects).
    """
    q = np.ascontiguousarray(query_desc, dtype=np.float32)
    r = np.ascontiguousarray(ref_desc, dtype=np.float32)
    # ‖q‖² is constant along a row: the ranking is made on ‖r‖² − 2·q·r and ‖q‖² added to the two values kept
    # (OpenCV's SIFT descriptors are integers below 256, so every float32 here is an exact integer: the same
    # values as summing all three terms first, two passes over the Nq×Nr matrix fewer)
    d2 = _product(q, r)
    d2 += (sq_norms(r) if ref_sq_norms is None else np.asarray(ref_sq_norms, dtype=np.float32))[None, :]
    if allowed is not None:
        np.copyto(d2, np.inf, where=~np.asarray(allowed, dtype=bool))
    rows = np.arange(len(q))
    best_j = np.argmin(d2, axis=1)
    best = d2[rows, best_j]
    d2[rows, best_j] = np.inf
    second = d2.min(axis=1)
    ok = _ratio_passes(best, second, sq_norms(q), ratio, max_single)
    return rows[ok].astype(int), best_j[ok].astype(int)


def circular_abs_diff(a_rad: np.ndarray, b_rad: np.ndarray, offset_rad: float = 0.0) -> np.ndarray:
    """``|wrap(a[None, :] − b[:, None] − offset)|`` (len(b) × len(a), float32, rad): the window masks' workhorse.

    Float32 and ``x − 2π·rint(x/2π)`` instead of :func:`~factorloc.geometry.wrap_angle`'s
    float64 modulo: several times faster on the 10⁶-element match masks, exact to ~1e-6 rad.
    """
    b = (np.asarray(b_rad, dtype=np.float64) + offset_rad).astype(np.float32)
    x = np.asarray(a_rad, dtype=np.float32)[None, :] - b[:, None]
    two_pi = np.float32(2.0 * math.pi)
    x -= two_pi * np.rint(x / two_pi)
    return np.abs(x, out=x)


def vote_consensus(
    votes_rad: np.ndarray, band_rad: float, iterations: int = 3, *, compiled: bool = True
) -> tuple[float, np.ndarray, int]:
    """The densest mode of heading votes and its inliers.

    Each vote ``θ_i = az_ref − az_query`` counts the votes within ``±band_rad``
    of it (circularly); the vote with most neighbours seeds the mode, which is
    refined as the circular mean of its inliers (``iterations`` times).
    ``compiled``: in one compiled pass (:func:`factorloc.vision._kernels.vote_mode`, the default); False: the
    NumPy reference (the same steps; the circular mean summed pairwise instead of in index order).

    Returns
    -------
    (theta_rad, inliers, runner_up)
        The mode (wrapped), a boolean inlier mask, and the largest support of
        a vote further than 3 bands from the mode (an ambiguity measure).
    """
    v = np.asarray(votes_rad, dtype=np.float64)
    if v.size == 0:
        return 0.0, np.zeros(0, dtype=bool), 0
    if compiled:
        from factorloc.vision._kernels import vote_mode

        theta, inliers, runner_up = vote_mode(np.ascontiguousarray(v.ravel()), float(band_rad), int(iterations))
        return float(theta), inliers, int(runner_up)
    support = _support(v, band_rad)
    k = int(np.argmax(support))
    theta = float(v[k])
    inliers = np.abs(wrap_angle(v - theta)) <= band_rad
    for _ in range(iterations):
        if not inliers.any():
            break
        theta = float(
            wrap_angle(
                theta + math.atan2(np.sin(wrap_angle(v[inliers] - theta)).mean(), np.cos(wrap_angle(v[inliers] - theta)).mean())
            )
        )
        inliers = np.abs(wrap_angle(v - theta)) <= band_rad
    far = np.abs(wrap_angle(v - theta)) > 3.0 * band_rad
    runner_up = int(support[far].max()) if far.any() else 0
    return theta, inliers, runner_up


def support_rows(votes_rad: np.ndarray, band_rad: float, *, compiled: bool = True) -> np.ndarray:
    """:func:`_support` of every row of an m×n array of votes at once (m×n counts).

    Compiled (the default): each row in turn (:func:`factorloc.vision._kernels.circular_support_rows`). NumPy
    reference (``compiled=False``): the rows are wrapped, each offset by ``20·row`` (rows cannot overlap: a row
    spans 6π < 20 once extended), sorted once and searched once (the offset rounds each vote to 20·row's ulp).
    """
    v = np.asarray(votes_rad, dtype=np.float64)
    m, n = v.shape
    if n == 0:
        return np.zeros((m, 0), dtype=int)
    if compiled:
        from factorloc.vision._kernels import circular_support_rows

        return circular_support_rows(np.ascontiguousarray(v), float(band_rad))
    v = np.asarray(wrap_angle(v))
    s = np.sort(v, axis=1)
    ext = np.concatenate([s - 2.0 * math.pi, s, s + 2.0 * math.pi], axis=1) + 20.0 * np.arange(m)[:, None]
    flat = ext.ravel()
    shifted = v + 20.0 * np.arange(m)[:, None]
    lo = np.searchsorted(flat, (shifted - band_rad).ravel(), side="left").reshape(m, n)
    hi = np.searchsorted(flat, (shifted + band_rad).ravel(), side="right").reshape(m, n)
    return np.minimum(hi - lo, n)


def _support(votes_rad: np.ndarray, band_rad: float) -> np.ndarray:
    """For each vote, how many votes (itself included) lie within ``±band_rad`` of it on the circle.

    Sorted search, O(n log n): the votes sorted and extended by ±2π, each
    count is the span of ``[v − band, v + band]`` in that array (capped at n).
    """
    v = np.asarray(wrap_angle(np.asarray(votes_rad, dtype=np.float64)))
    v = np.atleast_1d(v)
    n = v.size
    s = np.sort(v)
    ext = np.concatenate([s - 2.0 * math.pi, s, s + 2.0 * math.pi])
    lo = np.searchsorted(ext, v - band_rad, side="left")
    hi = np.searchsorted(ext, v + band_rad, side="right")
    return np.minimum(hi - lo, n)


def nearest_circular_distance(angles_rad: np.ndarray, targets_rad: np.ndarray) -> np.ndarray:
    """For each angle, the circular distance (rad) to the nearest of ``targets_rad`` (sorted search, O(n log n))."""
    a = np.asarray(angles_rad, dtype=np.float64)
    t = np.sort(np.asarray(wrap_angle(np.asarray(targets_rad, dtype=np.float64))))
    if t.size == 0:
        return np.full(a.shape, np.inf)
    ext = np.concatenate([t[-1:] - 2.0 * math.pi, t, t[:1] + 2.0 * math.pi])
    aw = np.asarray(wrap_angle(a))
    k = np.searchsorted(ext, aw)
    lo = np.abs(aw - ext[np.clip(k - 1, 0, ext.size - 1)])
    hi = np.abs(ext[np.clip(k, 0, ext.size - 1)] - aw)
    return np.minimum(lo, hi)


def competing_mode(votes_rad: np.ndarray, theta_rad: float, band_rad: float) -> tuple[int, float]:
    """The strongest vote mode further than ``3·band_rad`` from ``theta_rad``: its support and offset.

    Each vote further than three bands from the mode counts the votes within
    ``±band_rad`` of it (circularly); the one with most neighbours is the competing
    mode (as the ``runner_up`` of :func:`vote_consensus`).

    Returns
    -------
    (support, offset_rad)
        The number of votes of the competing mode and its offset
        ``wrap(θ_competitor − theta_rad)`` (rad); (0, 0.0) when every vote is near the mode.
    """
    v = np.asarray(votes_rad, dtype=np.float64)
    off = np.asarray(wrap_angle(v - theta_rad))
    far = np.abs(off) > 3.0 * band_rad
    if not far.any():
        return 0, 0.0
    from factorloc.vision._kernels import circular_support

    support = circular_support(np.ascontiguousarray(v.ravel()), float(band_rad))[far]
    k = int(np.argmax(support))
    return int(support[k]), float(off[far][k])
