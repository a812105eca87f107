"""Stage 1, reference samples: the half sphere of Makki et al. 2010 §3.2 (the paper's first use case).

:func:`half_sphere`: points (mm) on the upper half of a sphere centred at the origin, on rings of
latitude uniform in polar angle and azimuth (so denser towards the pole, as the paper's cloud is
"not uniform"), exact radial normals, no noise.
"""

from __future__ import annotations

import math

import numpy as np

from planning.inputs.samples.common import Sample, _check_float, _check_int, _check_seed

__all__ = ["half_sphere"]


def half_sphere(n_points: int = 2537, radius_mm: float = 50.0, seed: int = 0) -> Sample:
    """The paper's first use case: ``n_points`` points on the upper half of a sphere, exact normals.

    Makki et al. 2010 §3.2 simulate "a half of sphere mathematically defined", 2537 points, "the
    density of the cloud of points is not uniform", normals computed mathematically. The radius
    is not given in the paper; 50 mm is our choice (``radius_mm``).

    Layout: the sphere is centred at the origin; points lie on ``n_rings = round(sqrt(n / 2.83))``
    circles of latitude (30 for 2537) at polar angles ``(i + 1/2) * 90 / n_rings`` degrees from
    +Z, so there is no point exactly at the pole or on the equator (all z > 0). Every ring holds
    the same number of points (``n // n_rings``, the first ``n % n_rings`` rings one more), evenly
    spaced in azimuth from a phase drawn from ``seed``. Being uniform in polar angle and azimuth,
    the density per mm^2 grows as 1/sin(polar angle) towards the pole: the cap within 20 deg of
    the pole is about 5.7x denser than the band within 20 deg of the equator.

    Points are exactly on the sphere (|p| = R up to rounding), normals are exact (p / R), no noise.
    ``meta``: ``radius_mm``, ``centre_mm``, ``n_rings``, ``ring_polar_deg``, ``ring_counts``, ``seed``.
    """
    n = _check_int("n_points", n_points, 1, 10_000_000)
    r = _check_float("radius_mm", radius_mm, 0.0, 1e5)
    seed = _check_seed(seed)
    rng = np.random.default_rng(seed)

    # about square cells at 45 deg latitude: n_rings * (2 pi sin 45 deg) / (pi / 2) = n / n_rings
    n_rings = max(1, min(n, round(math.sqrt(n / (4.0 * math.sin(math.pi / 4))))))
    counts = np.full(n_rings, n // n_rings, dtype=np.int64)
    counts[: n % n_rings] += 1
    polar = (np.arange(n_rings) + 0.5) * (0.5 * math.pi / n_rings)
    phase = rng.uniform(0.0, 2.0 * math.pi, n_rings)
    ring = np.repeat(np.arange(n_rings), counts)
    start = np.concatenate(([0], np.cumsum(counts)[:-1]))
    k = np.arange(n) - start[ring]
    az = phase[ring] + 2.0 * math.pi * k / counts[ring]
    th = polar[ring]
    normals = np.column_stack((np.sin(th) * np.cos(az), np.sin(th) * np.sin(az), np.cos(th)))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    points = r * normals
    return Sample(
        name="half_sphere",
        points=points,
        normals=normals,
        description=(f"half sphere R {r:g} mm, {n} points on {n_rings} rings uniform in polar angle and "
                     f"azimuth (denser at the pole), exact radial normals, no noise (Makki 2010 §3.2)"),
        meta={"radius_mm": r, "centre_mm": (0.0, 0.0, 0.0), "n_rings": n_rings,
              "ring_polar_deg": np.degrees(polar), "ring_counts": counts, "seed": seed},
    )
