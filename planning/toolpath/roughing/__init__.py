"""Z-level roughing of one set-up with a flat or bull-nose end mill, straight from the cloud
(Popescu et al. 2014: slices, a binary occupancy map per slice, linking by shortest paths on a
graph; Tchanchane & Bey: the part's contours offset by R + stock allowance, parallel lines One-Way
or Zig-Zag clipped by them, then a pass along the offset contour). Everything is in the area frame
(:mod:`planning.toolpath.frames`: tool axis +Z; in a set-up frame every cloud point has z <= 0),
in mm; the path records the tool TIP (``Toolpath.tip_offset_mm = 0``). Stage: part of stage 7
(tool paths per area, :mod:`planning.toolpath`): :mod:`planning.toolpath.area_paths` calls
:func:`roughing_paths` once per area, before the finishing passes.

**Tool.** A flat end mill of radius ``Rt`` or a bull-nose with corner radius ``rc`` (flat-bottom
radius ``Rf = Rt - rc``): the points within ``rc`` of the core, the half-infinite cylinder
``rho <= Rf, z >= tip + rc`` (``rc = 0``: the flat cylinder ``rho <= Rt, z >= tip``). Flutes,
shank and holder are this cylinder continued upwards without end (conservative for a shank no
wider than the cutter; the holder is not modelled). A cloud point's *clearance* is its distance
to that solid (0 or below: inside the tool).

**Stock.** The cloud's bounding box grown by ``stock_margin_mm`` on the four sides and on the top:
the stock top is the highest cloud z + ``stock_margin_mm`` (so ``stock_margin_mm`` in a set-up
frame). Each set-up starts from this full box: material removed by earlier set-ups is NOT
modelled, so some lines may cut air. With a window (``window_xy_mm``, ``window_reach_mm``) the tool
centre cuts only within the given reach of the window's points (the area being machined); the
stock outside it is left to the other set-ups.

**Levels.** Tip heights from the stock top down every ``step_down_mm``, the last exactly at the
floor (``floor_z_mm``, default the lowest cloud z + allowance; the caller passes the area's
lowest point + allowance); a level within 1e-6 mm above the floor is dropped.

**Modules**, one per concern (the entry first, in the order the stages run):

- :mod:`~planning.toolpath.roughing.levels`: the entry :func:`roughing_paths` (arguments, stock,
  levels) and its result :class:`RoughingPath`; cuts the levels from the top down.
- :mod:`~planning.toolpath.roughing.maps`: the planning raster, the forbidden map (Popescu's binary
  map per level, made conservative) and the remaining-material map.
- :mod:`~planning.toolpath.roughing.regions`: a level's clearing region, its connected components
  and its boundary loops (marching squares).
- :mod:`~planning.toolpath.roughing.clearing`: the clearing lines clipped to the region and the
  offset contours (Tchanchane & Bey).
- :mod:`~planning.toolpath.roughing.ordering`: the order of a level's pieces (components,
  boustrophedon zones, contours).
- :mod:`~planning.toolpath.roughing.links`: feed links at the level (Popescu: shortest paths on a
  graph) and lifts over the remaining material.
- :mod:`~planning.toolpath.roughing.clearance`: the verification, :func:`min_tool_clearance`.
- :mod:`~planning.toolpath.roughing.common`: argument checks and small kernels they share.

**Cost.** Per set-up: one pass over the cloud for the cells' highest points and one disc maximum
per sub-band; per level: one pass over the raster (the region and its runs), the boundary from
the runs (only the 2 x 2 blocks that can be mixed), the links' grid searches (in a window, scratch
arrays reused), the coarse material map; then one counting sort of the cloud for the
verification. The default raster of the femur-like case is about 1300 x 650 cells.

Simplified: no trochoidal or adaptive clearing, no ramped entries (plunges are straight down), no
holder or fixture collisions, no material model of earlier set-ups, no rest machining of the
corners a cutter of radius Rt cannot enter.
"""

from planning.toolpath.roughing.clearance import ToolClearance, min_tool_clearance
from planning.toolpath.roughing.levels import REMOVED_NOTE, RoughingPath, roughing_paths
from planning.toolpath.roughing.links import GAP_MM

__all__ = ["GAP_MM", "REMOVED_NOTE", "RoughingPath", "ToolClearance", "min_tool_clearance", "roughing_paths"]
