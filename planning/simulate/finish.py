"""The finish measured exactly from the finishing moves (issue 31, item 1).

The deviation read on the tri-dexel stock (:func:`planning.simulate.run.deviation_pair`) is read on
rays ``simulate.resolution_mm`` apart (1 mm by default): it cannot see a scallop of a few hundredths
between two passes, and it reads a cusp or a seam as a cut. Here the material the finishing ball
leaves over every scan point is measured from the moves themselves:

* the finishing tool is the plan's ball-end cutter of radius R (:func:`planning.simulate.tools.finishing_shape`);
  on a feed move from tip ``s`` to tip ``e`` with unit axis ``a`` (the program's rotary position) the
  ball's centre runs along the segment ``s + R a .. e + R a``, so the ball sweeps the capsule of
  radius R about that segment. A 5-axis move comes as the reader's steps, each with the axis at its
  end; a step that continues the one before starts where that step left the ball, ``s + R a0`` (the
  rule of :func:`planning.simulate.gouge.penetration_mm`, whose ball layer this is);
* the **material left** over a point p is ``min over the finishing feed moves of dist(p, centre
  segment) - R`` (mm): positive, the surface the ball swept lies that far from p (the scallop
  between passes, or stock the finishing never came down to); negative, the ball went that deep
  below p (a cut below the scan by the finishing tool). Lines exactly; arcs as the program reader's
  chords (within :data:`planning.simulate.verify.READER_CHORD_TOL_MM`);
* a point that no finishing move comes near is *not reached*: ``+inf`` (a move counts for a point when
  the middle of one of its :data:`planning.simulate.gouge.PIECE_MM` pieces lies within
  ``PIECE_MM / 2 + 2 R +`` :data:`BEYOND_MM` of it: 9 mm for R 3 mm).

This is the ball layer of the exact gouge depth (:func:`planning.simulate.gouge.penetration_mm`,
the same numba kernels: binned pieces, the points in parallel) with the finishing tool alone and
without its fluted side above the ball: left = -depth.

What it does not see: material the roughing left that the ball never touched is "not reached" or
read as the ball's distance (the tri-dexel deviation still reports the stock); the flank of the
flutes above the ball (it cuts walls steeper than the ball's reach; the tri-dexel stock has it).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from planning.simulate.motion import ProgramMotion, ToolShape

Progress = Callable[[float, str], None]

#: The moves are searched this far (mm) beyond the ball's own reach, so that material left up to about
#: this is settled by the kernels' bounded search alone (:func:`planning.simulate.gouge.penetration_mm`,
#: ``beyond_mm``); more left is measured as exactly, by a second, unbounded search of the same moves.
BEYOND_MM = 1.0


def finish_left_mm(points: np.ndarray, motions: list[ProgramMotion], finishing: ToolShape,
                   progress: Progress | None = None) -> np.ndarray:
    """(n,) the material the finishing ball leaves over each of ``points`` (n,3, part frame, mm): the
    distance from the point to the surface the ball swept on the feed moves of ``motions`` made with
    ``finishing`` (its T number; a ball, radius R), minus nothing: ``min dist(p, centre segment) - R``
    (module docstring); negative where the ball went below the point; ``+inf`` where no finishing
    move reaches it and at points with a non-finite coordinate.

    ``progress(fraction, message)`` as :func:`planning.simulate.gouge.penetration_mm` calls it."""
    from planning.simulate.gouge import penetration_mm

    if finishing.kind != "ball":
        raise ValueError(f"the finishing tool must be a ball-end cutter, got {finishing.kind!r}")
    # the ball alone: with the flutes no longer than the ball there is no side layer
    ball = dataclasses.replace(finishing, flute_length_mm=float(finishing.radius_mm), pieces=())
    said = None if progress is None else (lambda f, m: progress(f, m.replace("exact gouge depth", "material left")))
    depth = penetration_mm(points, motions, {int(finishing.number): ball}, said, beyond_mm=BEYOND_MM)
    return -depth
