"""Candidate tool axes on the discretized Gaussian sphere (Makki 2010 §2.2.1).

Every candidate is a unit vector in the PART frame pointing from the part towards the spindle
(docs/design.md conventions), given with its spherical coordinates:

* ``phi_deg``   polar angle from part +Z, in [0, 180] degrees;
* ``theta_deg`` azimuth from part +X towards +Y, in [0, 360) degrees (0 at the poles),

so that ``axis = (sin phi cos theta, sin phi sin theta, cos phi)``.

Two samplings (``orientations.sampling``):

* ``phi_theta`` (:func:`phi_theta_axes`) — the paper's grid of phi and theta steps;
* ``uniform`` (:func:`uniform_axes`) — a deterministic near-uniform Fibonacci-spiral sampling whose
  covering radius (largest angle from any direction to its nearest axis) is at most
  ``resolution_deg``.

Pure functions, deterministic: the same parameters always give the same axes in the same order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planning.errors import ParameterError

__all__ = [
    "CandidateAxes",
    "phi_theta_axes",
    "uniform_axes",
    "candidate_axes",
    "MAX_AXES",
    "FIBONACCI_COVERING_CONSTANT",
]

#: Largest number of candidate axes a sampling may produce (guards against absurdly fine steps:
#: the visibility matrix is (n_points, n_axes)).
MAX_AXES = 1_000_000

#: Covering radius (radians) of the offset Fibonacci spiral times sqrt(n). Measured exactly with a
#: spherical Voronoi diagram for every n in 4..400 and for n up to 41,253: the maximum is 2.7336
#: (n = 19-20, at the polar caps) and the value tends to 2.7281 for large n. 2.74 is a safe bound.
FIBONACCI_COVERING_CONSTANT = 2.74

# Tolerance (in units of the step) when deciding whether 180 / 360 is a multiple of a step.
_STEP_EPS = 1e-9


@dataclass(frozen=True)
class CandidateAxes:
    """Candidate tool axes (Makki §2.2.1).

    ``axes`` (m,3) float64 unit vectors in the part frame (part -> spindle); ``phi_deg`` (m,) polar
    angle from +Z in [0, 180] degrees; ``theta_deg`` (m,) azimuth from +X towards +Y in [0, 360)
    degrees (0 at the poles).
    """

    axes: np.ndarray
    phi_deg: np.ndarray
    theta_deg: np.ndarray

    def __len__(self) -> int:
        return int(self.axes.shape[0])


# ----------------------------------------------------------------------------------------------
# helpers


def _check_number(name: str, value, lo: float, hi: float, unit: str = "degrees") -> float:
    """Return ``value`` as float if ``lo < value <= hi``; else raise ParameterError naming it."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ParameterError(
            f"{name} = {value!r}: must be a number in ({lo:g}, {hi:g}] {unit}",
            parameter=name, value=repr(value), allowed=f"({lo:g}, {hi:g}]")
    v = float(value)
    if not (math.isfinite(v) and lo < v <= hi):
        raise ParameterError(
            f"{name} = {v:g}: must be in ({lo:g}, {hi:g}] {unit}",
            parameter=name, value=v, allowed=f"({lo:g}, {hi:g}]")
    return v


