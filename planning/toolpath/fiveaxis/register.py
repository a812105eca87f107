"""Keep a continuous C within its register (issue 33 item 3): the links where C must be turned back
go through the safe height, where the post turns it back.

A continuous rotary axis is unwrapped along a path (:func:`planning.post.simultaneous.rotary_path`):
consecutive points never differ by 180 degrees or more, so passes that keep going round the part the
same way accumulate whole turns (the deep slot of issue 19 reached C-4,600, the 200k-point femur-like
plan C+4,433). The post turns C back on a rapid at the safe height (in the air between passes,
module docstring of :mod:`planning.post.simultaneous`, "The C register"), but the finishing's short
links (retract a few mm, one rapid across, plunge) have no such move, and the table must not swing
a full turn with the tool a few mm over the surface; and zig-zag passes joined by feed step-overs
turn C on within one run (on the slot, each pass across the floor passes the rotary pole on the
same side: 180 degrees more per pass).

:func:`route_unwinding_links` finds, in path order, the short links (a single rapid between two
feed moves) and the feed step-overs between two passes that the C would start at more than
:func:`unwind_at_deg` from 0, as the post would
walk it (its own unwinding on the links through the safe height included), and routes those links
through the safe height instead: the retract point goes straight up (area frame z) to ``safe_z_mm``
with its axis, across at ``safe_z_mm`` with the next axis, then down to the rapid's end, as
:func:`planning.toolpath.safety.cut_moves` links pieces. The post then turns C back on the move
across, by way of machine Z0; the guard runs the new rapids on the stock as it runs every other. Only as many links as needed are routed: after each,
the C that follows is one or more whole turns nearer 0.
"""

from __future__ import annotations

import numpy as np

from planning.toolpath.moves import RAPID, USE_RAPID, Toolpath

__all__ = ["air_moves", "route_unwinding_links", "unwind_at_deg"]


def unwind_at_deg(profile) -> float:
    """The |C| (degrees) above which a link is routed through the safe height: where the post turns
    C back (:func:`planning.post.simultaneous.unwind_deg`: the register less two turns, at least one)."""
    from planning.post.simultaneous import unwind_deg

    return unwind_deg(profile)


def air_moves(tp: Toolpath, safe_z_mm: float) -> np.ndarray:
    """(P,) bool: the moves (into point k) that are rapids with both ends at or above ``safe_z_mm``
    (area frame): where the post may turn C back (:class:`planning.post.simultaneous.FiveAxisOperation`
    ``unwind``). The guard feeds a rapid that meets the stock below the safe height, never one at it."""
    z = tp.xyz_mm[:, 2]
    out = np.zeros(tp.n_moves, dtype=bool)
    s = float(safe_z_mm) - 1e-6
    out[1:] = (tp.kind[1:] == RAPID) & (z[1:] >= s) & (z[:-1] >= s)
    return out


def _events(tp: Toolpath, pi: np.ndarray | None, safe_z_mm: float):
    """``(index (m,), kind (m,), runs)``: the links of ``tp`` in path order. kind 0: a rapid at the
    safe height (:func:`air_moves`: the post may unwind there); 1: a short link (one rapid between two feed moves); 2: a
    feed step-over (a run of feed points off the passes, ``pass_index`` -1, between two passes).
    ``runs``: per step-over, the (first, last) points of its run."""
    P = tp.n_moves
    kind = tp.kind
    rr = air_moves(tp, safe_z_mm)
    short = np.zeros(P, dtype=bool)
    short[1:-1] = (kind[1:-1] == RAPID) & (kind[:-2] != RAPID) & (kind[2:] != RAPID)
    idx = [np.flatnonzero(rr), np.flatnonzero(short)]
    runs = {}
    if pi is not None:
        off = (pi < 0) & (kind != RAPID)
        start = np.flatnonzero(off & ~np.r_[False, off[:-1]])
        end = np.flatnonzero(off & ~np.r_[off[1:], False])
        ok = (start > 0) & (end < P - 1)
        start, end = start[ok], end[ok]
        ok = (pi[start - 1] >= 0) & (pi[end + 1] >= 0) & (kind[start - 1] != RAPID) & (kind[end + 1] != RAPID)
        start, end = start[ok], end[ok]
        runs = dict(zip(start.tolist(), end.tolist()))
        idx.append(start)
    else:
        idx.append(np.zeros(0, np.int64))
    at = np.concatenate(idx)
    what = np.concatenate([np.full(a.size, k) for k, a in enumerate(idx)])
    order = np.argsort(at, kind="stable")
    return at[order], what[order], runs


