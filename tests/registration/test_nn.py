"""KdTree2D: the same neighbours as scipy's cKDTree (small_gicp backend or scipy fallback)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from factorloc.errors import InputError
from factorloc.registration.nn import LIFT_Z, KdTree2D, fast_backend, lift_2d

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
