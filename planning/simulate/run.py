"""One program's moves run on the stock and checked against the obstacles, in program order
(:mod:`planning.simulate.dexel`): consecutive moves with the same tool in the spindle go to
:func:`~planning.simulate.dexel.simulate_moves` together (it keeps their order), so the stock every
move meets is the stock the moves before it left."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planning.simulate.dexel import TriDexel, collide, deviation_pair, signed_deviation, simulate_moves
from planning.simulate.motion import ProgramMotion

__all__ = ["MoveFigures", "deviation_pair", "run_moves", "signed_deviation"]


@dataclass
class MoveFigures:
    """Per move (P,): ``removed_mm3`` material removed; ``rapid_depth_mm`` how far a rapid's tool
    is in stock; ``holder_depth_mm`` how far a feed move's shank or holder is in stock;
    ``fixture_depth_mm`` how far any part of the tool is in a fixture, the riser or the table; all
    0 when clear. ``no_tool``: moves made with no tool in the spindle (not simulated)."""

    removed_mm3: np.ndarray
    rapid_depth_mm: np.ndarray
    holder_depth_mm: np.ndarray
    fixture_depth_mm: np.ndarray
    no_tool: int = 0


def _blocks(tool: np.ndarray) -> list[tuple[int, int]]:
    """Runs [a, b) of consecutive moves with the same tool."""
    if tool.size == 0:
        return []
    cut = np.flatnonzero(tool[1:] != tool[:-1]) + 1
    edges = np.concatenate([[0], cut, [tool.size]])
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def run_moves(stock: TriDexel, obstacles: TriDexel | None, motion: ProgramMotion, tools: dict, *,
              rapid_clearance_mm: float = 0.0, progress=None) -> MoveFigures:
    """Cut ``stock`` (in place) with the moves of ``motion`` in their order and measure every move
    (see :class:`MoveFigures`); ``tools`` maps T numbers to
    :class:`~planning.simulate.motion.ToolShape`. A T number missing from ``tools`` raises.
    ``progress(fraction, message)``: the share of the moves done, per block of one tool."""
    P = motion.n_moves
    out = MoveFigures(np.zeros(P), np.zeros(P), np.zeros(P), np.zeros(P))
    for a, b in _blocks(motion.tool):
        if progress is not None:
            progress(a / max(P, 1), f"moves {a + 1}-{b} of {P} (T{int(motion.tool[a])})")
        number = int(motion.tool[a])
        if number == 0:
            out.no_tool += b - a
            continue
        if number not in tools:
            raise KeyError(f"{motion.program}: tool T{number} is not one of the plan's tools {sorted(tools)}")
        shape = tools[number]
        s, e, ax, kind = motion.start_mm[a:b], motion.end_mm[a:b], motion.axis[a:b], motion.kind[a:b]
        inner = None
        if progress is not None:            # the block's share of the moves: 85 % the stock, 15 % the obstacles
            inner = (lambda share, text, a=a, b=b: (lambda f, m: progress((a + share[0] * (b - a) + f * share[1] * (b - a))
                                                                          / max(P, 1), f"{text}: {m}")))
        r = simulate_moves(stock, s, e, ax, shape, kind, rapid_clearance_mm=rapid_clearance_mm,
                           progress=None if inner is None else inner((0.0, 0.85), "stock"))
        out.removed_mm3[a:b] = r.removed_mm3
        out.rapid_depth_mm[a:b] = r.rapid_depth_mm
        out.holder_depth_mm[a:b] = r.holder_depth_mm
        if obstacles is not None:
            out.fixture_depth_mm[a:b] = collide(obstacles, s, e, ax, shape, which="tool",
                                                progress=None if inner is None else inner((0.85, 0.15), "fixtures"))
    return out
