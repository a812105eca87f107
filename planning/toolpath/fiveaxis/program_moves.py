"""The moves of a 5-axis finishing path as its LinuxCNC program makes them (issue 33, the guard).

The guard (:mod:`planning.toolpath.guard`) runs an operation's moves on the carried stock and cuts
out the moves whose shank or holder meets material; the verification
(:mod:`planning.simulate.verify`) runs the posted program on its own stock. For a 3+2 path both
see the same straight tip segments. A simultaneous 5-axis path they saw differently:

* the guard ran each planned move straight, the axis turned along the great circle in steps of at
  most 1 degree, each step with its end's axis (:func:`planning.toolpath.guard.part_moves`);
* the program moves every axis linearly in JOINT space between the points the post writes (the
  post inserts about eight points per planned move to keep the ball centre within
  ``PostOptions.chord_tol_mm`` of the planned segment, :mod:`planning.post.simultaneous`), and the
  verification's reader cuts each move into steps of at most 1 degree of either rotary axis, each
  with its end's axis.

A step with its end's axis puts the flutes up to ``height x turn`` (rad) from where the turning tool
is, so the two models removed different material (the guard's carried stock had 110-125 mm3 less
per set-up on the 20k femur-like plan, ``bench/bench_guard_vs_program.py``) and placed the holder
differently: the verification found shank and holder contacts of up to 0.05 mm the guard never saw.

:func:`program_part_moves` removes the difference at its root: it posts the path as the LinuxCNC
post will (:func:`planning.post.simultaneous.linuxcnc_5axis_motion`: the blocks of
:func:`~planning.post.simultaneous.linuxcnc_5axis_blocks` as numbers, of the operation the plan's
programs post, :func:`planning.post.programs.five_axis_operation`) and moves the machine through those
blocks as the verification's reader does (:mod:`planning.simulate.program`, LinuxCNC: the printed
X Y Z plus the tool length ``G43`` is the controlled point; every axis linear in joint space, cut
into steps of at most ``rotary_step_deg`` of either rotary axis by
:func:`planning.simulate.kinematics.interpolate_moves`; each step's tips and end axis from
:meth:`~planning.simulate.kinematics.MachineModel.tip_from_machine`). The guard then runs the moves
the verification will: the same inserted points, the same printed words, the same C turned back at
machine Z0 (``G53 G0 Z0``, the rotary words alone, then down). ``tests/test_guard_program_moves.py``
compares them with the reader's moves of the posted text.

Cost: the post's point insertion once per guard round (a few seconds for 30k planned moves).
"""

from __future__ import annotations

import numpy as np

__all__ = ["program_part_moves"]


def program_part_moves(operation, *, profile, placement_mm, options, rotary_step_deg: float = 1.0):
    """:class:`planning.toolpath.guard.PartMoves` of a 5-axis path as its LinuxCNC program runs it
    (module docstring): ``start``/``end`` tool tips (part frame, mm) and ``axis`` (unit, part frame)
    of every step, from the approach block to the last posted point; ``kind`` the simulation's RAPID /
    FEED; ``source`` the planned move (point index of the path) whose posted point the step leads to
    (the approach: move 0).

    ``operation``: the path as the programs post it, :class:`~planning.post.simultaneous.FiveAxisOperation`
    (:func:`planning.post.programs.five_axis_operation`: ball centres and axes in the part frame, the
    tool's gauge length = the tool length of ``G43``, where C may be turned back); ``profile`` /
    ``placement_mm``: the machine and the part on its table; ``options``: the
    :class:`~planning.post.options.PostOptions` of the area's programs; ``rotary_step_deg``: the
    reader's step (:func:`planning.simulate.program.read_program`, the verification's 1 degree)."""
    from planning.post.simultaneous import linuxcnc_5axis_motion
    from planning.simulate.kinematics import MachineModel, interpolate_moves
    from planning.simulate.motion import FEED as SIM_FEED
    from planning.simulate.motion import RAPID as SIM_RAPID
    from planning.toolpath.guard import PartMoves
    from planning.toolpath.moves import RAPID

    blocks = linuxcnc_5axis_motion(operation, profile, placement_mm, options)
    model = MachineModel(profile, placement_mm)
    gauge = float(operation.gauge_length_mm)
    # the controlled point: the printed X Y Z plus the tool length (G43 H) on a table-table machine;
    # the head's rotation centre as printed (G49) on a head-head one
    lift = np.array([0.0, 0.0, gauge if model.table else 0.0])
    pos = np.vstack([blocks["approach_mm"][None, :], blocks["pos_mm"]]) + lift
    ang = np.vstack([blocks["approach_deg"][None, :], blocks["angles_deg"]])
    rapid = np.concatenate([[True], blocks["kind"] == RAPID])
    move = np.concatenate([[0], blocks["move"]])
    home = np.concatenate([[False], blocks["home"]])
    # every block as a move from the one before; a turn back at machine Z0 is three: up to Z0 (the
    # angles as they were), the rotary axes alone, down to the point (module docstring)
    p0, p1, a0, a1 = pos[:-1], pos[1:], ang[:-1], ang[1:]
    src, fast = move[1:], rapid[1:]
    h = np.flatnonzero(home[1:])
    if h.size:
        top = p0[h].copy()
        top[:, 2] = model.home[2]
        seg_p0 = np.stack([p0[h], top, top], axis=1)
        seg_p1 = np.stack([top, top, p1[h]], axis=1)
        seg_a0 = np.stack([a0[h], a0[h], a1[h]], axis=1)
        seg_a1 = np.stack([a0[h], a1[h], a1[h]], axis=1)
        n = np.where(home[1:], 3, 1)
        at = np.cumsum(n) - n
        P0, P1 = np.repeat(p0, n, axis=0), np.repeat(p1, n, axis=0)
        A0, A1 = np.repeat(a0, n, axis=0), np.repeat(a1, n, axis=0)
        rows = (at[h][:, None] + np.arange(3)[None, :]).ravel()
        P0[rows], P1[rows] = seg_p0.reshape(-1, 3), seg_p1.reshape(-1, 3)
        A0[rows], A1[rows] = seg_a0.reshape(-1, 2), seg_a1.reshape(-1, 2)
        p0, p1, a0, a1 = P0, P1, A0, A1
        src, fast = np.repeat(src, n), np.repeat(fast, n)
    owner, q0, q1, b0, b1 = interpolate_moves(p0, p1, a0, a1, float(rotary_step_deg))
    t0, _ = model.tip_from_machine(q0, b0, gauge)
    t1, axis = model.tip_from_machine(q1, b1, gauge)
    kind = np.where(fast[owner], SIM_RAPID, SIM_FEED).astype(np.int8)
    return PartMoves(start=t0, end=t1, kind=kind, source=src[owner].astype(np.int64), axis=axis)
