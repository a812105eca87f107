"""Per-area machining frames (issue 5, Makki 2010 §4: each area is machined by 3-axis paths at its
fixed orientation): a right-handed frame whose +Z is the set-up's tool axis.

Conventions (part frame in, area frame out; mm):

* ``z`` = the tool axis (unit, from the part towards the spindle);
* ``x`` = the longer side of the area's footprint: the principal direction of the area's points
  projected on the plane normal to ``z`` (2-D principal component), signed so that its largest
  part-frame component is positive. With fewer than 2 distinct footprint points, the part's +X
  projected on that plane (+Y when the axis is along X);
* ``y = z x x``;
* origin: the centre of the footprint's bounding rectangle in (x, y), at the height of the highest
  point of the whole cloud along ``z`` (every cloud point has area-frame z <= 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planning.errors import ParameterError


@dataclass(frozen=True)
class AreaFrame:
    """``rotation`` (3,3): rows are the frame's x, y, z axes in part coordinates; ``origin_mm`` (3,)."""

    rotation: np.ndarray
    origin_mm: np.ndarray

    def to_frame(self, points) -> np.ndarray:
        """Part-frame points (k,3) mm -> area-frame coordinates (k,3) mm."""
        return (np.asarray(points, dtype=np.float64) - self.origin_mm) @ self.rotation.T

    def to_part(self, points) -> np.ndarray:
        """Area-frame points (k,3) mm -> part-frame coordinates (k,3) mm."""
        return np.asarray(points, dtype=np.float64) @ self.rotation + self.origin_mm


def area_frame(tool_axis, cloud_points, area_points: np.ndarray | None = None) -> AreaFrame:
    """The frame of one area: tool axis as +Z, X along the footprint's longer side (see the module
    docstring). ``cloud_points`` (N,3): the whole cloud (for the origin height); ``area_points``
    (k,3): the area's points (for X and the origin in the plane; default the whole cloud)."""
    t = np.asarray(tool_axis, dtype=np.float64).reshape(3)
    nt = np.linalg.norm(t)
    if not np.isfinite(nt) or nt < 1e-12:
        raise ParameterError("tool_axis must be a finite non-zero vector")
    z = t / nt
    cloud = np.asarray(cloud_points, dtype=np.float64).reshape(-1, 3)
    area = cloud if area_points is None else np.asarray(area_points, dtype=np.float64).reshape(-1, 3)
    if cloud.shape[0] == 0 or area.shape[0] == 0:
        raise ParameterError("area_frame needs at least one cloud point and one area point")
    ref = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = ref - (ref @ z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    if area.shape[0] >= 2:
        q = np.stack([area @ x, area @ y], 1)
        q = q - q.mean(axis=0)
        cov = q.T @ q
        if np.trace(cov) > 1e-18:
            w, V = np.linalg.eigh(cov)
            d = V[:, -1]                     # the larger principal direction
            xn = d[0] * x + d[1] * y
            xn /= np.linalg.norm(xn)
            if xn[np.argmax(np.abs(xn))] < 0:
                xn = -xn
            x = xn
            y = np.cross(z, x)
    rot = np.stack([x, y, z])
    u, v = area @ x, area @ y
    centre = 0.5 * (u.min() + u.max()) * x + 0.5 * (v.min() + v.max()) * y
    top = float((cloud @ z).max())
    return AreaFrame(rotation=rot, origin_mm=centre + top * z)
