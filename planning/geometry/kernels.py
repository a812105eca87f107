"""Small pieces every compiled kernel may use, and the result of a drop: no stage's code.

* :func:`serial_twin`: a serial copy of a parallel numba kernel with its own cache entry;
* :func:`interval_gap`: the distance between two intervals (the cell and box bounds of the rasters);
* :class:`BallDrop`: what a ball-end cutter dropped on a surface answers per vertical line (the
  point drop of :mod:`planning.toolpath.balldrop`, the triangle drop of :mod:`planning.geometry.triangles`).
"""

from __future__ import annotations

import types
from dataclasses import dataclass

import numpy as np
from numba import njit


def serial_twin(kernel, name: str):
    """A serial (``nogil``) copy of the parallel numba ``kernel`` under its own ``name``. numba's
    cache keys an entry by the function's module, qualified name, line and signature, not by its
    flags: ``njit(cache=True)(kernel.py_func)`` shares the parallel kernel's cache entry, and
    whichever of the two compiled first is loaded for both (the "serial" one then started the
    thread pool on every small call). A copy of the function object with another qualified name
    gets its own entry."""
    f = kernel.py_func
    g = types.FunctionType(f.__code__, f.__globals__, name, f.__defaults__, f.__closure__)
    g.__qualname__ = name
    g.__doc__ = f.__doc__
    return njit(cache=True, nogil=True)(g)


@njit(cache=True, nogil=True)
def interval_gap(a0, a1, b0, b1):
    """Distance between the intervals [a0, a1] and [b0, b1] (0 when they overlap)."""
    if a1 < b0:
        return b0 - a1
    if b1 < a0:
        return a0 - b1
    return 0.0


@dataclass(frozen=True)
class BallDrop:
    """``z_mm`` (K,) ball-centre heights (``-inf`` where nothing lies within R of the line); ``contact``
    (K,) index of what the ball rests on (a point, or a triangle for a triangle drop; -1 where none)."""

    z_mm: np.ndarray
    contact: np.ndarray
