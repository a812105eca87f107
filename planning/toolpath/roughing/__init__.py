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
wider than the cutter). A cloud point's *clearance* is its distance to that solid (0 or below:
inside the tool).

**Holder** (``holder_pieces``, optional: the caller passes
:attr:`planning.simulate.motion.ToolShape.pieces` of the roughing tool, cylinders ``(z0, z1, r)``
above the tip). At each level a tool-centre cell is *blocked* where a piece would meet the cloud
(within r + allowance, above z + z0 - allowance) or the remaining material (the material map:
the box or the given stock as lowered so far, within r, above z + z0 - HOLDER_GAP_MM); blocked
cells are not cut, linked through, entered or descended to, and the lifts' rapids rise so that
every piece clears the material (:class:`~planning.toolpath.roughing.maps._HolderMap`). Where a
region is blocked the roughing stops going deeper there (the tool cannot reach; the material is
left for finishing or other set-ups); ``RoughingPath.holder_blocked_cells`` counts them and
``deepest_cut_mm`` says how deep it went. Without pieces (default) nothing changes.

**Stock.** Either the box or the material that is there now. *Box* (default): the cloud's
bounding box grown by ``stock_margin_mm`` on the four sides and on the top: the stock top is the
highest cloud z + ``stock_margin_mm`` (so ``stock_margin_mm`` in a set-up frame); material removed
by earlier set-ups is not modelled, so lines may cut air. *Rest roughing* (``stock_points_mm``,
``stock_spacing_mm``): the caller carries a simulated (tri-dexel) stock through the set-ups and
passes points sampling the boundary of what is left, in the area frame; their highest point per
raster cell, taken as a maximum over a disc of the spacing + one cell (hole-free, never too low),
is the stock top per cell (-inf where there is none). Each level then cuts only tool-centre cells
within Rt + one cell of stock above the level (no air over empty cells), the levels start one step
below the highest top the window's tool centres reach, and the remaining-material map (lifts,
links, rapids) starts from that top instead of the box's
(:mod:`~planning.toolpath.roughing.levels`). Either way nothing comes within ``stock_allowance_mm``
of the cloud (the forbidden map is the same). With a window (``window_xy_mm``,
``window_reach_mm``) the tool centre cuts only within the given reach of the window's points (the
area being machined); the stock outside it is left to the other set-ups.

**Levels.** Tip heights from the stock top down every ``step_down_mm``, the last exactly at the
floor (``floor_z_mm``, default the lowest cloud z + allowance; the caller passes the area's
lowest point + allowance); a level within 1e-6 mm above the floor is dropped. Rest roughing with no
stock above the floor gives no level and an empty path.

**Entries** (:mod:`~planning.toolpath.roughing.entries`, ``entry``): where a piece of a level starts
after a lift, the tool comes straight down only into air or a hole already cut (by the
remaining-material map); into material it comes down in air beside it and feeds in, or descends by
a helix (default) or a ramp at ``entry_angle_deg`` inside the level's allowed cells; a straight
plunge into material is left only where none fits, and counted (``entry="plunge"``: straight
plunges everywhere, as before).

**Modules**, one per concern (the entry first, in the order the stages run):

- :mod:`~planning.toolpath.roughing.levels`: the entry :func:`roughing_paths` (arguments, stock,
  levels) and its result :class:`RoughingPath`; cuts the levels from the top down.
- :mod:`~planning.toolpath.roughing.maps`: the planning raster, the forbidden map (Popescu's binary
  map per level, made conservative) and the remaining-material map.
- :mod:`~planning.toolpath.roughing.regions`: a level's clearing region, its connected components
  and its boundary loops (marching squares).
- :mod:`~planning.toolpath.roughing.clearing`: the clearing lines clipped to the region and the
  offset contours (Tchanchane & Bey); on the stock view the contours' staircase steps away from the
  walls are replaced by chords where the exact clearance keeps the allowance.
- :mod:`~planning.toolpath.roughing.ordering`: the order of a level's pieces (components,
  boustrophedon zones, contours).
- :mod:`~planning.toolpath.roughing.links`: feed links at the level (Popescu: shortest paths on a
  graph) and lifts over the remaining material.
- :mod:`~planning.toolpath.roughing.entries`: how a piece is entered after a lift (straight, from
  the side, helix, ramp).
- :mod:`~planning.toolpath.roughing.clearance`: the verification, :func:`min_tool_clearance`.
- :mod:`~planning.toolpath.roughing.common`: argument checks and small kernels they share.

**Cost.** Per set-up: one pass over the cloud for the cells' highest points and one disc maximum
per sub-band; per level: one pass over the raster (the region and its runs), the boundary from
the runs (only the 2 x 2 blocks that can be mixed), the links' grid searches (in a window, scratch
arrays reused), the coarse material map; per entry into material a few disc queries of the map and
the chords of the candidate helices (numba); then one counting sort of the cloud for the
verification. Rest roughing adds one pass over the stock points and two disc maxima per set-up.
On the stock view, one more counting sort of the cloud per set-up and per level up to HUG_ROUNDS
clearance calls for the contours' chords. The holder adds one disc maximum per piece per set-up (the cloud), and per level two passes over
the raster (the candidates' box, the mask in it) and, where the map has changed, one disc maximum
per piece of the material map over blocks of cells (about HOLDER_BLOCKS blocks per radius). The
default raster of the femur-like case is about 1300 x 650 cells.

Simplified: no trochoidal or adaptive clearing; helices and ramps are straight chords (24 per
helix turn), not arcs; no fixture collisions, the holder only when its pieces are given (each
piece taken as reaching up without end, at most HOLDER_PIECES of them, merged conservatively, its
blocked cells grown by up to about 3 raster cells + the blocks' diagonal: about 1.9 mm for a
12.5 mm collet nut, 2.7 mm for a 25 mm flange with the default Ø10 cutter); the material of earlier
set-ups is known only through the stock the caller passes (its top per cell: an overhang of stock over air counts as
solid down to the floor), and the box otherwise; the remaining-material map is conservative (a cell
is lowered only when wholly swept), so lifts and rapid descents may stop higher than needed, and
its stock top is grown by the sampling spacing + one cell, so up to that much air is cut beside the
stock's edges; no rest machining of the corners a cutter of radius Rt cannot enter.
"""

from planning.toolpath.roughing.clearance import ToolClearance, min_tool_clearance
from planning.toolpath.roughing.entries import ENTRY_KINDS
from planning.toolpath.roughing.levels import REMOVED_NOTE, REST_NOTE, RoughingPath, roughing_paths
from planning.toolpath.roughing.links import GAP_MM
from planning.toolpath.roughing.maps import HOLDER_GAP_MM

__all__ = ["ENTRY_KINDS", "GAP_MM", "HOLDER_GAP_MM", "REMOVED_NOTE", "REST_NOTE", "RoughingPath", "ToolClearance",
           "min_tool_clearance", "roughing_paths"]
