"""Plain JSON values from numpy: the one way every file and message the project writes
turns numpy scalars and arrays (and NaN, for strict JSON) into JSON."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def json_default(value: Any) -> Any:
    """numpy scalars and arrays as plain JSON values (``json.dumps(..., default=...)``), so
    every file and message the project writes turns numpy into JSON the same way."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def finite(value: Any) -> Any:
    """``value`` with NaN and infinities as None and numpy scalars as Python numbers: what
    strict JSON (a browser's JSON.parse) accepts."""
    if isinstance(value, dict):
        return {str(k): finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite(v) for v in value]
    if isinstance(value, np.ndarray):
        return finite(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
