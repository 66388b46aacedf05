"""Step 2 of the hierarchy: the virtual compass → θ2 (issue: visual heading estimators)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class CompassConfig:
    """Configuration of the virtual compass."""

    enabled: bool = True
