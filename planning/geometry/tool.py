"""The tool assembly as the collision tests see it: a ball and a stack of coaxial cylinders.

Makki 2010 §2.2.4 models the tool and its holder as cylinders along the tool axis. Here every
length is measured along the tool axis ``t`` (unit, part frame, from the part towards the spindle)
from the **ball centre** ``c`` (for a ball-end mill of radius ``R`` touching point ``p`` with unit
normal ``n``: ``c = p + R n``). A :class:`Segment` ``(lo, hi, r)`` is the solid cylinder
``{c + a t + w : lo < a <= hi, w . t = 0, |w| < r}``; ``hi = None`` means unbounded towards the
spindle. The ball's lower half (``a <= 0``) is not a segment: it is where the cutter touches the
surface and belongs to the local gouge test of the tool paths.

The assembly is, from the tip upwards:

* cutter: radius ``R`` from ``a = 0`` to the top of the flutes, ``a = flute_length - R``;
* shank: radius ``shank_diameter / 2`` from there to the holder face, ``a = stickout - R``;
* holder elements, each a cylinder or a cone (a cone is replaced by short cylinders, each with
  the larger radius of its slice, so the model contains the real cone: conservative by at most
  :data:`CONE_SLICE_MM` of radius), stacked from the holder face towards the spindle.

``gauge_length_mm`` is the distance from the tool tip to the spindle gauge line (the point the
machine's linear axes position), used by the translational travel check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

from planning.errors import ParameterError

#: Largest radial over-estimate when a cone is sliced into cylinders, mm.
CONE_SLICE_MM = 0.1


@dataclass(frozen=True)
class Segment:
    """Solid cylinder ``lo_mm < a <= hi_mm``, ``rho < radius_mm`` about the tool axis (mm from the
    ball centre along the axis; ``hi_mm=None``: unbounded). ``part`` names what it models."""

    lo_mm: float
    hi_mm: Optional[float]
    radius_mm: float
    part: str = "holder"


@dataclass(frozen=True)
class ToolAssembly:
    """A ball-end cutter of radius ``radius_mm`` and the segments above its ball centre."""

    radius_mm: float
    segments: tuple[Segment, ...]
    gauge_length_mm: float

    @property
    def cutter_segments(self) -> tuple[Segment, ...]:
        """Cutter and shank segments (the tool itself)."""
        return tuple(s for s in self.segments if s.part in ("cutter", "shank"))

    @property
    def holder_segments(self) -> tuple[Segment, ...]:
        """Holder segments (everything above the holder face)."""
        return tuple(s for s in self.segments if s.part == "holder")

    @property
    def top_mm(self) -> Optional[float]:
        """Highest ``a`` of the assembly above the ball centre (None when unbounded)."""
        if any(s.hi_mm is None for s in self.segments):
            return None
        return max((s.hi_mm for s in self.segments), default=0.0)


def _cone_slices(lo: float, length: float, r0: float, r1: float, part: str) -> list[Segment]:
    if abs(r1 - r0) <= 1e-12:
        return [Segment(lo, lo + length, r0, part)]
    n = max(1, int(math.ceil(abs(r1 - r0) / CONE_SLICE_MM)))
    out = []
    for k in range(n):
        a0 = lo + length * k / n
        a1 = lo + length * (k + 1) / n
        ra = r0 + (r1 - r0) * k / n
        rb = r0 + (r1 - r0) * (k + 1) / n
        out.append(Segment(a0, a1, max(ra, rb), part))
    return out


def ball_tool(radius_mm: float, *, flute_length_mm: float, stickout_mm: Optional[float] = None,
              shank_radius_mm: Optional[float] = None,
              holder: Sequence[tuple[float, Optional[float], Optional[float]]] = (),
              gauge_length_mm: Optional[float] = None) -> ToolAssembly:
    """Build a :class:`ToolAssembly` for a ball-end mill (all lengths and radii in mm).

    ``flute_length_mm`` and ``stickout_mm`` are measured from the tool tip (stickout: tip to the
    holder face; default = flute length). ``holder`` lists ``(radius_bottom, length, radius_top)``
    from the holder face towards the spindle; ``length=None`` (last element only) is unbounded and
    ``radius_top=None`` means a cylinder. ``gauge_length_mm`` defaults to stickout + holder lengths.
    """
    R = float(radius_mm)
    if not R > 0:
        raise ParameterError(f"tool radius {radius_mm} mm: must be > 0")
    F = float(flute_length_mm)
    S = F if stickout_mm is None else float(stickout_mm)
    if not F >= R:
        raise ParameterError(f"tool.flute_length_mm = {F:g} must be at least the ball radius {R:g} mm")
    if not S >= F:
        raise ParameterError(f"tool.stickout_mm = {S:g} must be at least tool.flute_length_mm = {F:g}")
    rs = R if shank_radius_mm is None else float(shank_radius_mm)
    if not rs > 0:
        raise ParameterError("tool.shank_diameter_mm must be > 0")
    segs: list[Segment] = []
    if F > R:
        segs.append(Segment(0.0, F - R, R, "cutter"))
    if S > F:
        segs.append(Segment(F - R, S - R, rs, "shank"))
    a = S - R
    total = S
    for i, (r0, length, r1) in enumerate(holder):
        if length is None:
            if i != len(holder) - 1:
                raise ParameterError("only the last holder element may be unbounded (length null)")
            segs.append(Segment(a, None, max(float(r0), float(r1 if r1 is not None else r0)), "holder"))
            break
        if not (r0 > 0 and length > 0 and (r1 is None or r1 > 0)):
            raise ParameterError(f"tool.holder[{i}]: diameters and length must be > 0")
        segs.extend(_cone_slices(a, float(length), float(r0), float(r0 if r1 is None else r1), "holder"))
        a += float(length)
        total += float(length)
    if not segs:
        # a bare ball (flute length = R, no holder): a zero-height cutter cylinder keeps the model
        # well defined (it can collide with nothing)
        segs.append(Segment(0.0, 0.0, R, "cutter"))
    g = total if gauge_length_mm is None else float(gauge_length_mm)
    if not g >= S:
        raise ParameterError(f"tool.gauge_length_mm = {g:g} must be at least the stick-out {S:g} mm")
    return ToolAssembly(radius_mm=R, segments=tuple(segs), gauge_length_mm=g)
