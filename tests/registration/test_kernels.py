"""Robust kernels: IRLS weights at known residuals."""

from __future__ import annotations

import numpy as np
import pytest

from factorloc.errors import InputError
from factorloc.registration.kernels import (
    KERNEL_CODES,
    L2,
    Cauchy,
    Huber,
    RobustKernel,
    Tukey,
    kernel_from_name,
    weight_scalar,
)


def test_weights_match_the_m_estimator_formulas() -> None:
    r = np.array([0.0, 0.05, 0.1, -0.2])
    np.testing.assert_allclose(L2().weight(r), [1, 1, 1, 1])
    np.testing.assert_allclose(Huber(0.05).weight(r), [1, 1, 0.5, 0.25])
    np.testing.assert_allclose(Cauchy(0.05).weight(r), [1, 0.5, 0.2, 1 / 17])
    np.testing.assert_allclose(Tukey(0.1).weight(r), [1, 0.5625, 0, 0])


def test_kernel_from_name_builds_each_strategy_and_rejects_unknown_names() -> None:
    for name in ("l2", "huber", "cauchy", "tukey"):
        assert isinstance(kernel_from_name(name, 0.05), RobustKernel)
    with pytest.raises(InputError, match="kernel must be one of"):
        kernel_from_name("geman", 0.05)
    with pytest.raises(InputError, match="scale_m must be > 0"):
        Cauchy(0.0)


def test_the_compiled_weight_is_the_numpy_weight_of_every_kernel() -> None:
    """The ICP core calls weight_scalar(code, scale, r); the classes' numpy weight() must give the same bits."""
    rng = np.random.default_rng(2)
    r = np.concatenate([rng.normal(0.0, 0.1, 500), [0.0, -0.0, 0.05, -0.05, 0.1, -0.1, 1e-300, 1e300, -1e300]])
    kernels = [L2(), Huber(0.05), Cauchy(0.05), Tukey(0.1), Huber(3.0), Cauchy(1e-3)]
    assert sorted({k.code for k in kernels}) == sorted(KERNEL_CODES.values())
    for kernel in kernels:
        with np.errstate(over="ignore"):  # (1e300 / k)² overflows to inf: weight 0, as intended
            w = kernel.weight(r)
        assert w.shape == r.shape and np.all((w >= 0.0) & (w <= 1.0))
        compiled = np.array([weight_scalar(kernel.code, kernel.scale_m, x) for x in r])
        np.testing.assert_array_equal(compiled, w, err_msg=repr(kernel))
    np.testing.assert_allclose(Huber(0.05).weight(r[:500]), np.minimum(1.0, 0.05 / np.abs(r[:500])), rtol=1e-15)
    assert Cauchy(0.05).weight(np.zeros((2, 3))).shape == (2, 3)
