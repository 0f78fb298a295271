"""Checks that config classes share for their settings."""

from __future__ import annotations

from typing import Optional


def check_fraction(key: str, value: Optional[float], of: str, optional: bool = False) -> None:
    """Refuse a setting ``key`` outside (0, 1] (a fraction ``of`` something); ``optional``: None is allowed too."""
    if optional and value is None:
        return
    if value is None or not 0 < value <= 1:
        left_out = " or left out" if optional else ""
        raise ValueError(f"{key} must be in (0, 1] (a fraction of {of}){left_out}, got {value}")