def _sincos_deg(angle_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """sin and cos of angles in degrees, exact (0, +-1) at multiples of 90 degrees.

    The angle is reduced to [-45, 45] about the nearest multiple of 90 before converting to radians,
    so e.g. ``cos(90 deg)`` is exactly 0 and ``sin(180 deg)`` exactly 0 (no 6e-17 residue).
    """
    a = np.asarray(angle_deg, dtype=np.float64)
    q = np.round(a / 90.0)
    r = np.radians(a - 90.0 * q)
    s, c = np.sin(r), np.cos(r)
    k = np.mod(q, 4).astype(np.int64)
    sin = np.select([k == 0, k == 1, k == 2, k == 3], [s, c, -s, -c])
    cos = np.select([k == 0, k == 1, k == 2, k == 3], [c, -s, -c, s])
    return sin + 0.0, cos + 0.0   # + 0.0 turns -0.0 into 0.0


def _axes_from_angles(phi_deg: np.ndarray, theta_deg: np.ndarray) -> np.ndarray:
    sp, cp = _sincos_deg(phi_deg)
    st, ct = _sincos_deg(theta_deg)
    return np.stack([sp * ct, sp * st, cp], axis=1)


def _angles_from_axes(axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(phi_deg, theta_deg) of unit vectors; theta 0 where the horizontal part vanishes."""
    h = np.hypot(axes[:, 0], axes[:, 1])
    phi = np.degrees(np.arctan2(h, axes[:, 2]))
    theta = np.degrees(np.arctan2(axes[:, 1], axes[:, 0]))
    theta = np.where(h > 0.0, theta, 0.0)
    theta = np.mod(theta, 360.0)
    theta = np.where(theta >= 360.0, 0.0, theta)   # mod of a tiny negative number can round to 360
    return phi, theta + 0.0


# ----------------------------------------------------------------------------------------------
# samplings


def phi_theta_axes(phi_step_deg: float = 10.0, theta_step_deg: float = 30.0) -> CandidateAxes:
    """The paper's grid of tool axes on the Gaussian sphere (Makki 2010 §2.2.1, Fig. 3).

    phi (polar angle from part +Z, degrees) takes the values 0, s, 2s, ... <= 180, 180 included
    only when it is a multiple of ``phi_step_deg`` = s; theta (azimuth from +X towards +Y, degrees)
    takes 0, t, 2t, ... < 360 with ``theta_step_deg`` = t. The poles phi = 0 and phi = 180 appear
    once, with theta = 0. Order: phi ascending, then theta ascending. The axes are
    ``(sin phi cos theta, sin phi sin theta, cos phi)`` (unit, part frame, part -> spindle), with
    exact zeros and ones at multiples of 90 degrees.

    With the defaults (10, 30): 17 x 12 + 2 = 206 axes; the paper's best pair on its half sphere,
    (phi 50, theta 30) and (phi 110, theta 210), is among them.

    ``phi_step_deg`` must lie in (0, 180] and ``theta_step_deg`` in (0, 360] degrees; otherwise,
    or when the grid would exceed :data:`MAX_AXES` axes, :class:`ParameterError` is raised.
    """
    s = _check_number("orientations.phi_step_deg", phi_step_deg, 0.0, 180.0)
    t = _check_number("orientations.theta_step_deg", theta_step_deg, 0.0, 360.0)

    n_phi = int(math.floor(180.0 / s + _STEP_EPS))          # last index with k*s <= 180
    south = abs(n_phi * s - 180.0) <= _STEP_EPS * s         # 180 is a multiple of s
    n_theta = int(math.ceil(360.0 / t - _STEP_EPS))         # k*t < 360 for k < n_theta
    n_rings = n_phi - 1 if south else n_phi                 # phi strictly between the poles
    count = 1 + n_rings * n_theta + (1 if south else 0)
    if count > MAX_AXES:
        raise ParameterError(
            f"orientations.phi_step_deg = {s:g} and orientations.theta_step_deg = {t:g} give {count} axes; "
            f"at most {MAX_AXES} are allowed: use larger steps",
            parameter="orientations.phi_step_deg", value=s, allowed=f"at most {MAX_AXES} axes")

    ring_phi = np.arange(1, n_rings + 1, dtype=np.float64) * s
    thetas = np.arange(n_theta, dtype=np.float64) * t
    phi = np.concatenate([[0.0], np.repeat(ring_phi, n_theta)])
    theta = np.concatenate([[0.0], np.tile(thetas, n_rings)])
    if south:
        phi = np.concatenate([phi, [180.0]])
        theta = np.concatenate([theta, [0.0]])
    axes = _axes_from_angles(phi, theta)
    return CandidateAxes(axes=axes, phi_deg=phi, theta_deg=theta)


def uniform_axes(resolution_deg: float = 10.0) -> CandidateAxes:
    """A deterministic near-uniform sampling of the whole Gaussian sphere (extends Makki §2.2.1).

    The axes are the offset Fibonacci spiral of n points: ``z_i = 1 - (2 i + 1) / n`` and azimuth
    ``i * 137.508 deg`` (the golden angle), i = 0..n-1, in that order. ``resolution_deg`` is the
    COVERING RADIUS: every unit direction lies within ``resolution_deg`` degrees of some axis.
    n = max(4, ceil((K / resolution_rad)^2)) with K = :data:`FIBONACCI_COVERING_CONSTANT` (the
    spiral's covering radius is at most 2.7336 / sqrt(n) radians, measured). The mean angle between
    an axis and its nearest neighbour is then about 1.24 x ``resolution_deg``; the count scales as
    1 / resolution^2 (10 deg: 247 axes, 5 deg: 986 axes). The poles are not axes as such but lie
    within ``resolution_deg`` of one.

    ``phi_deg`` / ``theta_deg`` (degrees) are computed from the axes. ``resolution_deg`` must lie in
    (0, 90] degrees and give at most :data:`MAX_AXES` axes; otherwise :class:`ParameterError`.
    """
    res = _check_number("orientations.resolution_deg", resolution_deg, 0.0, 90.0)
    res_rad = math.radians(res)
    n_f = (FIBONACCI_COVERING_CONSTANT / res_rad) ** 2
    if n_f > MAX_AXES:
        raise ParameterError(
            f"orientations.resolution_deg = {res:g} needs about {int(n_f)} axes; at most {MAX_AXES} are "
            f"allowed: use a resolution of at least "
            f"{math.degrees(FIBONACCI_COVERING_CONSTANT / math.sqrt(MAX_AXES)):.2f} degrees",
            parameter="orientations.resolution_deg", value=res, allowed=f"at most {MAX_AXES} axes")
    n = max(4, int(math.ceil(n_f - 1e-9)))
    i = np.arange(n, dtype=np.float64)
    z = 1.0 - (2.0 * i + 1.0) / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    golden_rad = math.pi * (3.0 - math.sqrt(5.0))
    az_rad = np.mod(golden_rad * i, 2.0 * math.pi)
    axes = np.stack([r * np.cos(az_rad), r * np.sin(az_rad), z], axis=1)
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    phi, theta = _angles_from_axes(axes)
    return CandidateAxes(axes=axes, phi_deg=phi, theta_deg=theta)


SAMPLINGS = ("phi_theta", "uniform")


def candidate_axes(sampling: str = "phi_theta", *, phi_step_deg: float = 10.0, theta_step_deg: float = 30.0,
                   resolution_deg: float = 10.0) -> CandidateAxes:
    """Candidate tool axes for ``orientations.sampling`` (Makki §2.2.1), unit vectors, part frame.

    ``'phi_theta'`` -> :func:`phi_theta_axes` (``phi_step_deg``, ``theta_step_deg``, degrees);
    ``'uniform'`` -> :func:`uniform_axes` (``resolution_deg``, degrees, covering radius). The
    parameters of the other sampling are ignored. An unknown sampling raises :class:`ParameterError`.
    """
    if sampling == "phi_theta":
        return phi_theta_axes(phi_step_deg, theta_step_deg)
    if sampling == "uniform":
        return uniform_axes(resolution_deg)
    raise ParameterError(
        f"orientations.sampling = {sampling!r}: must be one of {', '.join(repr(s) for s in SAMPLINGS)}",
        parameter="orientations.sampling", value=repr(sampling), allowed=list(SAMPLINGS))
