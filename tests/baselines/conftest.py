"""Fixtures of the strategy tests; the synthetic trajectories live in ``synthetic_trajectories.py``."""

from __future__ import annotations

import pytest
from synthetic_trajectories import make_synthetic


@pytest.fixture
def synthetic():
    return make_synthetic
