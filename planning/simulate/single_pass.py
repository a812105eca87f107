"""Stage 9, single pass (issue 30 item 2): the verification takes the moves the paths stage already ran
on the carried stock, once it has proved that the posted program runs exactly those moves.

While the paths are planned, every operation (the roughing or the finishing of one set-up) is run on
the stock the operations before it left (:func:`planning.toolpath.guard.guard_toolpath`); its last,
accepted run is kept as :class:`~planning.simulate.motion.SimulatedMoves`: the tool-tip segments in
the part frame with what each removed and how deep anything met material. The verification still
reads every posted program back as a control would (:func:`planning.simulate.program.read_program`,
from its text). :func:`prove_program` then checks, for each program:

1. each operation's moves are in the program, in order, with its tool in the spindle: from the first
   program move that ends on the operation's first point, every program move ends within ``tol_mm``
   of the simulated move's end (the posts' rounding: :func:`proof_tolerance_mm`), with the same kind
   (rapid or feed) and tool axis; a simulated move shorter than ``tol_mm`` may have no program move
   (the post writes no block that moves nothing after rounding);
2. every other program move with a tool in the spindle (to and from machine Z0, the rotary
   positioning, the approach to the first point, the retract from the last) is a rapid that keeps
   the rapid clearance from the stock as it is when the move runs (the stock the simulated
   operation after it met, or the one the operation before it left); its figures against the
   fixtures, the riser and the table are measured (they never change);
3. the simulated run had no offence of any class (the guard's accepted run is clean, or the
   verification could not tell what the program's own rounding would add).

A proven program's move figures are the simulated ones; when every program is proven the stock is
the carried stock. Anything unproven (a program edited after posting, a post that splits moves
differently, a 5-axis program, paths planned without the carried stock) makes the verification run
every program again on a fresh stock (``simulate.mode = "independent"``), and the plan says why.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

from planning.simulate.dexel import TriDexel, collide
from planning.simulate.motion import FEED, ProgramMotion, SimulatedMoves
from planning.simulate.run import MoveFigures

#: A simulated move that removed less than this removed nothing (mm^3): the verification's own limit.
AIR_MM3 = 1e-6

#: Largest difference of the program's tool axis from the simulated one (unit vectors): the rotary
#: words are printed to a thousandth of a degree (1.7e-5 rad).
AXIS_TOL = 1e-4


def proof_tolerance_mm(decimals: int) -> float:
    """How far a program move's end may lie from the simulated one (mm): the posts round every
    coordinate to ``decimals`` (at most half a unit of the last digit per axis, ``sqrt(3)/2`` of one
    unit in all), the reader turns them back into the part frame; twice that."""
    return 2.0 * 10.0 ** -int(decimals)


@dataclass
class Proof:
    """``figures``: the program's move figures (None when not proven); ``reason``: why not ('' when
    proven); ``n_simulated``: program moves taken from the simulated run; ``n_checked``: the other
    moves, checked here."""

    figures: MoveFigures | None
    reason: str = ""
    n_simulated: int = 0
    n_checked: int = 0


def _line(motion: ProgramMotion, i: int) -> str:
    return f"{motion.program} line {int(motion.line[min(max(i, 0), motion.n_moves - 1)])}"


@njit(cache=True)
def _match_anchors(prog_end, prog_tool, anchors, tool, tol):
    """For each anchor point in order, the index of the first program move after the previous match
    (from 0) that ends within ``tol`` of it (max norm) with ``tool`` in the spindle; -1 from the first
    anchor not found (a move with another tool ends the search)."""
    out = np.full(anchors.shape[0], -1, np.int64)
    i = 0
    n = prog_end.shape[0]
    for t in range(anchors.shape[0]):
        while i < n and prog_tool[i] == tool:
            d = max(abs(prog_end[i, 0] - anchors[t, 0]), abs(prog_end[i, 1] - anchors[t, 1]),
                    abs(prog_end[i, 2] - anchors[t, 2]))
            if d <= tol:
                break
            i += 1
        if i >= n or prog_tool[i] != tool:
            return out
        out[t] = i
        i += 1
    return out


@njit(cache=True)
def _polyline_distance(points, owner, seg_first, seg_last, seg_start, seg_end):
    """Per point, its distance (mm) to the nearest of the segments ``seg_first[owner]`` ..
    ``seg_last[owner]`` (inclusive)."""
    out = np.empty(points.shape[0])
    for k in range(points.shape[0]):
        t = owner[k]
        best = np.inf
        for j in range(seg_first[t], seg_last[t] + 1):
            dx = seg_end[j, 0] - seg_start[j, 0]
            dy = seg_end[j, 1] - seg_start[j, 1]
            dz = seg_end[j, 2] - seg_start[j, 2]
            px = points[k, 0] - seg_start[j, 0]
            py = points[k, 1] - seg_start[j, 1]
            pz = points[k, 2] - seg_start[j, 2]
            ll = dx * dx + dy * dy + dz * dz
            u = 0.0 if ll <= 0.0 else min(1.0, max(0.0, (px * dx + py * dy + pz * dz) / ll))
            qx, qy, qz = px - u * dx, py - u * dy, pz - u * dz
            best = min(best, math.sqrt(qx * qx + qy * qy + qz * qz))
        out[k] = best
    return out


def _prove_operation(motion: ProgramMotion, op: SimulatedMoves, i: int, figs: MoveFigures, taken: np.ndarray,
                     tol_mm: float, chord_tol_mm: float):
    """Step 1 of the module docstring for one operation, from program move ``i`` on: ``(next program
    move, '')`` with ``figs.removed_mm3`` and ``taken`` filled in, or ``(-1, why not)``.

    The anchors are the simulated toolpath moves' end points (an arc's last chord ends on the arc's
    end; a toolpath move shorter than ``tol_mm`` is merged into the next): each must end a program
    move, in order. The program moves between two anchors (the chords of an arc, as the reader or the
    post split it) must lie within ``chord_tol_mm + tol_mm`` of the simulated chords of the same
    toolpath move, with its kind (rapid, feed). What a toolpath move removed is shared among its
    program moves by length."""
    src = op.source
    last = np.flatnonzero(np.r_[src[1:] != src[:-1], True])          # each toolpath move's last segment
    first = np.r_[0, last[:-1] + 1]
    seg_len = np.linalg.norm(op.end_mm - op.start_mm, axis=1)
    move_len = np.add.reduceat(seg_len, first)
    move_removed = np.add.reduceat(op.removed_mm3, first)
    start_anchor = op.end_mm[last[0]]
    near = np.abs(motion.end_mm[i:] - start_anchor).max(axis=1) <= tol_mm
    hit = np.flatnonzero(near & (motion.tool[i:] == op.tool))
    if hit.size == 0:
        return -1, f"{motion.program}: the first point of the simulated T{op.tool} moves is not in it"
    i0 = i + int(hit[0])
    if move_removed[0] > AIR_MM3:
        return -1, f"{_line(motion, i0)}: the simulated T{op.tool} run cut before its first move"
    real = np.flatnonzero(move_len > tol_mm)
    real = real[real > 0]
    if real.size == 0:
        return i0 + 1, ""
    # what the moves merged into the next real one removed goes with it
    owner_of_move = np.minimum(np.searchsorted(real, np.arange(last.size), side="left"), real.size - 1)
    removed = np.zeros(real.size)
    np.add.at(removed, owner_of_move[1:], move_removed[1:])
    lines = _match_anchors(motion.end_mm[i0 + 1:], motion.tool[i0 + 1:], np.ascontiguousarray(op.end_mm[last[real]]),
                           int(op.tool), float(tol_mm))
    if lines[-1] < 0:
        t = int(np.flatnonzero(lines < 0)[0])
        after = i0 + 1 + (int(lines[t - 1]) + 1 if t > 0 else 0)
        return -1, (f"{_line(motion, after)}: the program leaves the simulated T{op.tool} path (toolpath move "
                    f"{int(real[t])} not found after it)")
    lines = lines + i0 + 1
    span = np.arange(i0 + 1, int(lines[-1]) + 1)
    owner = np.searchsorted(lines, span, side="left")                # the anchor each program move leads to
    kinds = op.kind[last[real]]
    bad = (motion.kind[span] != kinds[owner]) | (np.abs(motion.axis[span] - op.axis[last[real]][owner]).max(axis=1)
                                                 > AXIS_TOL)
    between = np.flatnonzero(~np.isin(span, lines))
    if between.size:
        t = real[owner[between]]
        dist = _polyline_distance(np.ascontiguousarray(motion.end_mm[span[between]]), t.astype(np.int64),
                                  first.astype(np.int64), last.astype(np.int64),
                                  np.ascontiguousarray(op.start_mm), np.ascontiguousarray(op.end_mm))
        bad[between] |= dist > chord_tol_mm + tol_mm
    if bad.any():
        j = int(span[np.flatnonzero(bad)[0]])
        return -1, f"{_line(motion, j)} is not on the path the paths stage simulated (T{op.tool})"
    # where the program has as many moves as the simulation has chords (every straight move, most
    # arcs), each move takes its chord's figures; elsewhere the toolpath move's share by length
    seg = np.arange(int(last[0]) + 1, op.n_moves)
    seg_owner = owner_of_move[src[seg]]
    long_ = seg_len[seg] > tol_mm
    direct = (np.bincount(seg_owner[long_], minlength=real.size) == np.bincount(owner, minlength=real.size))
    figs.removed_mm3[span[direct[owner]]] = op.removed_mm3[seg[long_ & direct[seg_owner]]]
    short = ~long_ & direct[seg_owner]
    np.add.at(figs.removed_mm3, lines[seg_owner[short]], op.removed_mm3[seg[short]])
    rest = ~direct[owner]
    plen = np.linalg.norm(motion.end_mm[span] - motion.start_mm[span], axis=1)
    total = np.bincount(owner[rest], weights=plen[rest], minlength=real.size)
    share = np.where(total[owner] > 0, plen / np.maximum(total[owner], 1e-300), (span == lines[owner]).astype(float))
    figs.removed_mm3[span[rest]] += (removed[owner] * share)[rest]
    taken[span] = True
    return int(lines[-1]) + 1, ""


def prove_program(motion: ProgramMotion, operations: Sequence[SimulatedMoves], stock0: TriDexel,
                  obstacles: TriDexel | None, tools: dict, *, tol_mm: float,
                  rapid_clearance_mm: float, chord_tol_mm: float = 0.005) -> Proof:
    """Whether ``motion`` (one program read back) runs the simulated ``operations`` (in their order)
    and nothing else that could meet material (module docstring), and if so its per-move figures.
    ``stock0``: the stock before any set-up ran; ``obstacles``: fixtures, riser and table (or None);
    ``tools``: T number -> :class:`~planning.simulate.motion.ToolShape`; ``tol_mm``: the largest
    distance of a program move's end from the simulated one; ``chord_tol_mm``: the chord tolerance
    of the arcs (the reader's and the post's); ``rapid_clearance_mm``: the verification's rapid
    clearance. Lengths mm."""
    P = motion.n_moves
    figs = MoveFigures(np.zeros(P), np.zeros(P), np.zeros(P), np.zeros(P))
    taken = np.zeros(P, dtype=bool)
    i = 0
    ran, starts = [], []                               # the operations run, and where their moves begin
    for op in operations:
        if op.n_moves == 0:
            continue
        if not op.clean:
            return Proof(None, f"{motion.program}: the simulated run of T{op.tool} has offences")
        before = taken.copy()
        i, why = _prove_operation(motion, op, i, figs, taken, tol_mm, chord_tol_mm)
        if i < 0:
            return Proof(None, why)
        new = np.flatnonzero(taken & ~before)
        if new.size:
            ran.append(op)
            starts.append(int(new[0]))
    if not taken.any() and any(op.n_moves for op in operations):
        return Proof(None, f"{motion.program}: none of the simulated moves is in it")
    # the program's other moves: rapids, run on the stock as it is when they run (before the first
    # operation, between two, after the last: the simulated runs' own stocks; the first stock when
    # they are not known, which holds more); the obstacles measured
    other = np.flatnonzero(~taken & (motion.tool != 0))
    feeds = other[motion.kind[other] == FEED]
    if feeds.size:
        return Proof(None, f"{_line(motion, int(feeds[0]))}: a feed move the paths stage did not simulate")
    phase = np.searchsorted(np.asarray(starts, dtype=np.int64), other, side="right")
    for k in np.unique(phase):
        stock = (ran[0].stock_before if k == 0 else ran[k - 1].stock_after) if ran else None
        stock = stock0 if stock is None else stock
        for number in np.unique(motion.tool[other[phase == k]]):
            idx = other[(phase == k) & (motion.tool[other] == number)]
            if int(number) not in tools:
                return Proof(None, f"{motion.program}: tool T{int(number)} is not one of the plan's tools")
            shape = tools[int(number)]
            s, e, ax = motion.start_mm[idx], motion.end_mm[idx], motion.axis[idx]
            depth = collide(stock, s, e, ax, shape, which="tool", grow_mm=rapid_clearance_mm)
            if np.any(depth > 0):
                j = int(idx[np.flatnonzero(depth > 0)[0]])
                return Proof(None, f"{_line(motion, j)}: a rapid the paths stage did not simulate comes within "
                                   f"{rapid_clearance_mm:g} mm of the stock")
            if obstacles is not None:
                figs.fixture_depth_mm[idx] = collide(obstacles, s, e, ax, shape, which="tool")
    figs.no_tool = int((motion.tool == 0).sum())
    return Proof(figs, "", n_simulated=int(taken.sum()), n_checked=int(other.size))
