"""Conversions shared by the environments and the policies."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces


def f32(b: bytes, shape: tuple[int, ...]) -> np.ndarray:
    """float32 bytes from the extension as an array of ``shape`` (a copy the caller owns)."""
    return np.frombuffer(b, dtype=np.float32).reshape(shape).copy()


def spaces_of(low: list[float], high: list[float]) -> spaces.Box:
    """The Box space with these bounds."""
    return spaces.Box(np.array(low, np.float32), np.array(high, np.float32), dtype=np.float32)


def count(name: str, value: Any, least: int = 0) -> int:
    """``value`` as an int of at least ``least``, or a ValueError/TypeError naming ``name``
    (rather than the extension's bare OverflowError)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name}: an int, got {type(value).__name__}")
    if value < least:
        raise ValueError(f"{name} = {value}: must be at least {least}")
    return int(value)
