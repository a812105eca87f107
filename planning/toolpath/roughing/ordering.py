"""The order in which one level's pieces are cut (Z-level roughing,
:mod:`planning.toolpath.roughing`; mm, area frame). Stage: per level, after the pieces
(:mod:`planning.toolpath.roughing.clearing`) and before they are linked
(:func:`planning.toolpath.roughing.levels._cut_level`).

Per level the connected components of the region (:mod:`planning.toolpath.roughing.regions`) are
cut one after another (the nearest next), each its lines first, then its contours. The lines of a
component are grouped in boustrophedon zones (a run and the run of the next line are in one zone
when each is the other's only overlap in x), each cut as one zig-zag (one-way: every run from its
-X end); zones are taken greedily on the distance to their entry plus the distance from their
exit to the next remaining entry (one step of look-ahead); contours greedily from the nearest
vertex (any vertex of a closed one).
"""

from __future__ import annotations

import math

import numpy as np

from planning.toolpath.roughing.clearing import _Piece

ORDER_DENSE_MAX = 2048  #: up to this many zone variants in a component, all exit-entry distances are kept


def _entry(piece: _Piece, p):
    """Where to enter a piece from point p: (distance, oriented xy, oriented cells)."""
    if piece.ends == "loop":
        d = np.hypot(piece.xy[:-1, 0] - p[0], piece.xy[:-1, 1] - p[1])
        k = int(np.argmin(d))
        xy = np.concatenate([piece.xy[k:-1], piece.xy[:k + 1]])
        cells = np.concatenate([piece.cells[k:-1], piece.cells[:k + 1]])
        return float(d[k]), xy, cells
    d0 = float(np.hypot(*(piece.xy[0] - p)))
    if piece.ends == "both":
        d1 = float(np.hypot(*(piece.xy[-1] - p)))
        if d1 < d0:
            return d1, piece.xy[::-1], piece.cells[::-1]
    return d0, piece.xy, piece.cells


def _zones(lines_: list[_Piece]) -> list[list[_Piece]]:
    """Boustrophedon zones of one component's line runs: a run and the run of the next row are in
    the same zone when each is the other's only overlapping run (in x) in that row."""
    by_row: dict[int, list[_Piece]] = {}
    for pc in lines_:
        by_row.setdefault(pc.row, []).append(pc)
    up: dict[int, list[_Piece]] = {}
    down: dict[int, list[_Piece]] = {}
    ext = {id(pc): (min(float(pc.xy[0, 0]), float(pc.xy[-1, 0])), max(float(pc.xy[0, 0]), float(pc.xy[-1, 0])))
           for pc in lines_}                 # a line run is a straight segment along x
    for r, runs in by_row.items():
        for a in runs:
            for b in by_row.get(r + 1, []):
                if min(ext[id(a)][1], ext[id(b)][1]) > max(ext[id(a)][0], ext[id(b)][0]):
                    up.setdefault(id(a), []).append(b)
                    down.setdefault(id(b), []).append(a)
    zones, seen = [], set()
    for r in sorted(by_row):
        for a in sorted(by_row[r], key=lambda pc: ext[id(pc)][0]):
            if id(a) in seen:
                continue
            zone = [a]
            seen.add(id(a))
            while True:
                nxt = up.get(id(zone[-1]), [])
                if len(nxt) != 1 or len(down.get(id(nxt[0]), [])) != 1 or id(nxt[0]) in seen:
                    break
                zone.append(nxt[0])
                seen.add(id(nxt[0]))
            zones.append(zone)
    return zones


def _zone_variants(zone: list[_Piece], oneway):
    """The ways to cut a zone: from its first or last run, entered at either end (one-way: the -X
    end), zig-zag alternating; each as a list of (piece, oriented xy, oriented cells)."""
    out = []
    ends = {id(pc): (pc.xy[0].tolist(), pc.xy[-1].tolist()) for pc in zone}
    for runs in ((zone, zone[::-1]) if len(zone) > 1 else (zone,)):
        for flip in ((False,) if oneway else (False, True)):
            seq = []
            end = None
            for k, pc in enumerate(runs):
                first, last = ends[id(pc)]
                if oneway:
                    f = False
                elif k == 0:
                    f = flip
                else:                   # enter each run at the end nearer the last exit
                    f = math.hypot(last[0] - end[0], last[1] - end[1]) < math.hypot(first[0] - end[0],
                                                                                    first[1] - end[1])
                seq.append((pc, pc.xy[::-1], pc.cells[::-1]) if f else (pc, pc.xy, pc.cells))
                end = first if f else last
            out.append(seq)
    return out