def route_unwinding_links(tp: Toolpath, pass_index, *, profile, rotation: np.ndarray,
                          safe_z_mm: float, max_rounds: int = 8) -> tuple[Toolpath, np.ndarray | None, int]:
    """``(toolpath, pass_index, n_routed)`` (module docstring). ``tp``: a 5-axis finishing path in its
    area frame (with ``axis``); ``pass_index`` (P,) or None (kept aligned, -1 on the new points);
    ``profile``: the machine profile; ``rotation``: the area frame's rotation (axes in the part frame
    are ``axis @ rotation``, as :meth:`planning.toolpath.fiveaxis.finishing.Admissible.solution_flips`
    takes them); ``safe_z_mm``: the ball-centre height of links through the safe height (area frame).
    Rounds: each routes what the walk of the path as it stands asks for (the step-overs first, whose
    routing renumbers the points), until nothing is left or ``max_rounds``."""
    pi = None if pass_index is None else np.asarray(pass_index)
    if tp.axis is None or tp.n_moves < 3 or not profile.rotary_continuous:
        return tp, pi, 0
    n_routed = 0
    for _ in range(int(max_rounds)):
        short, steps = _marks(tp, pi, profile, rotation, safe_z_mm)
        if steps:
            from planning.toolpath.safety import cut_moves

            drop = np.zeros(tp.n_moves, dtype=bool)
            for a, b in steps:
                drop[a:b + 1] = True
            cut = cut_moves(tp, drop, safe_z_mm=safe_z_mm, pass_index=pi)
            tp, pi = cut.toolpath, cut.pass_index
            n_routed += len(steps)
            continue
        if not short:
            break
        tp, pi = _through_safe_height(tp, pi, np.asarray(short, dtype=np.int64), safe_z_mm)
        n_routed += len(short)
    return tp, pi, n_routed


def _marks(tp: Toolpath, pi, profile, rotation, safe_z_mm: float) -> tuple[list, list]:
    """``(short links, step-overs)`` to route: the rapid's index of each short link and the (first,
    last) points of each step-over whose C would start beyond :func:`unwind_at_deg`, in path order
    with the post's own unwinding (module docstring)."""
    from planning.post.simultaneous import rotary_path

    ang, _ = rotary_path(tp.axis @ rotation, profile)       # the walk without unwinding: C up to whole turns
    C = ang[:, 1]
    at, what, runs = _events(tp, pi, safe_z_mm)
    limit = unwind_at_deg(profile)
    short, steps = [], []
    offset = 0.0
    for j, k in zip(at.tolist(), what.tolist()):
        c = C[j - 1] + offset
        if k == 0:
            if abs(c) > limit:
                offset -= 360.0 * np.rint(c / 360.0)
        elif abs(c) > limit:
            (short if k == 1 else steps).append(j if k == 1 else (j, runs[j]))
            offset -= 360.0 * np.rint(c / 360.0)
    return short, steps


def _through_safe_height(tp: Toolpath, pi, at: np.ndarray, safe_z_mm: float):
    """``tp`` with the short links whose rapid ends at ``at`` routed through ``safe_z_mm``."""
    safe = float(safe_z_mm)
    up = tp.xyz_mm[at - 1].copy()
    up[:, 2] = np.maximum(up[:, 2], safe)
    across = tp.xyz_mm[at].copy()
    across[:, 2] = np.maximum(across[:, 2], safe)
    # two new points before each routed rapid's end: above where it leaves, above where it arrives
    new_xyz = np.stack([up, across], axis=1).reshape(-1, 3)
    new_axis = np.stack([tp.axis[at - 1], tp.axis[at]], axis=1).reshape(-1, 3)
    pos = np.repeat(at, 2)
    out = Toolpath(xyz_mm=np.insert(tp.xyz_mm, pos, new_xyz, axis=0),
                   kind=np.insert(tp.kind, pos, np.int8(RAPID)).astype(np.int8),
                   centre_mm=np.insert(tp.centre_mm, pos, np.full((pos.size, 3), np.nan), axis=0),
                   plane=np.insert(tp.plane, pos, np.int8(0)).astype(np.int8),
                   use=np.insert(tp.use, pos, np.int8(USE_RAPID)).astype(np.int8),
                   tip_offset_mm=tp.tip_offset_mm, axis=np.insert(tp.axis, pos, new_axis, axis=0))
    return out, (None if pi is None else np.insert(pi, pos, -1))
