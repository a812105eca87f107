"""Stage 1, reference samples: the :class:`Sample` every generator returns and the argument checks.

A sample's points are in millimetres. The checks raise :class:`~planning.errors.ParameterError`
in scikit-learn style (name, value and allowed range in the message) and return the value as a
plain ``int``/``float`` (or a tuple of lengths in mm for :func:`_check_size`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planning.errors import ParameterError

__all__ = ["Sample"]


@dataclass(frozen=True, eq=False)
class Sample:
    """A generated cloud.

    ``points``: ``(N, 3)`` float64, mm (noisy where the sample simulates a scanner).
    ``normals``: ``(N, 3)`` float64 exact outward unit normals of the underlying surface at the
    point each row was drawn from (before noise), or ``None``.
    ``description``: one line for people. ``meta``: generation parameters and known answers.
    Compared by identity (the arrays make field-wise equality ambiguous).
    """

    name: str
    points: np.ndarray
    normals: np.ndarray | None
    description: str
    meta: dict = field(default_factory=dict)


def _check_int(name: str, value, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ParameterError(f"{name} = {value!r}: must be an integer in [{lo}, {hi}]",
                             parameter=name, value=repr(value), allowed=f"[{lo}, {hi}]")
    v = int(value)
    if not lo <= v <= hi:
        raise ParameterError(f"{name} = {v}: must be an integer in [{lo}, {hi}]",
                             parameter=name, value=v, allowed=f"[{lo}, {hi}]")
    return v


def _check_float(name: str, value, lo: float, hi: float, *, lo_open: bool = True,
                 unit: str = "mm") -> float:
    interval = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ParameterError(f"{name} = {value!r}: must be a number in {interval} {unit}",
                             parameter=name, value=repr(value), allowed=interval)
    v = float(value)
    ok = math.isfinite(v) and (lo < v if lo_open else lo <= v) and v <= hi
    if not ok:
        raise ParameterError(f"{name} = {v:g}: must be in {interval} {unit}",
                             parameter=name, value=v, allowed=interval)
    return v


def _check_seed(seed) -> int:
    return _check_int("seed", seed, 0, 2**63 - 1)


def _check_size(name, value, k):
    try:
        vals = tuple(float(v) for v in value)
    except TypeError:
        vals = ()
    if len(vals) != k or not all(math.isfinite(v) and 0.0 < v <= 1e5 for v in vals):
        raise ParameterError(f"{name} = {value!r}: must be {k} positive lengths in mm (each <= 1e5)",
                             parameter=name, value=repr(value), allowed=f"{k} numbers in (0, 1e5]")
    return vals
