"""Analytic test surfaces with exact outward normals and scanner-like noise.

Every generator returns a :class:`Surface`: noisy points, the exact outward unit normal of the
underlying surface at the noise-free position of each point, and an ``interior`` mask of the points
farther than ``margin_mm`` from the boundary of a finite patch (a test that is not about edge effects
measures only those; closed surfaces have no boundary).

Sampling: uniform per unit of true surface area (rejection sampling where the parametrisation is not
area-preserving), ``density`` points/mm^2 (default 45, the paper's femur scan), reproducible from
``seed`` (``numpy.random.default_rng``).

Noise: a structured-light scanner measures depth along its line of sight, so each point is moved by
Gaussian noise of standard deviation ``sigma_mm`` (default 0.02 mm, typical of structured-light
scanners: 0.01-0.03 mm) along the view that recorded it. The views are the 14 directions
±X, ±Y, ±Z and (±1, ±1, ±1)/sqrt(3) (unit vectors from the part towards the scanner, like a part
scanned from all around); a point is recorded by the view that faces it best (largest
``view . normal``, always >= 0.577, i.e. within 55 deg of the normal).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DEFAULT_DENSITY = 45.0       # points per mm^2 (Makki 2010: 45 points/mm^2 on the femur)
DEFAULT_SIGMA_MM = 0.02      # depth noise along the line of sight

_VIEWS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]
                  + [[sx, sy, sz] for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)], dtype=float)
SCANNER_VIEWS = _VIEWS / np.linalg.norm(_VIEWS, axis=1, keepdims=True)


@dataclass(frozen=True)
class Surface:
    """A sampled analytic surface (see the module docstring)."""

    name: str
    points: np.ndarray      # (N,3) noisy, mm
    normals: np.ndarray     # (N,3) exact outward unit normals at the noise-free points
    interior: np.ndarray    # (N,) bool: farther than margin_mm from a patch boundary
    sigma_mm: float
    density: float
    margin_mm: float


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _scan(name, rng, exact, normals, interior, sigma, density, margin) -> Surface:
    normals = _unit(normals)
    view = SCANNER_VIEWS[np.argmax(normals @ SCANNER_VIEWS.T, axis=1)]
    noisy = exact + rng.normal(0.0, sigma, exact.shape[0])[:, None] * view if sigma > 0 else exact.copy()
    return Surface(name=name, points=noisy, normals=normals, interior=interior, sigma_mm=float(sigma),
                   density=float(density), margin_mm=float(margin))


def _graph(name, f, grad, half_x, half_y, *, density, sigma, margin, seed) -> Surface:
    """z = f(x, y) over [-half_x, half_x] x [-half_y, half_y], uniform per true area."""
    rng = np.random.default_rng(seed)
    # bound of the area element sqrt(1 + |grad|^2) on a fine grid (+5 %)
    gx, gy = np.meshgrid(np.linspace(-half_x, half_x, 201), np.linspace(-half_y, half_y, 201))
    fx, fy = grad(gx, gy)
    jmax = 1.05 * float(np.sqrt(1.0 + fx * fx + fy * fy).max())
    area_xy = 4.0 * half_x * half_y
    m = int(density * area_xy * jmax * 1.02) + 16
    x = rng.uniform(-half_x, half_x, m)
    y = rng.uniform(-half_y, half_y, m)
    fx, fy = grad(x, y)
    jac = np.sqrt(1.0 + fx * fx + fy * fy)
    keep = rng.random(m) * jmax < jac
    x, y, fx, fy = x[keep], y[keep], fx[keep], fy[keep]
    exact = np.column_stack((x, y, f(x, y)))
    normals = np.column_stack((-fx, -fy, np.ones_like(x)))
    interior = (np.abs(x) < half_x - margin) & (np.abs(y) < half_y - margin)
    return _scan(name, rng, exact, normals, interior, sigma, density, margin)


def plane(size_mm: float = 30.0, tilt_deg: float = 0.0, *, density: float = DEFAULT_DENSITY,
          sigma_mm: float = DEFAULT_SIGMA_MM, margin_mm: float = 4.0, seed: int = 1) -> Surface:
    """Plane ``z = tan(tilt) x`` over a square of side ``size_mm`` in x, y; normal tilted towards -x."""
    t = math.tan(math.radians(tilt_deg))
    h = size_mm / 2.0
    return _graph(f"plane{tilt_deg:g}", lambda x, y: t * x, lambda x, y: (np.full_like(x, t), np.zeros_like(y)),
                  h, h, density=density, sigma=sigma_mm, margin=margin_mm, seed=seed)


def wave(size_mm: float = 40.0, amplitude_mm: float = 2.0, length_mm: float = 5.0, *,
         density: float = DEFAULT_DENSITY, sigma_mm: float = DEFAULT_SIGMA_MM, margin_mm: float = 4.0,
         seed: int = 2) -> Surface:
    """``z = a sin(x / l) cos(y / l)``: slopes up to a/l (22 deg), curvature radii >= l^2/a (12.5 mm)."""
    a, l = amplitude_mm, length_mm
    h = size_mm / 2.0
    return _graph("wave", lambda x, y: a * np.sin(x / l) * np.cos(y / l),
                  lambda x, y: (a / l * np.cos(x / l) * np.cos(y / l), -a / l * np.sin(x / l) * np.sin(y / l)),
                  h, h, density=density, sigma=sigma_mm, margin=margin_mm, seed=seed)


def saddle(size_mm: float = 30.0, c_mm: float = 60.0, *, density: float = DEFAULT_DENSITY,
           sigma_mm: float = DEFAULT_SIGMA_MM, margin_mm: float = 4.0, seed: int = 3) -> Surface:
    """``z = (x^2 - y^2) / c``: slopes up to size/c (27 deg), principal radii c/2 = 30 mm."""
    h = size_mm / 2.0
    return _graph("saddle", lambda x, y: (x * x - y * y) / c_mm, lambda x, y: (2 * x / c_mm, -2 * y / c_mm),
                  h, h, density=density, sigma=sigma_mm, margin=margin_mm, seed=seed)


def sphere(radius_mm: float = 40.0, *, z_min_mm: float = 0.0, density: float = DEFAULT_DENSITY,
           sigma_mm: float = DEFAULT_SIGMA_MM, margin_mm: float = 4.0, seed: int = 4) -> Surface:
    """The part of the sphere of radius R about the origin with ``z >= z_min_mm`` (default the upper
    hemisphere; ``z_min_mm = -R`` gives the whole sphere). Interior: ``z >= z_min + margin``."""
    rng = np.random.default_rng(seed)
    R = radius_mm
    zmin = max(-R, min(R, z_min_mm))
    area = 2.0 * math.pi * R * (R - zmin)
    n = int(round(density * area))
    z = rng.uniform(zmin, R, n)                     # Archimedes: uniform in z is uniform in area
    phi = rng.uniform(0.0, 2.0 * math.pi, n)
    rho = np.sqrt(np.maximum(R * R - z * z, 0.0))
    exact = np.column_stack((rho * np.cos(phi), rho * np.sin(phi), z))
    interior = z >= zmin + margin_mm if zmin > -R else np.ones(n, dtype=bool)
    return _scan(f"sphere{R:g}", rng, exact, exact.copy(), interior, sigma_mm, density, margin_mm)


def cylinder(radius_mm: float = 25.0, length_mm: float = 50.0, *, density: float = DEFAULT_DENSITY,
             sigma_mm: float = DEFAULT_SIGMA_MM, margin_mm: float = 4.0, seed: int = 5) -> Surface:
    """Closed cylinder of radius R about the X axis, |x| <= L/2, capped by two flat discs (a bar
    scanned all around). Closed, so no ball reaches the inside. Interior: points at least
    ``margin_mm`` from the two sharp circular edges (on the side: |x| <= L/2 - margin; on a cap:
    distance from the axis <= R - margin), where the exact normal is discontinuous."""
    rng = np.random.default_rng(seed)
    R, L = radius_mm, length_mm
    n_side = int(round(density * 2.0 * math.pi * R * L))
    n_cap = int(round(density * math.pi * R * R))
    x = rng.uniform(-L / 2.0, L / 2.0, n_side)
    ang = rng.uniform(0.0, 2.0 * math.pi, n_side)
    side = np.column_stack((x, R * np.cos(ang), R * np.sin(ang)))
    side_n = np.column_stack((np.zeros(n_side), np.cos(ang), np.sin(ang)))
    side_in = np.abs(x) <= L / 2.0 - margin_mm
    pts, nrm, inside = [side], [side_n], [side_in]
    for sign in (-1.0, 1.0):
        rho = R * np.sqrt(rng.random(n_cap))          # uniform on the disc
        a = rng.uniform(0.0, 2.0 * math.pi, n_cap)
        pts.append(np.column_stack((np.full(n_cap, sign * L / 2.0), rho * np.cos(a), rho * np.sin(a))))
        nrm.append(np.tile([sign, 0.0, 0.0], (n_cap, 1)))
        inside.append(rho <= R - margin_mm)
    return _scan(f"cylinder{R:g}", rng, np.vstack(pts), np.vstack(nrm), np.concatenate(inside),
                 sigma_mm, density, margin_mm)


def angular_error_deg(estimated: np.ndarray, exact: np.ndarray) -> np.ndarray:
    """Angle in degrees between matching rows of two (n,3) arrays of unit vectors."""
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", estimated, exact), -1.0, 1.0)))
