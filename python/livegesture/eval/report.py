"""What both evaluation reports (``python -m livegesture.eval`` and ``livegesture.eval.generalise``) write:
strict JSON from their nested dicts of numpy and Python values."""
from __future__ import annotations

import math

import numpy as np


def jsonable(o):
    """numpy -> python, NaN/inf -> None (strict JSON)."""
    if isinstance(o, dict):
        return {str(k): jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return jsonable(o.tolist())
    if isinstance(o, np.generic):
        o = o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    if isinstance(o, (str, int, float, bool)) or o is None:
        return o
    return str(o)
