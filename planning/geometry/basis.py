"""Small geometric helpers shared by the stages."""

from __future__ import annotations

import numpy as np


def complete_basis(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``(u, v)`` such that ``(u, v, t)`` is a right-handed orthonormal frame, for a
    unit vector ``t`` (3,). ``u`` is ``t`` crossed with the coordinate axis least aligned with it."""
    t = np.asarray(t, dtype=np.float64)
    e = np.zeros(3)
    e[int(np.argmin(np.abs(t)))] = 1.0
    u = np.cross(t, e)
    u /= np.linalg.norm(u)
    return u, np.cross(t, u)
