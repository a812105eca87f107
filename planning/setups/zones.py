"""Stage 5, set-ups: functional zones (Makki 2010 §3.1), the points where no two set-ups may overlap.

A zone is given in the plan configuration (``setups.functional_zones``) as input point indices, a
box or a sphere in part coordinates (mm); :func:`zone_mask` turns the zones into the per-point mask
:func:`~planning.setups.select.select_setups` takes as ``zone_mask``.
"""

from __future__ import annotations

import numpy as np

from planning.errors import ParameterError
from schemas.params import BoxZone, IndexZone, SphereZone

__all__ = ["zone_mask"]


def zone_mask(points: np.ndarray, sample_index: np.ndarray, zones) -> tuple[np.ndarray, list[str]]:
    """Bool mask (n,) of sampled points inside any functional zone, and warnings for empty zones.

    Index zones refer to the submitted cloud (0-based); boxes and spheres are in part coordinates, mm.
    """
    n_input = points.shape[0]
    sp = points[sample_index]
    mask = np.zeros(sample_index.shape[0], dtype=bool)
    warnings: list[str] = []
    for i, z in enumerate(zones):
        if isinstance(z, IndexZone):
            idx = np.asarray(z.indices, dtype=np.int64)
            if idx.max(initial=-1) >= n_input:
                raise ParameterError(
                    f"setups.functional_zones[{i}]: index {int(idx.max())} is out of range for a cloud of "
                    f"{n_input} points (indices are 0-based)")
            inside = np.isin(sample_index, idx)
        elif isinstance(z, BoxZone):
            lo, hi = np.asarray(z.min_mm), np.asarray(z.max_mm)
            inside = np.all((sp >= lo) & (sp <= hi), axis=1)
        elif isinstance(z, SphereZone):
            inside = np.sum((sp - np.asarray(z.center_mm)) ** 2, axis=1) <= z.radius_mm ** 2
        else:  # pragma: no cover - the schema admits no other kind
            raise ParameterError(f"setups.functional_zones[{i}]: unknown zone type")
        if not inside.any():
            warnings.append(f"functional zone {i} ({z.type}) contains no sampled point and constrains nothing")
        mask |= inside
    return mask, warnings
