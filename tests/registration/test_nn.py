"""KdTree2D: the same neighbours as scipy's cKDTree (small_gicp backend or scipy fallback)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from factorloc.errors import InputError
from factorloc.registration.nn import (
    GRID_CELL_M,
    GRID_MAX_CELLS,
    LIFT_Z,
    KdTree2D,
    build_grid,
    fast_backend,
    grid_nearest,
    grid_nearest2,
    lift_2d,
)

BACKENDS = ["scipy"] + (["small_gicp"] if fast_backend() else [])


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize(("k", "bound"), [(1, np.inf), (1, 0.15), (7, 0.5), (7, np.inf)])
def test_kdtree2d_matches_ckdtree(backend: str, k: int, bound: float) -> None:
    rng = np.random.default_rng(3)
    ref = rng.uniform(-5.0, 5.0, (180, 2))
    qry = ref[::2] + rng.normal(0.0, 0.1, ref[::2].shape)
    d, i = KdTree2D(ref, backend=backend).query(qry, k=k, distance_upper_bound=bound)
    d0, i0 = cKDTree(ref).query(qry, k=k, distance_upper_bound=bound)
    assert d.shape == d0.shape and i.shape == i0.shape
    np.testing.assert_allclose(d, d0, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(i, i0)  # misses get index M = 180 in both
    assert (i == len(ref)).any() == np.isfinite(bound)


@pytest.mark.parametrize("backend", BACKENDS)
def test_kdtree2d_pads_when_k_exceeds_the_point_count(backend: str) -> None:
    d, i = KdTree2D(np.array([[0.0, 0.0], [1.0, 0.0]]), backend=backend).query(np.array([[0.1, 0.0]]), k=4)
    np.testing.assert_allclose(d[0, :2], [0.1, 0.9])
    assert np.all(np.isinf(d[0, 2:])) and np.all(i[0, 2:] == 2)


def test_kdtree2d_rejects_bad_input() -> None:
    with pytest.raises(InputError, match="M×2"):
        KdTree2D(np.zeros((0, 2)))
    with pytest.raises(InputError, match="backend"):
        KdTree2D(np.zeros((3, 2)), backend="flann")


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("k", [1, 7])
def test_nearest_lifted_matches_ckdtree_without_a_bound(backend: str, k: int) -> None:
    rng = np.random.default_rng(4)
    ref = rng.uniform(-5.0, 5.0, (180, 2))
    qry = ref[::2] + rng.normal(0.0, 0.3, ref[::2].shape)
    tree = KdTree2D(ref, backend=backend)
    lifted = lift_2d(qry)
    assert lifted.shape == (90, 3) and np.all(lifted[:, 2] == LIFT_Z) and lifted.flags.c_contiguous
    d, i = tree.nearest_lifted(lifted, k)
    d0, i0 = cKDTree(ref).query(qry, k=k)
    assert i.dtype == np.int64 and d.shape == d0.shape
    np.testing.assert_allclose(d, d0, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(i, i0)
    np.testing.assert_array_equal(tree.lifted[:, :2], ref)


# --------------------------------------------------------------------------
# the uniform grid of the compiled ICP core
# --------------------------------------------------------------------------
def _grid(ref: np.ndarray, cell_m: float = GRID_CELL_M, max_cells: int = GRID_MAX_CELLS):
    order, start, geo = build_grid(ref[:, 0].copy(), ref[:, 1].copy(), cell_m, max_cells)
    return order, start, geo, np.ascontiguousarray(ref[order])


def _grid_query(ref: np.ndarray, qry: np.ndarray, bound: float, **kw) -> tuple[np.ndarray, ...]:
    """(d, index into ref, second distance) of every query by grid_nearest2, and d, index by grid_nearest."""
    order, start, geo, packed = _grid(ref, **kw)
    out = np.empty((len(qry), 5))
    for n, (x, y) in enumerate(qry):
        d2, k, s2 = grid_nearest2(x, y, packed, start, geo, bound * bound)
        e2, kk = grid_nearest(x, y, packed, start, geo, bound * bound)
        out[n] = np.sqrt(d2), order[k] if k >= 0 else -1, np.sqrt(s2), np.sqrt(e2), order[kk] if kk >= 0 else -1
    return out[:, 0], out[:, 1].astype(np.int64), out[:, 2], out[:, 3], out[:, 4].astype(np.int64)


SCENES = {
    "uniform": lambda rng: rng.uniform(-5.0, 5.0, (300, 2)),
    "walls": lambda rng: (
        np.column_stack([np.linspace(-8, 8, 300), np.where(np.arange(300) % 2, 3.0, -2.0)]) + rng.normal(0.0, 0.01, (300, 2))
    ),
    "clusters": lambda rng: rng.normal(0.0, 0.02, (300, 2)) + rng.integers(-3, 4, (300, 2)) * 1.7,
    "one point": lambda rng: rng.uniform(-1.0, 1.0, (1, 2)),
}


@pytest.mark.parametrize("scene", list(SCENES))
@pytest.mark.parametrize("bound", [0.05, 0.3, 1.0, 50.0])
def test_grid_nearest_matches_ckdtree_within_the_bound(scene: str, bound: float) -> None:
    rng = np.random.default_rng(6)
    ref = SCENES[scene](rng)
    # queries near the points, anywhere around them, and outside the grid (near and far)
    qry = np.vstack(
        [
            ref[::3] + rng.normal(0.0, 0.2, ref[::3].shape),
            rng.uniform(-12.0, 12.0, (200, 2)),
            ref[:1] + 0.01,
            [[400.0, 0.0], [0.0, -9.5]],
        ]
    )
    d, i, second, d1, i1 = _grid_query(ref, qry, bound)
    d0, i0 = cKDTree(ref).query(qry, k=2)
    d0 = d0.reshape(len(qry), -1)
    i0 = i0.reshape(len(qry), -1)
    hit = d0[:, 0] < bound
    assert hit.any() and (~hit).any()  # both outcomes checked
    np.testing.assert_array_equal(i[hit], i0[hit, 0])
    np.testing.assert_allclose(d[hit], d0[hit, 0], rtol=1e-12, atol=1e-12)
    assert np.all(i[~hit] == -1) and np.all(np.isinf(d[~hit]))
    # the second distance is the second neighbour's, capped at the bound (every point when nothing is found)
    expect = np.minimum(d0[:, 1], bound)  # cKDTree pads a missing second neighbour with inf
    expect[~hit] = bound
    np.testing.assert_allclose(second, expect, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(i1, i)
    np.testing.assert_array_equal(d1, d)


def test_grid_handles_duplicates_wide_scenes_and_absurd_queries() -> None:
    rng = np.random.default_rng(7)
    pts = rng.uniform(-3.0, 3.0, (50, 2))
    twice = np.vstack([pts, pts])
    d, i, second, _, _ = _grid_query(twice, pts + 0.01, 1.0)
    np.testing.assert_allclose(d, np.full(50, np.hypot(0.01, 0.01)), rtol=1e-9)
    np.testing.assert_allclose(second, d, rtol=1e-12)  # the twin is as close
    assert np.all(i % 50 == np.arange(50))
    # a scene 1e6 m wide: cells grow until the grid has at most max_cells cells; still exact
    wide = rng.uniform(-5e5, 5e5, (400, 2))
    _, start, geo, _ = _grid(wide, max_cells=4096)
    assert len(start) - 1 <= 4096 and geo[2] >= GRID_CELL_M
    qry = wide[::7] + rng.normal(0.0, 1e3, wide[::7].shape)
    d, i, _, _, _ = _grid_query(wide, qry, 1e4, max_cells=4096)
    d0, i0 = cKDTree(wide).query(qry, distance_upper_bound=1e4)
    np.testing.assert_array_equal(i, np.where(np.isfinite(d0), i0, -1))
    # queries the search cannot use: nothing found, no crash
    order, start, geo, packed = _grid(pts)
    for x, y in ((1e300, 0.0), (-1e300, 1e300), (np.nan, 0.0), (0.0, np.inf)):
        assert grid_nearest2(x, y, packed, start, geo, 1.0) == (np.inf, -1, 1.0)
        assert grid_nearest(x, y, packed, start, geo, 1.0) == (np.inf, -1)
    # the grid orders the points by cell: every point once
    assert sorted(order) == list(range(50))
