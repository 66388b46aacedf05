"""Fixtures of the estimator tests."""

from __future__ import annotations

import pytest
from helpers_visual import PHOTOS

from factorloc import Reference
from factorloc.sim import photo


@pytest.fixture(scope="module", params=sorted(PHOTOS))
def real_photo(request, shared_data):
    """(name, equirectangular image, reference) for each real panorama; a missing file fails."""
    eq = photo.load_equirectangular(shared_data / "panoramas" / request.param)
    w, h = PHOTOS[request.param]
    return request.param, eq, Reference(panorama=photo.reference_panorama(eq, w, h))
