"""Strict JSON for every report wbmpc writes: no NaN/Infinity tokens (they are not JSON).

`to_json` turns non-finite floats into null (a metric that could not be measured, e.g. a mean
over no samples) and NumPy scalars/arrays into plain numbers/lists, then serialises with
`allow_nan=False`, so any other stray non-finite value raises instead of writing invalid JSON.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np


def finite_or_none(value: Any) -> Any:
    """The same structure with NaN/inf -> None and NumPy values -> Python values."""
    if isinstance(value, dict):
        return {str(k): finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_none(v) for v in value]
    if isinstance(value, np.ndarray):
        return finite_or_none(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


def to_json(payload: Any, indent: int | None = None) -> str:
    return json.dumps(finite_or_none(payload), indent=indent, allow_nan=False)