def _near(p, variants_lists, contours):
    """Distance from p to the nearest entry of the remaining zones (or else contours; 0 if none)."""
    d = [float(np.hypot(*(v[0][1][0] - p))) for vs in variants_lists for v in vs]
    if not d:
        d = [_entry(pc, p)[0] for pc in contours]
    return min(d) if d else 0.0


def _exit_entry(ext, ent, zone_ext, zone_ent=None):
    """Distances from the exits ``ext`` (m,2) to the entries ``ent`` (n,2), inf between variants of
    the same zone."""
    zone_ent = zone_ext if zone_ent is None else zone_ent
    D = np.hypot(ent[None, :, 0] - ext[:, None, 0], ent[None, :, 1] - ext[:, None, 1])
    D[zone_ext[:, None] == zone_ent[None, :]] = np.inf
    return D


def _order(pieces: list[_Piece], p, oneway):
    """The order of a level's pieces from point p (None: anywhere): components one after another
    (the nearest next), in each the line zones then the contours. Zones: greedy on the distance to
    the zone's entry plus the distance from its exit to the next remaining entry (one step of
    look-ahead; the distances from every exit to every entry computed at once); contours: greedy
    nearest vertex."""
    comps: dict[int, tuple[list, list]] = {}
    for pc in pieces:
        comps.setdefault(pc.comp, ([], []))[0 if pc.is_line else 1].append(pc)
    todo = {}
    for c, (ls, cs) in comps.items():
        zs = [_zone_variants(z, oneway) for z in _zones(ls)]
        flat = [v for vs in zs for v in vs]
        zone = np.array([i for i, vs in enumerate(zs) for _ in vs], np.int64)
        ent = np.array([v[0][1][0] for v in flat]).reshape(-1, 2)
        ext = np.array([v[-1][1][-1] for v in flat]).reshape(-1, 2)
        todo[c] = (flat, zone, ent, ext, len(zs), list(cs))
    seq = []
    while todo:
        def entry_dist(c, p=p):
            flat, _, ent, _, _, cs = todo[c]
            if p is None:
                return 0.0
            if flat:
                return float(np.hypot(ent[:, 0] - p[0], ent[:, 1] - p[1]).min())
            return _near(p, [], cs)
        c = min(todo, key=entry_dist)
        flat, zone, ent, ext, nz, cs = todo.pop(c)
        if flat:
            # D[v, w]: from the exit of variant v to the entry of variant w of another zone
            D = _exit_entry(ext, ent, zone) if len(flat) <= ORDER_DENSE_MAX else None
            alive = np.ones(len(flat), dtype=bool)
            for _ in range(nz):
                live = np.flatnonzero(alive)
                if np.unique(zone[live]).size > 1:
                    if D is not None:
                        near = D[np.ix_(live, live)].min(axis=1)
                    else:
                        near = np.concatenate([_exit_entry(ext[live[k:k + 256]], ent[live], zone[live[k:k + 256]],
                                                           zone[live]).min(axis=1) for k in range(0, live.size, 256)])
                else:                       # the last zone: look ahead to the contours
                    near = np.array([_near(ext[v], [], cs) for v in live])
                d = np.zeros(live.size) if p is None else np.hypot(ent[live, 0] - p[0], ent[live, 1] - p[1])
                v = int(live[int(np.argmin(d + near))])
                alive[zone == zone[v]] = False
                seq += flat[v]
                p = flat[v][-1][1][-1]
        while cs:
            if p is None:
                p = cs[0].xy[0]
            k = min(range(len(cs)), key=lambda i: _entry(cs[i], p)[0])
            pc = cs.pop(k)
            _, xy, cells = _entry(pc, p)
            seq.append((pc, xy, cells))
            p = xy[-1]
    return seq
