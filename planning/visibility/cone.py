"""Tool visibility (Makki 2010 §2.2.3): which candidate axes may machine each sampled point.

A ball-end mill touching a point with normal ``n`` along tool axis ``t`` cuts with the part of the
ball at angle ``v = angle(n, t)`` from its tip. The axis is admissible when ``v1 <= v <= v2``
(``visibility.cone_deg``): below v1 the cutting speed is near zero, near 90 deg the scallops grow.
Global visibility (tool and holder collisions, §2.2.4) plugs in behind ``visibility.global`` as a
further mask combined with this one.
"""

from __future__ import annotations

import numpy as np

from planning.errors import ParameterError

# Angles exactly on a cone boundary (grid axes meeting exact normals) are admitted.
_COS_EPS = 1e-9


def cone_visibility(normals: np.ndarray, axes: np.ndarray, cone_deg=(10.0, 80.0), *,
                    chunk_rows: int = 65_536) -> np.ndarray:
    """Bool matrix (n, m): True where the angle between normal i and axis j lies in [v1, v2] degrees.

    ``normals`` (n,3) and ``axes`` (m,3) are unit vectors in the part frame. Follows Makki §2.2.3
    (two cones about the normal). Computed in row chunks so the float work never exceeds
    ``chunk_rows * m`` values.
    """
    normals = np.asarray(normals, dtype=np.float64)
    axes = np.asarray(axes, dtype=np.float64)
    if normals.ndim != 2 or normals.shape[1] != 3 or axes.ndim != 2 or axes.shape[1] != 3:
        raise ParameterError("normals and axes must be (n,3) and (m,3) arrays")
    v1, v2 = (float(c) for c in cone_deg)
    if not (0.0 <= v1 < v2 <= 90.0):
        raise ParameterError(f"visibility.cone_deg = [{v1}, {v2}]: need 0 <= v1 < v2 <= 90 degrees")
    cos_hi = np.cos(np.radians(v1)) + _COS_EPS   # dot <= cos(v1)
    cos_lo = np.cos(np.radians(v2)) - _COS_EPS   # dot >= cos(v2)
    out = np.empty((normals.shape[0], axes.shape[0]), dtype=bool)
    at = axes.T.copy()
    for start in range(0, normals.shape[0], chunk_rows):
        d = normals[start:start + chunk_rows] @ at
        out[start:start + chunk_rows] = (d >= cos_lo) & (d <= cos_hi)
    return out


def axis_normal_angles_deg(normals: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Angles (n, k) in degrees between each normal and each of a few axes (used to split overlaps)."""
    d = np.clip(np.asarray(normals, float) @ np.asarray(axes, float).T, -1.0, 1.0)
    return np.degrees(np.arccos(d))
