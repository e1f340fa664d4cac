"""Small 3-vector helpers for the per-frame set-up code (views, light frames)."""

from __future__ import annotations

import numpy as np


def cross3(a, b) -> np.ndarray:
    """``np.cross(a, b)`` of two 3-vectors, the same bits (the same products and differences, in
    float64) without ``np.cross``'s general broadcasting machinery, which costs tens of
    microseconds a call: the views and light frames take several a frame."""
    a0, a1, a2 = np.asarray(a, dtype=np.float64).tolist()
    b0, b1, b2 = np.asarray(b, dtype=np.float64).tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
