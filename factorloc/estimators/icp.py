"""Step 4 of the hierarchy: ICP → x4, y4 (issue: ICP position estimator)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class IcpConfig:
    """Configuration of the ICP step."""

    enabled: bool = True
