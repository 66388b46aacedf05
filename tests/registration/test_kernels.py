"""Robust kernels: IRLS weights at known residuals."""

from __future__ import annotations

import numpy as np
import pytest

from factorloc.errors import InputError
from factorloc.registration.kernels import L2, Cauchy, Huber, RobustKernel, Tukey, kernel_from_name


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
