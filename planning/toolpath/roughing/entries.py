"""Entries into the material where a piece of a level starts (Z-level roughing,
:mod:`planning.toolpath.roughing`; mm, degrees, area frame, tool tip). Stage: per level, where
:func:`planning.toolpath.roughing.levels._cut_level` must come down to a piece's first point after a
lift (or the first approach); reads the level's clearing region
(:mod:`planning.toolpath.roughing.regions`), the forbidden map and the remaining-material map
(:mod:`planning.toolpath.roughing.maps`) and writes its moves with the lifts of
:mod:`planning.toolpath.roughing.links`.

**Rule** (``entry``: ``"helix"`` default, ``"ramp"`` or ``"plunge"``). The material under the tool
at the piece's first point q is the highest remaining material whose cell comes closer than Rt to q
(:meth:`_Entries.material`: the remaining-material map, and in rest roughing also the stock top
per raster cell, both upper bounds of what is there, so their smaller maximum is one too; the map
is first lowered along what this level has cut so far). At or below the level (air, or a hole
already cut): the tool comes straight down as the lifts always did (rapid to GAP_MM above the
material, plunge at feed). Otherwise, in this order:

1. *side entry*: q moved by d (h / 2 steps, d <= Rt + 4 h, h the raster cell) back along the
   piece's first segment, or square to it, or ahead along it (the least d of the four, back first
   on a tie) to a point q' where the disc is clear of material: the tool plunges there in air and
   feeds to q at the level; every position of that move (sampled h / 4 apart) lies in a
   cell the forbidden map allows at the level and in the window, and (holder pieces given) that the
   holder does not block (:class:`planning.toolpath.roughing.maps._HolderMap`; the allowance is kept; outside
   the region it may cut at most that short way beyond the region's limits: at the stock box's
   sides, where the clearing lines start with the disc h into the stock, it is the way in from
   outside).
2. ``"helix"``: a helix (Tchanchane & Bey's roughing enters the stock by helix or ramp where
   Popescu's slices start inside it) of the tool centre on a circle of radius ``entry_diameter / 2``
   (default 70 % of the cutter diameter, so no core is left under a cutter that does not cut at its
   centre), turning counter-clockwise seen from +Z (climb milling of the hole's wall with an M3
   spindle), from its start height zs (below) down to the level, every chord descending at
   ``entry_angle_deg`` from the horizontal exactly (HELIX_CHORDS chords per turn, the first one
   shorter). It ends at q (the circle passes through q), or at the circle's point e nearest q and
   the tool then feeds on to q at the level. Near q: centres at the radius from q, then that + 2 h,
   + Rt / 2 and + Rt, each in the piece's first direction and then 30, 60, ..., 180 degrees off it
   (:func:`_near_helix`, in that order; e -> q straight in the region). The cheapest (descent + link length)
   whose every chord lies in the level's clearing region (cells the forbidden map allows, inside
   the region's limits: sampled h / 4 apart like the links; :func:`_helix_in`) is taken, with the
   configured diameter, then half of it. Where that helix must start higher than GAP_MM above the
   previous level (+ rc) (the map keeps the part's height in the cells beside its walls, which it
   never lowers, so a helix there would start above the part's top), centres farther away are
   tried too: region cells within FAR_RADII x Rt of q (:func:`_helix_sites`), cheapest first, the
   tool feeding from e to q along a shortest path in the region (Popescu's graph,
   :meth:`~planning.toolpath.roughing.links._Level.grid_path`). Since the forbidden map only grows
   downwards, a position allowed at the level is allowed above it: the descent is gouge-free.
3. ``"ramp"`` (and the helix's fallback): back and forth along the piece's first straight segment
   (its first ``ramp_length`` mm, at least Rt long, in the region), from zs (the material within Rt
   of the segment) at the entry angle, ending at q (the first leg shorter); where that segment is
   shorter than Rt (a contour's short edges) and the material is read from the stock itself
   (``exact``: the ramp starts over the material that is there, not over the map's bound, which
   keeps the full height beside walls), back and forth along the piece's own path instead
   (its first ``ramp_length`` mm, at least Rt long: the piece lies in the region, and a position
   allowed at the level is allowed above it), so a narrow slot or a pocket no helix fits is still
   entered at the entry angle. With ``"ramp"`` the
   ramp comes first; where it must start higher than GAP_MM above the previous level (+ rc), a
   cheaper helix is taken instead, and where no ramp fits, a helix.
4. else a straight plunge, counted in ``n_plunges_into_material`` -- except when the roughing
   reads the material from the stock itself (a stock view, ``exact``; issue 30: a straight plunge
   into material is a planning error): then the piece is not cut at this level but left, counted
   in ``n_pieces_left``. Such pieces are the region's slivers, a few cells where the tool centre
   fits between the part's allowance and the material's edge, or pockets walled in by the part:
   their material stays over the level for the flutes of the next level's passes beside it, or for
   finishing. Without a stock view the material is only bounded (the map keeps the full height
   beside walls it never saw wholly swept), most such "plunges into material" are into air, and
   leaving them would leave whole passes uncut, so the tool plunges as before. With
   ``entry="plunge"`` the tool plunges straight everywhere.

**Start height** zs of a helix or ramp: GAP_MM above the highest material under it (the helix's
circle grown by Rt, or within Rt of the ramp's segment; :meth:`_Entries.material`), at most the
safe height; the rapid down to it is therefore clear of the map's material. With the stock read
from a stock view (``exact``) the gap is the rapid clearance + ENTRY_GAP_EXTRA_MM instead (the
material is known, and the rapid down stops where the grown tool clears it anyway). There the
part of the descent above the material is not fed at the entry angle (0.65 mm at 3 degrees is
12 mm of feed through air): the helix or ramp is cut where it comes down to ENTRY_FEED_GAP_MM
above the material read under it, and the tool is fed straight down to that point from the
start height, when the stock itself (``clear``: the tool at that point, moved straight up to the
start height, keeps FEED_CLEAR_MM from every ray of the tri-dexel stock) shows the straight feed
meets nothing (``n_fed_down``); otherwise the whole descent stays. The material "read under it" is
the stock itself (``rise``, :meth:`_Entries._sweep_top`): the cutter, narrowed by a raster cell at its
rim, moved straight up from the level over the descent's way (sampled SWEEP_SAMPLE_MM apart); the
maps' bound beside a wall is the part's own height, which put ramps along a slot's walls 9-10 mm
above the material they met (about 150 mm of air each at 3 degrees on the slot case). The rapid down
then stops where the tool grown by the rapid clearance meets the stock, and the feed goes on from
there. Where the straight feed down would still touch the stock (the allowance on a wall beside the
descent's start, which the narrowed cutter does not see), the descent through the air runs at
STEEP_DEG along the entry's own way instead (counted in ``n_fed_down`` too): its flat bottom is in
air down to the material, only its rim may brush the wall, and it is no straight plunge.

**The stock decides, the maps propose (with a stock view).** The maps bound the material from
one ray family, grown by a ray spacing; the stock view reads all three. A piece whose start the
maps put under material is entered straight down when the stock shows the tool there, and the
column above it up to the safe height, clear by FEED_CLEAR_MM (``n_in_air``: no helix or ramp needed); a side entry's
start is moved further out until the stock shows its straight feed down meets nothing (a sliver
of another ray family the maps did not see made the femur-like plan's last straight plunge).

In air (the first case and side entries) the rapid down stops GAP_MM above that material under
the disc rather than above the coarser dilated map the lifts read. With ``"plunge"`` every start is
the former straight plunge, unchanged (the counts still say which went into material). Helix and
ramp moves are feed moves at plunge feed (``USE_PLUNGE``), straight lines, never above the safe
height. They are not added to the level's swept area (only the feed to q at the level is), so the
remaining-material map stays an upper bound. Cost: one disc query per entry (a few hundred cells),
and per candidate helix a check of its chords.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from planning.errors import ParameterError
from planning.toolpath.moves import USE_CUT, USE_PLUNGE, USE_RAPID
from planning.toolpath.roughing.common import _finite
from planning.toolpath.roughing.links import (
    GAP_MM,
    _down_off_wall,
    _Level,
    _lift,
    _link_height,
    _rapid_from,
    _retract,
    _seg_in,
    _Writer,
)
from planning.toolpath.roughing.maps import (
    Z_TOL_MM,
    _disc_top,
    _fine_disc_top,
    _MaterialMap,
)

ENTRY_KINDS = ("helix", "ramp", "plunge")
HELIX_CHORDS = 24       #: straight chords per helix turn
HELIX_DIAMETER = 0.7    #: default helix diameter (tool centre path) / cutter diameter
RAMP_DIAMETERS = 2.0    #: default longest ramp leg / cutter diameter
FAR_RADII = 8.0        #: helices away from the piece's start are sought within this many tool radii of it
FAR_TRIES = 32         #: of those, the cheapest this many are tried
#: With the stock read exactly, a helix or ramp is fed straight down through the air to this far above
#: the material read under it and descends at the entry angle from there (mm)
ENTRY_FEED_GAP_MM = 0.1
#: A straight feed down (a side entry's, or the one above a helix or ramp) keeps this far from the
#: stock itself (mm): the programs' rounding does not turn it into a plunge into material
FEED_CLEAR_MM = 0.02
#: The descent of a helix or ramp is sampled this far apart where the stock itself is asked how high
#: its material under the descent reaches (mm)
SWEEP_SAMPLE_MM = 0.25
#: Where the stock shows the flat bottom of a helix or ramp in air down to just above the material but
#: a straight feed down would shave a wall beside it, the descent through the air runs at this angle
#: from the horizontal along the entry's own way (degrees)
STEEP_DEG = 45.0

#: a helix or ramp that starts more than this above the lowest start its level can expect (mm) is begun
#: at the last vertex of its way whose column is air (:meth:`_Entries._late_start`)
LATE_START_MM = 1.0

_DIRS_DEG = (0.0, 30.0, -30.0, 60.0, -60.0, 90.0, -90.0, 120.0, -120.0, 150.0, -150.0, 180.0)
_DIR_COS = np.array([math.cos(math.radians(a)) for a in _DIRS_DEG])   #: cos / sin of _DIRS_DEG, the
_DIR_SIN = np.array([math.sin(math.radians(a)) for a in _DIRS_DEG])   #: directions of the near centres


@dataclass(frozen=True)
class _EntryCfg:
    """The checked entry settings: ``kind``, ``tan`` the tangent of the descent angle, ``radius``
    the helix radius (tool centre, mm), ``ramp`` the longest ramp leg and ``min_ramp`` the shortest
    (mm)."""

    kind: str
    angle_deg: float
    tan: float
    radius: float
    ramp: float
    min_ramp: float


def _entry_cfg(entry, entry_angle_deg, entry_diameter_mm, ramp_length_mm, Rt) -> _EntryCfg:
    """The entry settings of :func:`planning.toolpath.roughing.levels.roughing_paths`, checked
    (:class:`~planning.errors.ParameterError`): ``entry`` one of ENTRY_KINDS; ``entry_angle_deg`` in
    (0, 45]; ``entry_diameter_mm`` in (0, 4 Rt) (None: HELIX_DIAMETER x 2 Rt); ``ramp_length_mm`` >=
    Rt (None: RAMP_DIAMETERS x 2 Rt)."""
    if entry not in ENTRY_KINDS:
        raise ParameterError(f"entry = {entry!r}: must be one of {', '.join(ENTRY_KINDS)}")
    ang = _finite("entry_angle_deg", entry_angle_deg)
    if not 0 < ang <= 45:
        raise ParameterError(f"entry_angle_deg = {entry_angle_deg}: the descent angle must be in (0, 45] degrees")
    d = HELIX_DIAMETER * 2 * Rt if entry_diameter_mm is None else _finite("entry_diameter_mm", entry_diameter_mm)
    if not 0 < d < 4 * Rt:
        raise ParameterError(f"entry_diameter_mm = {entry_diameter_mm}: the helix diameter must be in (0, {4 * Rt}) mm "
                             f"(less than twice the cutter diameter)")
    L = RAMP_DIAMETERS * 2 * Rt if ramp_length_mm is None else _finite("ramp_length_mm", ramp_length_mm)
    if not L >= Rt:
        raise ParameterError(f"ramp_length_mm = {ramp_length_mm}: must be at least the cutter radius {Rt} mm")
    return _EntryCfg(str(entry), ang, math.tan(math.radians(ang)), 0.5 * d, L, Rt)


# ----------------------------------------------------------------------------------------------
# Kernels (numba)
# ----------------------------------------------------------------------------------------------

@njit(cache=True, nogil=True)
def _material_at(top, cx, cy, hx, hy, X0, Y0, H, fine, use_fine, x0, y0, h, px, py, r):
    """Highest remaining material under the disc of radius r about (px, py): the largest ``top``
    over the coarse cells whose part comes closer than r (as
    :func:`planning.toolpath.roughing.maps._disc_top`), and with ``use_fine`` the smaller of that
    and the largest ``fine`` (the raster's stock top) over the raster cells closer than r."""
    best = _disc_top(top, cx, cy, hx, hy, X0, Y0, H, px, py, r)
    if not use_fine or best == -np.inf:
        return best
    return min(best, _fine_disc_top(fine, x0, y0, h, px, py, r))


@njit(cache=True, nogil=True)
def _seg_material(top, cx, cy, hx, hy, X0, Y0, H, fine, use_fine, x0, y0, h, ax, ay, bx, by, r):
    """Highest remaining material within r of the segment a -> b (:func:`_material_at` at samples
    at most H / 2 apart, with r grown by a quarter of the spacing: every point of the segment is
    within that of a sample)."""
    L = math.hypot(bx - ax, by - ay)
    n = max(1, int(math.ceil(L / (0.5 * H))))
    grow = 0.5 * L / n
    best = -np.inf
    for k in range(n + 1):
        t = k / n
        v = _material_at(top, cx, cy, hx, hy, X0, Y0, H, fine, use_fine, x0, y0, h,
                         ax + (bx - ax) * t, ay + (by - ay) * t, r + grow)
        best = max(best, v)
    return best


@njit(cache=True, nogil=True)
def _side_start(region, G, thr, win, use_win, nx, ny, qx, qy, ux, uy, dmin, dmax, z, Rt, edge,
                top, cx, cy, hx, hy, X0, Y0, H, fine, use_fine, x0, y0, h):
    """The side entry (module docstring): the least d (a multiple of h / 2 above ``dmin``, at most ``dmax``) such
    that at q' = q - d u the disc of radius Rt is clear of material above z and every sample of
    q' -> q (h / 4 apart) lies in a ``region`` cell or in a cell the forbidden map allows
    (``G <= thr``) and, with ``use_win``, in the window (``win``); q' at least ``edge`` inside the
    raster's edge; -1 when none."""
    lim = z + 1e-6
    kmax = int(math.floor(dmax / (0.5 * h)))
    for k in range(int(math.floor(dmin / (0.5 * h))) + 1, kmax + 1):
        d = 0.5 * h * k
        px = qx - d * ux
        py = qy - d * uy
        if not (x0 + edge <= px <= x0 + nx * h - edge and y0 + edge <= py <= y0 + ny * h - edge):
            return -1.0
        if _material_at(top, cx, cy, hx, hy, X0, Y0, H, fine, use_fine, x0, y0, h, px, py, Rt) > lim:
            continue
        n = max(1, int(math.ceil(d / (0.25 * h))))
        ok = True
        for s in range(n + 1):
            t = s / n
            sx = px + (qx - px) * t
            sy = py + (qy - py) * t
            ix = min(max(int(math.floor((sx - x0) / h)), 0), nx - 1)
            iy = min(max(int(math.floor((sy - y0) / h)), 0), ny - 1)
            c = ix * ny + iy
            if region[c]:
                continue
            if G[c] > thr or (use_win and not win[c]):
                ok = False
                break
        if ok:
            return d
    return -1.0


@njit(cache=True, nogil=True)
def _helix_sites(region, nx, ny, qx, qy, dmax, stride, R, z, gap, safe, tan, cap, ntop,
                 top, cx, cy, hx, hy, X0, Y0, H, fine, use_fine, x0, y0, h):
    """Candidate helix centres away from q: the region cells every ``stride`` cells within ``dmax``
    of q whose lower bound of cost (the helix's descent length from GAP above the material within R
    of the centre, plus the straight distance to q; mm) is below ``cap``: rows (x, y, material top,
    cost bound), in the order of the cells (x, then y). Only the ``ntop`` cheapest matter (a
    stable sort by cost then takes them), so not every row is returned: the material is looked up
    cheapest first by the bound that ignores it (the descent from GAP above the level), and the
    look-ups stop once that bound exceeds the ``ntop``-th cost found; every row whose cost is at most
    that is returned (the ``ntop`` cheapest in the stable order are among them)."""
    iq = int(math.floor((qx - x0) / h))
    jq = int(math.floor((qy - y0) / h))
    k = int(math.ceil(dmax / h))
    nc = 0
    for i in range(max(iq - k, 0), min(iq + k, nx - 1) + 1, stride):
        for j in range(max(jq - k, 0), min(jq + k, ny - 1) + 1, stride):
            nc += 1
    cand = np.empty((nc, 4))                  # x, y, distance to q, cost bound without the material
    n = 0
    d0 = (min(z + gap, safe) - z) / tan       # least descent: zs >= min(z + gap, safe)
    for i in range(max(iq - k, 0), min(iq + k, nx - 1) + 1, stride):
        px = x0 + (i + 0.5) * h
        for j in range(max(jq - k, 0), min(jq + k, ny - 1) + 1, stride):
            if not region[i * ny + j]:
                continue
            py = y0 + (j + 0.5) * h
            d = math.hypot(px - qx, py - qy)
            if d > dmax or d >= cap:
                continue
            lb = d0 + max(d - R, 0.0)
            if lb >= cap:
                continue
            cand[n, 0] = px
            cand[n, 1] = py
            cand[n, 2] = d
            cand[n, 3] = lb
            n += 1
    keep = np.zeros(n, np.bool_)
    Ts = np.empty(n)
    costs = np.empty(n)
    best = np.full(max(ntop, 1), np.inf)      # the ntop least costs found, ascending
    for m in np.argsort(cand[:n, 3]):
        if cand[m, 3] > best[-1]:
            break
        px = cand[m, 0]
        py = cand[m, 1]
        d = cand[m, 2]
        T = _material_at(top, cx, cy, hx, hy, X0, Y0, H, fine, use_fine, x0, y0, h, px, py, R)
        zs = min(max(T, z) + gap, safe)
        cost = (zs - z) / tan + max(d - R, 0.0)
        if cost >= cap:
            continue
        keep[m] = True
        Ts[m] = T
        costs[m] = cost
        if cost < best[-1]:
            a = best.shape[0] - 1
            while a > 0 and best[a - 1] > cost:
                best[a] = best[a - 1]
                a -= 1
            best[a] = cost
    out = np.empty((int(keep.sum()), 4))
    o = 0
    for m in range(n):
        if keep[m]:
            out[o, 0] = cand[m, 0]
            out[o, 1] = cand[m, 1]
            out[o, 2] = Ts[m]
            out[o, 3] = costs[m]
            o += 1
    return out


@njit(cache=True, nogil=True)
def _helix_in(flat, x0, y0, h, nx, ny, cx, cy, r, phi_end, L, ex, ey):
    """Whether the helix of :func:`_helix_xyz` (centre (cx, cy), radius r, ending at angle
    ``phi_end`` at (ex, ey), horizontal chordal length L) lies in cells where ``flat`` is True
    (:func:`planning.toolpath.roughing.links._seg_in` per chord), without building it: its first
    (shorter) chord and its last full turn, which every other chord repeats."""
    delta = 2.0 * math.pi / HELIX_CHORDS
    cl = 2.0 * r * math.sin(0.5 * delta)
    nf = int(math.floor(L / cl + 1e-9))
    rem = L - nf * cl
    ax = ex
    ay = ey
    for k in range(min(nf, HELIX_CHORDS)):
        a = phi_end - (k + 1) * delta
        bx = cx + r * math.cos(a)
        by = cy + r * math.sin(a)
        if not _seg_in(flat, x0, y0, h, nx, ny, bx, by, ax, ay):
            return False
        ax = bx
        ay = by
    if rem > 1e-9 * (1.0 + L):
        a0 = phi_end - nf * delta
        a = a0 - 2.0 * math.asin(min(rem / (2.0 * r), 1.0))
        if not _seg_in(flat, x0, y0, h, nx, ny, cx + r * math.cos(a), cy + r * math.sin(a),
                       cx + r * math.cos(a0), cy + r * math.sin(a0)):
            return False
    return True


@njit(cache=True, nogil=True)
def _start_z(T, z, gap, safe):
    """Where a helix or ramp starts (mm): ``gap`` above the material ``T`` (at least the level z), at
    most ``safe`` (:meth:`_Entries._start_height`, with Python's ``max`` / ``min`` on ties)."""
    m = T
    if z > m:  # noqa: PLR1730 (Python's max / min on ties, as the callers had)
        m = z
    m = m + gap
    if safe < m:  # noqa: PLR1730 (Python's max / min on ties, as the callers had)
        m = safe
    return m


@njit(cache=True, nogil=True)
def _helix_end(qx, qy, cx, cy, r):
    """Where the helix about (cx, cy) of radius r ends (mm): at q when q lies on its circle (within
    1e-12 r), else at the circle's point nearest q: (ex, ey, phi the end's angle about the centre,
    whether it ends at q)."""
    dq = math.hypot(qx - cx, qy - cy)
    if dq <= r * (1 + 1e-12):
        return qx, qy, math.atan2(qy - cy, qx - cx), True
    ex = cx + r * (qx - cx) / dq
    ey = cy + r * (qy - cy) / dq
    return ex, ey, math.atan2(ey - cy, ex - cx), False


@njit(cache=True, nogil=True, inline="always")
def _helix_fits(flat, x0, y0, h, nx, ny, qx, qy, px, py, r, zs, z, tan):
    """The helix about (px, py) of radius r from zs down to z towards q: where it ends
    (:func:`_helix_end`), whether every chord lies in the region (:func:`_helix_in`) and its descent
    length (mm). Returns (fits, end x, y, end angle, ends at q, descent length)."""
    ex, ey, phi, atq = _helix_end(qx, qy, px, py, r)
    dz = zs - z
    if 0.0 > dz:  # noqa: PLR1730 (Python's max / min on ties, as the callers had)
        dz = 0.0
    fits = _helix_in(flat, x0, y0, h, nx, ny, px, py, r, phi, dz / tan, ex, ey)
    return fits, ex, ey, phi, atq, (zs - z) / tan


@njit(cache=True, nogil=True)
def _near_helix(flat, nx, ny, qx, qy, ux, uy, r, Rt, z, safe, gap, tan, good, cap, dcos, dsin,
                top, cx, cy, hx, hy, X0, Y0, H, fine, use_fine, x0, y0, h):
    """The cheapest helix of radius r about a centre near q (module docstring, 2.; the centres of
    at distance r, r + 2 h, r + Rt / 2 and r + Rt from q, each in direction k = 0, 1, ... at cos / sin
    ``dcos[k]`` / ``dsin[k]`` off u, in that order):
    every chord in the region (:func:`_helix_in`), the link e -> q (when it does not end at q) in
    sight (:func:`planning.toolpath.roughing.links._seg_in`), its cost (descent length from the
    start height over the material within r + Rt of the centre, plus the link; mm) below ``cap``
    and below the best one so far; the first one starting at most ``good`` + 1e-9 is taken at once.
    Returns (found, centre x, y, end x, y, end angle, start height zs, cost, ends at q, taken at
    once)."""
    found = False
    b_cx = b_cy = b_ex = b_ey = b_phi = b_zs = b_cost = 0.0
    b_atq = False
    for i in range(4):
        if i == 0:
            rho = r
        elif i == 1:
            rho = r + 2.0 * h
        elif i == 2:
            rho = r + 0.5 * Rt
        else:
            rho = r + Rt
        for j in range(dcos.shape[0]):
            ca = dcos[j]
            sa = dsin[j]
            px = qx + rho * (ca * ux - sa * uy)
            py = qy + rho * (sa * ux + ca * uy)
            T = _material_at(top, cx, cy, hx, hy, X0, Y0, H, fine, use_fine, x0, y0, h, px, py, r + Rt)
            zs = _start_z(T, z, gap, safe)
            dq = math.hypot(qx - px, qy - py) - r
            if 0.0 > dq:  # noqa: PLR1730 (Python's max / min on ties, as the callers had)
                dq = 0.0
            lim = cap
            if found and b_cost < lim:
                lim = b_cost
            if (zs - z) / tan + dq >= lim:
                continue
            fits, ex, ey, phi, atq, cost = _helix_fits(flat, x0, y0, h, nx, ny, qx, qy, px, py, r, zs, z, tan)
            if not fits:
                continue
            if not atq:
                if not _seg_in(flat, x0, y0, h, nx, ny, ex, ey, qx, qy):
                    continue
                cost += math.hypot(qx - ex, qy - ey)
            found = True
            b_cx, b_cy, b_ex, b_ey, b_phi, b_zs, b_cost, b_atq = px, py, ex, ey, phi, zs, cost, atq
            if zs <= good + 1e-9:
                return True, b_cx, b_cy, b_ex, b_ey, b_phi, b_zs, b_cost, b_atq, True
    return found, b_cx, b_cy, b_ex, b_ey, b_phi, b_zs, b_cost, b_atq, False


@njit(cache=True, nogil=True)
def _far_helix(flat, nx, ny, x0, y0, h, qx, qy, r, z, safe, gap, tan, bound, sites, order, start):
    """The first of the far helices (rows of :func:`_helix_sites`, tried in ``order`` from position
    ``start``, while their cost bound is below ``bound``) whose chords lie in the region
    (:func:`_helix_in`) and that ends at q or in sight of it with its cost (descent length plus the
    straight link, mm) below ``bound``, or whose end needs a path in the region to q (the caller
    seeks it). Returns (status: 0 none, 1 found, 2 needs a path; position in ``order``, end x, y, end
    angle, start height zs, cost without a path, ends at q)."""
    for m in range(start, order.shape[0]):
        k = order[m]
        if sites[k, 3] >= bound:
            break
        px = sites[k, 0]
        py = sites[k, 1]
        zs = _start_z(sites[k, 2], z, gap, safe)
        fits, ex, ey, phi, atq, cost = _helix_fits(flat, x0, y0, h, nx, ny, qx, qy, px, py, r, zs, z, tan)
        if not fits:
            continue
        if atq:
            if cost < bound:
                return 1, m, ex, ey, phi, zs, cost, atq
            continue
        if _seg_in(flat, x0, y0, h, nx, ny, ex, ey, qx, qy):
            cost += math.hypot(qx - ex, qy - ey)
            if cost < bound:
                return 1, m, ex, ey, phi, zs, cost, atq
            continue
        return 2, m, ex, ey, phi, zs, cost, atq
    return 0, -1, 0.0, 0.0, 0.0, 0.0, 0.0, False


# ----------------------------------------------------------------------------------------------
# Geometry of helices and ramps
# ----------------------------------------------------------------------------------------------

def _helix_xyz(c, r, phi_end, zs, z, tan) -> np.ndarray:
    """The vertices (k, 3) of a counter-clockwise helix about ``c`` of radius ``r`` ending at angle
    ``phi_end`` at height z, starting at zs: HELIX_CHORDS chords per turn, the first shorter, each
    chord descending ``tan`` x its length (so its angle from the horizontal is exactly the entry
    angle)."""
    delta = 2.0 * math.pi / HELIX_CHORDS
    cl = 2.0 * r * math.sin(0.5 * delta)
    L = max(zs - z, 0.0) / tan                           # horizontal (chordal) length
    nf = int(math.floor(L / cl + 1e-9))
    rem = L - nf * cl
    lens = [cl] * nf
    dang = [delta] * nf
    if rem > 1e-9 * (1.0 + L):
        lens.insert(0, rem)
        dang.insert(0, 2.0 * math.asin(min(rem / (2.0 * r), 1.0)))
    if not lens:
        lens, dang = [0.0], [0.0]
    dang = np.array(dang)
    ang = phi_end - dang.sum() + np.concatenate([[0.0], np.cumsum(dang)])
    drop = np.concatenate([np.cumsum(np.array(lens)[::-1])[::-1], [0.0]]) * tan
    out = np.column_stack([c[0] + r * np.cos(ang), c[1] + r * np.sin(ang), z + drop])
    out[-1, :2] = c + r * np.array([math.cos(phi_end), math.sin(phi_end)])
    return out


def _path_ramp_xyz(path, zs, z, tan) -> np.ndarray:
    """The vertices (k, 3) of a ramp back and forth along the polyline ``path`` (m, 2; ``path[0]`` = q)
    ending at q at height z, from zs: the tool runs along the path and back (legs of the path's
    length, the first one shorter), descending ``tan`` x the distance it travels."""
    seg = np.hypot(*(np.diff(path, axis=0).T))
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    Lr = float(cum[-1])
    D = max(zs - z, 0.0) / tan                       # the horizontal distance of the whole descent
    n = max(1, int(math.ceil(D / Lr - 1e-9)))
    first = D - (n - 1) * Lr
    # walked backwards from q: leg 0 (the last one) leaves q along the path, leg 1 comes back, ...
    pts = [np.asarray(path[0], dtype=np.float64)]
    s_cur = 0.0
    for k in range(n):
        length = Lr if k < n - 1 else first
        out = k % 2 == 0
        s_next = s_cur + length if out else s_cur - length
        lo, hi = min(s_cur, s_next), max(s_cur, s_next)
        inner = cum[(cum > lo + 1e-12) & (cum < hi - 1e-12)]
        for sv in [*(inner if out else inner[::-1]), s_next]:
            pts.append(np.array([np.interp(sv, cum, path[:, 0]), np.interp(sv, cum, path[:, 1])]))
        s_cur = s_next
    v = np.array(pts[::-1], dtype=np.float64)        # from the start, high, to q
    lens = np.hypot(*(np.diff(v, axis=0).T))
    drop = np.concatenate([np.cumsum(lens[::-1])[::-1], [0.0]]) * tan
    return np.column_stack([v, z + drop])


def _path_head(xy, length: float) -> np.ndarray:
    """The first ``length`` mm (along it) of the polyline ``xy`` (m, 2), as a polyline."""
    seg = np.hypot(*(np.diff(xy, axis=0).T))
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    if cum[-1] <= length:
        return np.asarray(xy, dtype=np.float64)
    k = int(np.searchsorted(cum, length))
    t = (length - cum[k - 1]) / max(seg[k - 1], 1e-12)
    end = xy[k - 1] + t * (xy[k] - xy[k - 1])
    return np.vstack([xy[:k], end[None, :]]).astype(np.float64)


def _ramp_xyz(q, p, zs, z, tan) -> np.ndarray:
    """The vertices (k, 3) of a ramp back and forth between q and p ending at q at height z, from
    zs: every leg descends ``tan`` x its length, the first one shorter."""
    Lr = float(np.hypot(*(p - q)))
    L = max(zs - z, 0.0) / tan
    n = max(1, int(math.ceil(L / Lr - 1e-9)))
    first = L - (n - 1) * Lr
    ends = [q if (n - k) % 2 == 0 else p for k in range(n + 1)]     # ends[n] = q
    v = np.array(ends, dtype=np.float64)
    v[0] = v[1] + (v[0] - v[1]) * (first / Lr)
    lens = np.hypot(*(np.diff(v, axis=0).T))
    drop = np.concatenate([np.cumsum(lens[::-1])[::-1], [0.0]]) * tan
    return np.column_stack([v, z + drop])


def _steep_head(xyz, low, zs, zf):
    """The descent from ``zs`` to ``low[0]`` (at height ``zf``) at STEEP_DEG from the horizontal along
    the way the descent ``xyz`` (k,3) came to ``low[0]``, walked back from it (k', 3), its first
    point at ``zs``; None when that way is too short."""
    k = int(np.argmax(xyz[:, 2] <= zf)) if (xyz[:, 2] <= zf).any() else xyz.shape[0] - 1
    back = np.vstack([low[:1, :2], xyz[k - 1::-1, :2]]) if k > 0 else low[:1, :2]
    need = (zs - zf) / math.tan(math.radians(STEEP_DEG))
    d = np.hypot(*np.diff(back, axis=0).T)
    cum = np.concatenate([[0.0], np.cumsum(d)])
    if cum[-1] < need - 1e-9:
        return None
    m = int(np.searchsorted(cum, need))                 # cum[m - 1] < need <= cum[m]
    t = (need - cum[m - 1]) / max(d[m - 1], 1e-12)
    pts = np.vstack([back[:m], back[m - 1] + t * (back[m] - back[m - 1])])[::-1]
    s = np.concatenate([cum[:m], [need]])[::-1]       # the way left to low[0]
    return np.column_stack([pts, zf + s / need * (zs - zf)])


def _from_height(xyz, zf) -> np.ndarray:
    """The descent ``xyz`` (k, 3; heights non-increasing) from where it comes down to ``zf``: the
    point at that height (interpolated on its segment), then the vertices below."""
    k = int(np.argmax(xyz[:, 2] <= zf)) if (xyz[:, 2] <= zf).any() else xyz.shape[0] - 1
    if k == 0:
        return xyz
    a, b = xyz[k - 1], xyz[k]
    t = (a[2] - zf) / max(a[2] - b[2], 1e-12)
    return np.vstack([a + min(max(t, 0.0), 1.0) * (b - a), xyz[k:]])


# ----------------------------------------------------------------------------------------------
# The entries of a roughing
# ----------------------------------------------------------------------------------------------

@dataclass
class _Plan:
    """A helix or ramp entry found: ``xyz`` its vertices (the first is where the approach ends),
    ``zs`` its start height, ``link`` (k, 2) or None: the feed path at the level from its end to
    the piece's first point, ``cost`` its length (horizontal, mm: the descent and the link)."""

    kind: str
    xyz: np.ndarray
    zs: float
    link: np.ndarray | None
    cost: float


class _Entries:
    """Chooses and writes the entries (module docstring) and counts them: ``n_helix``,
    ``n_ramps``, ``n_side`` (side entries), ``n_plunges`` (straight plunges into material).
    ``fine``: the stock top per raster cell (rest roughing) or None; ``G``: the forbidden map;
    ``edge``: side entries start at least this far inside the raster's edge (mm: the tool radius and
    a cell where material may lie beyond the stock box, one cell otherwise); ``win`` (nx, ny) or
    None: the window's cells, which side entries keep to (the tool centre stays in the window,
    beyond the stock box's reach or not; with the holder the caller sets ``win`` (flat) and
    ``use_win`` per level to the cells the holder leaves free). Per level the caller
    sets ``thr`` (the forbidden map's threshold) and ``z_prev`` (the level above, or the stock
    top)."""

    def __init__(self, cfg: _EntryCfg, mat: _MaterialMap, fine, G, Rt, rc, edge, win=None):
        self.cfg, self.mat, self.Rt, self.rc, self.edge = cfg, mat, Rt, rc, float(edge)
        self.use_win = win is not None
        self.win = np.ascontiguousarray(win if win is not None else np.ones((1, 1), bool)).ravel()
        self.use_fine = fine is not None
        self.fine = np.ascontiguousarray(fine if fine is not None else np.full((1, 1), np.inf))
        self.G = np.ascontiguousarray(G).ravel()
        self.thr = math.inf
        self.z_prev = math.inf
        self.n_helix = self.n_ramps = self.n_side = self.n_plunges = self.n_left = 0
        #: the material is read from the stock itself (a stock view), not bounded: a piece that only a
        #: straight plunge would enter is left rather than plunged into
        self.exact = False
        #: how far above the material under it a helix or ramp starts (mm): GAP_MM, or with the stock
        #: read exactly, just above the rapid clearance (every 0.1 mm of it costs 0.1 / tan(entry angle)
        #: of feed in air: 1.9 mm at 3 degrees)
        self.gap = GAP_MM
        self.left_mm = 0.0
        #: (nx, ny) the stock's top as read (not grown), where helices and ramps start; None: ``fine``
        self.fine_start = None
        #: ``clear(x, y, z, top)`` -> bool: the tool at (x, y, z), moved straight up to ``top``, meets no
        #: material of the stock itself (set with a stock view); None: the maps alone decide
        self.clear = None
        #: ``rise(xy, z, top)`` -> the highest frame height at which the cutter moved straight up from
        #: the level z to ``top`` over the points ``xy`` (k,2) meets the stock itself (-inf: none); set with
        #: a stock view; None: the maps alone say where a helix or ramp begins to cut
        self.rise = None
        #: helices and ramps begun by a straight feed down through the air (``clear`` said it was)
        self.n_fed_down = 0
        #: pieces entered by a feed straight down that the stock itself shows to be in air
        self.n_in_air = 0
        #: helices and ramps begun higher because the stock stood in the column above their start
        #: (:meth:`_raised`)
        self.n_raised = 0
        #: helices and ramps begun at a later vertex of their way (:meth:`_late_start`)
        self.n_started_late = 0

    def _margs(self, lv: _Level, start: bool = False):
        """The material arguments of the kernels: the map and the tops; ``start``: the tops a helix or
        ramp starts over (``fine_start``, the stock as read, when there is one), else the tops that
        decide whether there is material under the tool at all (``fine``, an upper bound)."""
        m = self.mat
        fine = self.fine_start if (start and self.fine_start is not None) else self.fine
        return (m.top, m.cx, m.cy, m.hx, m.hy, m.x0, m.y0, m.H, fine, self.use_fine, lv.x0, lv.y0, lv.h)

    def material(self, lv: _Level, xy, r) -> float:
        """Highest remaining material under the disc of radius r (mm) about xy (module docstring)."""
        return float(_material_at(*self._margs(lv), float(xy[0]), float(xy[1]), float(r)))

    def enter(self, w: _Writer, lv: _Level, cur, xy, cell, z, safe) -> list[np.ndarray]:
        """Come down from ``cur`` (None: the first approach from the safe height) to the first point
        of the piece ``xy`` (k, 2; ``cell`` its region cell) at level z; returns the polylines cut at
        the level on the way (for the remaining-material map), or None when the piece cannot be
        entered but by a straight plunge into material (helix and ramp modes): nothing is written, the
        piece is left (counted in ``n_left``)."""
        q = np.asarray(xy[0], dtype=np.float64)
        top_q = self.material(lv, q, self.Rt)
        if not top_q > z + Z_TOL_MM:
            _lift(w, lv, cur, q, z, safe, None if self.cfg.kind == "plunge" else top_q)
            return []
        if self.clear is not None and self.clear(q[0], q[1], z, safe):
            # the maps bound the material (grown by a ray spacing); the stock itself says the tool comes
            # down at q through air (the whole column up to the safe height: wherever the lift's rapid
            # stops and its feed starts): no helix or ramp needed, and the rapid comes down to the gap
            # above the level (no material above it there; the lift keeps the rapid clearance on the
            # stock itself), not above the maps' bound
            _lift(w, lv, cur, q, z, safe, z)
            self.n_in_air += 1
            return []
        if self.cfg.kind != "plunge":
            u, seg = _first_dir(xy)
            if u is not None:
                best_d, q2 = math.inf, None
                for v in (u, np.array([-u[1], u[0]]), np.array([u[1], -u[0]]), -u):     # back, aside, ahead
                    d = 0.0
                    while True:
                        d = float(_side_start(lv.flat, self.G, self.thr, self.win, self.use_win, lv.nx, lv.ny,
                                              float(q[0]), float(q[1]), float(v[0]), float(v[1]), d,
                                              min(best_d - 0.25 * lv.h, self.Rt + 4.0 * lv.h), float(z), self.Rt,
                                              self.edge, *self._margs(lv)))
                        # the maps bound the material along one ray family; the stock itself (``clear``)
                        # decides whether the feed down at the start would cut a sliver the maps miss
                        if d <= 0 or self.clear is None or self.clear(*(q - d * v), z, safe):
                            break
                    if d > 0:
                        best_d, q2 = d, q - d * v
                if q2 is not None:
                    # on the stock the column at q2 is air down to the level (``clear``): the rapid comes
                    # down to the gap above it there; on the maps alone, above their material
                    _lift(w, lv, cur, q2, z, safe, z if self.clear is not None else self.material(lv, q2, self.Rt))
                    w.add([q[0], q[1], z], USE_CUT)
                    self.n_side += 1
                    return [np.array([q2, q])]
            plan = None
            if self.cfg.kind == "ramp":
                plan = self._ramp(lv, q, u, seg, z, safe, xy)
                if plan is not None and plan.zs > self._good(z) + 1e-9:
                    hp = self._helix(lv, q, int(cell), u, z, safe, plan.cost)
                    plan = hp if hp is not None else plan
                if plan is None:
                    plan = self._helix(lv, q, int(cell), u, z, safe, math.inf)
            else:
                plan = self._helix(lv, q, int(cell), u, z, safe, math.inf)
                if plan is None:
                    plan = self._ramp(lv, q, u, seg, z, safe, xy)
            if plan is not None:
                return self._write(w, lv, cur, plan, q, z, safe)
        if self.cfg.kind != "plunge" and self.exact:  # no way in but a straight plunge: the piece is left
            self.n_left += 1
            return None
        self.n_plunges += 1
        _lift(w, lv, cur, q, z, safe)
        return []

    def _good(self, z) -> float:
        """The lowest start a helix or ramp can expect at level z: GAP_MM above the previous level
        (+ the corner radius), where the previous level's cut left the map."""
        return max(self.z_prev + self.rc, z) + self.gap

    def _start_height(self, T, z, safe) -> float:
        """Where a helix or ramp starts: GAP_MM above the material under it (``T``), at most the safe
        height."""
        return min(max(T, z) + self.gap, safe)

    def _write(self, w, lv, cur, plan: _Plan, q, z, safe):
        xyz = plan.xyz
        zs = plan.zs
        if self.clear is not None:
            # fed straight down through the air to just above the material read under the entry, the
            # helix or ramp from there: 0.55 mm fed down instead of 11 mm of descent at 3 degrees; only
            # where the stock itself says that the straight feed meets nothing
            zf = max(plan.zs - self.gap, z) + ENTRY_FEED_GAP_MM
            if self.rise is not None and xyz[0, 2] > z:
                # the maps' material under the entry is a bound (beside a wall: the part's own height);
                # the stock itself says where the descent's sweep first meets material
                zf = min(zf, max(self._sweep_top(xyz, z, plan.zs), z) + ENTRY_FEED_GAP_MM)
            if zf < plan.zs - 1e-6 and xyz[0, 2] > zf:
                low = _from_height(xyz, zf)
                steep = None
                if not self.clear(low[0, 0], low[0, 1], zf, plan.zs) and self.rise is not None:
                    # a straight feed would shave the allowance on a wall beside it (a plunge, as the
                    # verification counts them); down the entry's own way at STEEP_DEG instead: its flat
                    # bottom is in air (``rise``) down to zf, only its rim may touch the wall
                    steep = _steep_head(xyz, low, plan.zs, zf)
                if steep is not None:
                    xyz = np.vstack([steep, low[1:]])
                    self.n_fed_down += 1
                elif self.clear(low[0, 0], low[0, 1], zf, plan.zs):
                    if w.column_clear is not None:
                        # the rapid down stops where the tool grown by the rapid clearance meets the
                        # stock (:func:`_approach`), the feed goes on from there
                        xyz, zs = low, float(low[0, 2])
                    else:
                        xyz = np.vstack([[low[0, 0], low[0, 1], plan.zs], low])
                    self.n_fed_down += 1
        if (w.column_clear_many is not None and xyz.shape[0] > 2 and abs(float(xyz[0, 2]) - zs) < 1e-9
                and zs > self._good(z) + LATE_START_MM):
            xyz, zs = self._late_start(w, xyz, zs, safe)
        if self.clear is not None and not self.clear(xyz[0, 0], xyz[0, 1], zs, safe):
            xyz, zs = self._raised(w, xyz, zs, safe)
        _approach(w, lv, cur, xyz[0, :2], zs, z, safe)
        w.add(xyz[1:], USE_PLUNGE)
        if plan.kind == "helix":
            self.n_helix += 1
        else:
            self.n_ramps += 1
        if plan.link is None:
            return []
        w.add(np.column_stack([plan.link[1:], np.full(plan.link.shape[0] - 1, z)]), USE_CUT)
        return [plan.link]

    def _late_start(self, w, xyz, zs, safe):
        """The descent ``xyz`` (k,3, its first point at ``zs``) begun at its last vertex s (0 < s < k - 1)
        over which the tool grown by the rapid clearance is clear of the stock and the obstacles all the
        way up to ``safe`` from the descent's own height there (:attr:`_Writer.column_clear_many`, one
        batch; the exact swept test ``clear`` confirms it): the rapid comes down to that vertex and the
        descent goes on at the entry angle from there. Asked only of descents that start more than
        LATE_START_MM above the lowest start the level can expect (:meth:`_good`): the others have little
        air to drop, and the batch over the whole way is not cheap. The rest of the descent is unchanged
        (its heights are the entry angle's from the level back), so it cuts what it cut; what is
        dropped ran through the air. A descent whose start the material chose high (a sliver of stock at the top of
        its way, the maps' bound beside a wall) otherwise ran back and forth through the air at the
        entry angle (on the half sphere's tilted set-up, under the block's lower edge). Returns (xyz', zs'); unchanged when no inner vertex qualifies."""
        inner = np.ascontiguousarray(xyz[1:-1], dtype=np.float64)
        zc = np.asarray(w.column_clear_many(inner, safe), dtype=np.float64)
        ok = np.flatnonzero(zc <= inner[:, 2] + 1e-9)
        if ok.size == 0:
            return xyz, zs
        s = int(ok[-1]) + 1
        if self.clear is not None and not self.clear(xyz[s, 0], xyz[s, 1], float(xyz[s, 2]), safe):
            return xyz, zs
        self.n_started_late += 1
        return xyz[s:], float(xyz[s, 2])

    def _raised(self, w, xyz, zs, safe):
        """The descent ``xyz`` (k,3, its first point at ``zs``) begun higher where the stock itself (a
        sliver the maps and the line reading miss, a wall's allowance at the rim) stands in the column
        above its start: the rapid down would stop above ``zs`` and the straight feed on to it would cut
        (a straight plunge, as the verification counts them). Returns (xyz', zs'): a ramp back and forth
        along the descent's own way (:func:`_path_ramp_xyz`; it lies in the region, and a position allowed
        lower is allowed higher) at the entry angle from zs', the lowest height from which the tool grown
        by the rapid clearance clears the stock up to ``safe`` over every point of that way (sampled
        SWEEP_SAMPLE_MM apart), down to the start; unchanged when nothing can be asked or the way is a point."""
        if w.column_clear_many is None:
            return xyz, zs
        xy = np.asarray(xyz[:, :2], dtype=np.float64)
        keep = np.concatenate([[True], np.hypot(*np.diff(xy, axis=0).T) > 1e-9])
        xy = xy[keep]
        if xy.shape[0] < 2:
            return xyz, zs
        d = np.hypot(*np.diff(xy, axis=0).T)
        pts = [xy[:1]]
        for k in range(d.size):
            n = int(math.ceil(d[k] / SWEEP_SAMPLE_MM))
            t = np.arange(1, n + 1)[:, None] / n
            pts.append(xy[k] + t * (xy[k + 1] - xy[k]))
        xs = np.concatenate(pts)
        zc = float(np.max(w.column_clear_many(np.column_stack([xs, np.full(xs.shape[0], float(zs))]), safe)))
        zc = min(zc, safe)
        if not zc > zs + 1e-6:
            return xyz, zs
        head = _path_ramp_xyz(xy, zc, float(zs), self.cfg.tan)
        self.n_raised += 1
        return np.vstack([head, xyz[1:]]), float(head[0, 2])

    def _sweep_top(self, xyz, z, top) -> float:
        """The highest material the descent ``xyz`` (k,3) may meet: the stock itself under the cutter
        moved straight up from the level ``z`` to ``top`` over its points, the segments sampled at most
        SWEEP_SAMPLE_MM apart (between two samples the tool discs leave a lens no deeper than
        SWEEP_SAMPLE_MM^2 / (8 Rt) uncovered: 0.003 mm for Rt = 2 mm), plus that lens; -inf when none."""
        xy = np.asarray(xyz[:, :2], dtype=np.float64)
        d = np.hypot(*np.diff(xy, axis=0).T)
        pts = [xy[:1]]
        for k in range(d.size):
            n = int(math.ceil(d[k] / SWEEP_SAMPLE_MM))
            if n >= 1:
                t = np.arange(1, n + 1)[:, None] / n
                pts.append(xy[k] + t * (xy[k + 1] - xy[k]))
        t_top = self.rise(np.concatenate(pts), z, top)
        return t_top + SWEEP_SAMPLE_MM ** 2 / (8.0 * self.Rt) if math.isfinite(t_top) else -math.inf

    def _helix_at(self, c, r, e, phi, zs, z, cost, link) -> _Plan:
        """The helix plan about c (mm) of radius r ending at e (angle ``phi``) at level z from zs."""
        hx = _helix_xyz(c, r, phi, zs, z, self.cfg.tan)
        hx[-1, :2] = e
        return _Plan("helix", hx, zs, link, cost)

    def _helix(self, lv, q, qcell, u, z, safe, cap):
        """The cheapest helix found (module docstring, 2.), no dearer than ``cap``; None when none
        fits. The candidates are tried by :func:`_near_helix` (the centres near q) and
        :func:`_far_helix` (those of :func:`_helix_sites`); only the paths in the region for far
        helices out of sight of q are sought here."""
        cfg = self.cfg
        u = np.array([1.0, 0.0]) if u is None else u
        good = self._good(z)
        qx, qy = float(q[0]), float(q[1])
        best = None
        for r in (cfg.radius, 0.5 * cfg.radius):
            found, cx, cy, ex, ey, phi, zs, cost, atq, now = _near_helix(
                lv.flat, lv.nx, lv.ny, qx, qy, float(u[0]), float(u[1]), float(r), float(self.Rt), float(z),
                float(safe), self.gap, cfg.tan, float(good), float(cap), _DIR_COS, _DIR_SIN,
                *self._margs(lv, start=True))
            if found:
                e = q if atq else np.array([ex, ey])
                best = self._helix_at(np.array([cx, cy]), r, e, phi, zs, z, cost, None if atq else np.array([e, q]))
                if now:
                    return best
                break
        # farther: a helix where the map is lower (away from the part's walls), linked to q at the level
        for r in (cfg.radius, 0.5 * cfg.radius):
            lim = min(cap, math.inf if best is None else best.cost)
            sites = _helix_sites(lv.flat, lv.nx, lv.ny, qx, qy, FAR_RADII * self.Rt,
                                 max(1, int(round(0.5 * r / lv.h))), float(r + self.Rt), float(z), self.gap,
                                 float(safe), cfg.tan, float(lim), FAR_TRIES, *self._margs(lv, start=True))
            if sites.shape[0] == 0:
                continue
            order = np.ascontiguousarray(np.argsort(sites[:, 3], kind="stable")[:FAR_TRIES])
            bound = min(lim, math.inf if best is None else best.cost)
            m = 0
            while True:
                st, m, ex, ey, phi, zs, cost, atq = _far_helix(lv.flat, lv.nx, lv.ny, lv.x0, lv.y0, lv.h, qx, qy,
                                                               float(r), float(z), float(safe), self.gap, cfg.tan,
                                                               float(bound), sites, order, m)
                if st == 0:
                    break
                e = q if atq else np.array([ex, ey])
                link = None if atq else np.array([e, q])
                if st == 2:                    # out of sight of q: a shortest path in the region
                    ce = _region_cell(lv, e)
                    link = None if ce < 0 else lv.grid_path(e, ce, q, qcell, bound - cost)
                    if link is None:
                        m += 1
                        continue
                    cost = cost + float(np.hypot(*np.diff(link, axis=0).T).sum())
                    if not cost < bound:
                        m += 1
                        continue
                k = order[m]
                best = self._helix_at(sites[k, :2].copy(), r, e, phi, zs, z, cost, link)
                break
            if best is not None:
                break
        return best

    def _ramp(self, lv, q, u, seg, z, safe, xy=None):
        """A ramp along the first segment ending at q (module docstring, 3.), or, where that is
        shorter than the shortest ramp and ``xy`` (the piece's polyline) is given, along the piece's
        own path (its first ``ramp_length`` mm: the piece lies in the region, so the path is allowed
        at any height above the level); None when neither fits."""
        cfg = self.cfg
        if u is not None and seg is not None and min(seg, cfg.ramp) >= cfg.min_ramp:
            p = q + min(seg, cfg.ramp) * u
            if lv.visible(q, p):
                T = float(_seg_material(*self._margs(lv, start=True), float(q[0]), float(q[1]), float(p[0]),
                                        float(p[1]), self.Rt))
                zs = self._start_height(T, z, safe)
                return _Plan("ramp", _ramp_xyz(q, p, zs, z, cfg.tan), zs, None, (zs - z) / cfg.tan)
        if xy is None or xy.shape[0] < 3 or not self.exact:
            return None
        path = _path_head(np.asarray(xy, dtype=np.float64), cfg.ramp)
        if float(np.hypot(*(np.diff(path, axis=0).T)).sum()) < cfg.min_ramp:
            return None
        T = max(float(_seg_material(*self._margs(lv, start=True), float(a[0]), float(a[1]), float(b[0]), float(b[1]),
                                    self.Rt))
                for a, b in zip(path[:-1], path[1:]))
        zs = self._start_height(T, z, safe)
        return _Plan("ramp", _path_ramp_xyz(path, zs, z, cfg.tan), zs, None, (zs - z) / cfg.tan)


def _region_cell(lv: _Level, xy) -> int:
    """A region cell holding xy (a point within 1e-9 cell of an edge may take the cell across), or
    -1."""
    for ex in (0.0, -1e-9, 1e-9):
        for ey in (0.0, -1e-9, 1e-9):
            ix = int(math.floor((xy[0] - lv.x0) / lv.h + ex))
            iy = int(math.floor((xy[1] - lv.y0) / lv.h + ey))
            if 0 <= ix < lv.nx and 0 <= iy < lv.ny and lv.flat[ix * lv.ny + iy]:
                return ix * lv.ny + iy
    return -1


def _first_dir(xy):
    """The unit direction and length of the piece's first segment of non-zero length (None, None
    when there is none)."""
    for k in range(1, xy.shape[0]):
        d = np.asarray(xy[k] - xy[0], dtype=np.float64)
        L = float(np.hypot(*d))
        if L > 1e-9:
            return d / L, L
    return None, None


def _approach(w: _Writer, lv: _Level, cur, p, zs, z, safe):
    """Lift from ``cur`` (None: the first approach, from the safe height), rapid over to p and down
    to zs, the start of a helix or ramp: GAP_MM above the map's material under the whole helix or
    ramp, which holds the tool disc at p, so the rapid stays clear of it. The link height
    (:func:`planning.toolpath.roughing.links._link_height`) is raised to zs, at most the safe
    height."""
    if cur is None:
        zl = safe
        w.add([p[0], p[1], safe], USE_RAPID)
    else:
        zl = min(safe, max(_link_height(lv, np.array(cur[:2]), p, cur[2], z, safe), zs))
        if w.rapid_clear is not None:
            zl = w.rapid_clear(np.array(cur[:2]), p, zl, safe)
        a2 = _retract(w, cur, zl, lv)
        zl = _rapid_from(w, np.array(cur[:2]), a2, p, zl, safe)
    # where the rapid down stops: the grown tool meets the stock beside (the rest is fed)
    zr = zs if (w.column_clear is None or not zl > zs) else min(zl, w.column_clear(p[0], p[1], zs, zl))
    if cur is not None:
        # beside a wall (or under a tilted block's edge) come down off it and feed in at 45 degrees
        if w.column_clear is not None and _down_off_wall(w, lv, p, zs, zr, zl, safe):
            return
        w.add([p[0], p[1], zl], USE_RAPID)
    if zl > zs:
        if zr > zs:                   # the rapid stops where the grown tool would meet material; fed on
            if zl > zr:
                w.add([p[0], p[1], zr], USE_RAPID)
            w.add([p[0], p[1], zs], USE_PLUNGE)
        else:
            w.add([p[0], p[1], zs], USE_RAPID)
