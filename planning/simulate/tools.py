"""The tools in the spindle as the simulation sees them (:class:`planning.simulate.motion.ToolShape`).

* T ``post.finishing_tool_number``: the ball-end cutter of ``tool.*`` (:class:`ToolAssembly`): its
  cutting part is the ball and the fluted cylinder up to ``tool.flute_length_mm`` from the tip; the
  shank and the holder pieces above are non-cutting (a cone is already sliced into cylinders of
  its larger radius, conservative by at most :data:`planning.geometry.tool.CONE_SLICE_MM`).
* T ``post.roughing_tool_number``: the flat or bull-nose end mill of ``paths.roughing.*``. The
  configuration says nothing of its holding, so it is taken as held like the finishing cutter: the
  same stick-out, fluted over the whole stick-out (its shank is no wider than its cut, so only the
  holder can rub), the same holder and gauge length.
"""

from __future__ import annotations

import math

from planning.geometry.tool import ToolAssembly
from planning.simulate.motion import ToolShape


def _holder_pieces(tool: ToolAssembly, from_mm: float) -> tuple[tuple[float, float, float], ...]:
    """The assembly's segments above ``from_mm`` (measured from the tip) as (z0, z1, radius) pieces."""
    R = tool.radius_mm
    out = []
    for s in tool.segments:
        lo = s.lo_mm + R
        hi = math.inf if s.hi_mm is None else s.hi_mm + R
        if hi <= from_mm + 1e-12:
            continue
        out.append((max(lo, from_mm), hi, float(s.radius_mm)))
    return tuple(out)


def finishing_shape(tool: ToolAssembly, number: int, flute_length_mm: float) -> ToolShape:
    """The ball-end cutter of the plan (see the module docstring); lengths in mm from the tip."""
    R = float(tool.radius_mm)
    return ToolShape(number=int(number), kind="ball", radius_mm=R, corner_radius_mm=R,
                     flute_length_mm=float(flute_length_mm), pieces=_holder_pieces(tool, float(flute_length_mm)),
                     gauge_length_mm=float(tool.gauge_length_mm))


def roughing_shape(tool: ToolAssembly, number: int, roughing, stickout_mm: float) -> ToolShape:
    """The roughing end mill (``roughing``: :class:`schemas.params.RoughingParams`), held like the
    finishing cutter (see the module docstring); lengths in mm from the tip."""
    R = float(roughing.diameter_mm) / 2.0
    rc = float(roughing.corner_radius_mm) if roughing.tool_type == "bull" else 0.0
    holder = tuple(p for p in _holder_pieces(tool, float(stickout_mm)))
    return ToolShape(number=int(number), kind="bull" if rc > 0 else "flat", radius_mm=R, corner_radius_mm=rc,
                     flute_length_mm=float(stickout_mm), pieces=holder, gauge_length_mm=float(tool.gauge_length_mm))
