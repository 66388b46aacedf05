"""Step 3 of the hierarchy: panorama correlation → θ3 and scale (issue: visual heading estimators)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class CorrelationConfig:
    """Configuration of the panorama correlation."""

    enabled: bool = True
