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

:func:`route_unwinding_links` asks the post's own walk where C must be turned back: run with C
allowed to turn back on the moves in the air and at the start of every link that has none (a short
link, a feed step-over), it turns C back where the post will and, at such links, where the post
could not. Those links are cut out and :func:`planning.toolpath.safety.cut_moves` links the two
passes through the safe height (retract along the axis, up, across, down, plunge); the post then
turns C back on the move across, by way of machine Z0, and the guard runs the new moves on the
stock as it runs every other. Only as many links as needed are routed: after each, the C that
follows is whole turns nearer 0.
"""

from __future__ import annotations

import numpy as np

from planning.toolpath.moves import RAPID, Toolpath

__all__ = ["air_moves", "route_unwinding_links"]


def air_moves(tp: Toolpath, safe_z_mm: float) -> np.ndarray:
    """(P,) bool: the moves (into point k) that are rapids with both ends at or above ``safe_z_mm``
    (area frame): where the post may turn C back (:class:`planning.post.simultaneous.FiveAxisOperation`
    ``unwind``). The guard feeds a rapid that meets the stock below the safe height, never one at it."""
    z = tp.xyz_mm[:, 2]
    out = np.zeros(tp.n_moves, dtype=bool)
    s = float(safe_z_mm) - 1e-6
    out[1:] = (tp.kind[1:] == RAPID) & (z[1:] >= s) & (z[:-1] >= s)
    return out


def _links(pi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(first, last)`` points of every link: a run of points off the passes (``pass_index`` < 0)
    between two points on passes."""
    off = pi < 0
    first = np.flatnonzero(off & ~np.r_[False, off[:-1]])
    last = np.flatnonzero(off & ~np.r_[off[1:], False])
    ok = (first > 0) & (last < pi.shape[0] - 1)
    return first[ok], last[ok]


def route_unwinding_links(tp: Toolpath, pass_index, *, profile, rotation: np.ndarray,
                          safe_z_mm: float, max_rounds: int = 8) -> tuple[Toolpath, np.ndarray | None, int]:
    """``(toolpath, pass_index, n_routed)`` (module docstring). ``tp``: a 5-axis finishing path in its
    area frame (with ``axis``); ``pass_index`` (P,) (kept aligned, -1 on the new points; None: nothing
    is routed); ``profile``: the machine profile; ``rotation``: the area frame's rotation (axes in
    the part frame are ``axis @ rotation``, as
    :meth:`planning.toolpath.fiveaxis.finishing.Admissible.solution_flips` takes them);
    ``safe_z_mm``: the ball-centre height of links through the safe height (area frame).

    The post's own walk (:func:`planning.post.simultaneous.rotary_path`) decides: run with C allowed
    to turn back on the moves in the air (:func:`air_moves`) and at the start of every link without
    one, it turns C back exactly where the post would, and at the links it could not. Those links'
    points are cut out and :func:`planning.toolpath.safety.cut_moves` links the passes through the
    safe height. Rounds (cutting renumbers the points) until nothing is left or ``max_rounds``."""
    from planning.post.simultaneous import rotary_path
    from planning.toolpath.safety import cut_moves

    if pass_index is None or tp.axis is None or tp.n_moves < 3 or not profile.rotary_continuous:
        return tp, pass_index, 0
    pi = np.asarray(pass_index)
    n_routed = 0
    for _ in range(int(max_rounds)):
        air = air_moves(tp, safe_z_mm)
        first, last = _links(pi)
        # a link is in the air when a move into one of its points is
        cs = np.cumsum(air)
        in_air = cs[last] - cs[first - 1] > 0
        first, last = first[~in_air], last[~in_air]
        cand = air.copy()
        cand[first] = True
        ang, _ = rotary_path(tp.axis @ rotation, profile, unwind=cand)
        turned = np.abs(ang[first, 1] - ang[first - 1, 1]) >= 180.0
        if not turned.any():
            break
        edge = np.zeros(tp.n_moves + 1, dtype=np.int64)
        np.add.at(edge, first[turned], 1)
        np.add.at(edge, last[turned] + 1, -1)
        drop = np.cumsum(edge)[:-1] > 0
        cut = cut_moves(tp, drop, safe_z_mm=safe_z_mm, pass_index=pi)
        tp, pi = cut.toolpath, cut.pass_index
        n_routed += int(turned.sum())
    return tp, pi, n_routed
