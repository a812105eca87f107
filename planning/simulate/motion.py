"""The data the simulation passes between its parts (issue 15): tool shapes and posed program motion.

* :class:`ToolShape`: a cutter and what holds it, as solids of revolution along the tool axis,
  measured from the tool TIP (mm): the cutting part (ball, flat or bull-nose up to the flute
  length) and the non-cutting pieces above it (shank, holder: cylinders; a cone is replaced by the
  cylinder of its larger radius, conservative).
* :class:`ProgramMotion`: one NC program read back as a control would run it
  (:mod:`planning.simulate.program` from the text, or :mod:`planning.simulate.rs274` from
  LinuxCNC's interpreter), every move a straight segment of the tool tip in the PART frame with the
  tool axis it has (arcs split into chords, rotary repositioning into small steps), plus where the
  machine's axes are at the end of the move (for the travel check).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Move kinds of :class:`ProgramMotion`: a rapid (G0) or a cutting move (G1, or a chord of G2/G3).
RAPID, FEED = 0, 1


@dataclass(frozen=True)
class ToolShape:
    """A tool in the spindle (mm, along the axis from the tip).

    ``number``: T number; ``kind``: ``"ball"``, ``"flat"`` or ``"bull"``; ``radius_mm`` R;
    ``corner_radius_mm`` (bull: 0 < rc < R; ball: R; flat: 0); ``flute_length_mm``: the cutting
    part reaches from the tip to this height; ``pieces``: non-cutting solids above it, each
    ``(z0_mm, z1_mm, radius_mm)`` (a cylinder from z0 to z1 above the tip; z1 may be ``inf``);
    ``gauge_length_mm``: tip to the spindle gauge line (the point the machine's linear axes
    position on table-table machines)."""

    number: int
    kind: str
    radius_mm: float
    corner_radius_mm: float
    flute_length_mm: float
    pieces: tuple[tuple[float, float, float], ...] = ()
    gauge_length_mm: float = 0.0


@dataclass
class ProgramMotion:
    """One program's moves in the part frame (P moves; see the module docstring).

    ``program``: artifact name (``area_0.linuxcnc.nc``); ``area``: the area / set-up it machines;
    ``line`` (P,) int: the 1-based line of the program text that commands the move; ``kind`` (P,)
    int8: :data:`RAPID` or :data:`FEED`; ``tool`` (P,) int: T number in the spindle (0: none);
    ``start_mm`` / ``end_mm`` (P,3): tool tip at the start / end of the move (part frame);
    ``axis`` (P,3): unit tool axis in the part frame, from the tip towards the spindle (constant
    over one move); ``machine_mm`` (P,3): the machine's linear axes (the profile's controlled
    point, machine frame) at the end of the move; ``rotary_deg`` (P,2): (tilt, rotary) machine
    positions at the end of the move; ``notes``: what the reader assumed (e.g. where G53 Z0 is)."""

    program: str
    area: int
    line: np.ndarray
    kind: np.ndarray
    tool: np.ndarray
    start_mm: np.ndarray
    end_mm: np.ndarray
    axis: np.ndarray
    machine_mm: np.ndarray
    rotary_deg: np.ndarray
    notes: list[str] = field(default_factory=list)
    #: (n_lines,) per program line (0-based) the F word in force, and whether G93 (inverse time) is;
    #: None where the reader does not give them (the moves then run at the tools' nominal feeds)
    line_feed: np.ndarray | None = None
    line_inverse_time: np.ndarray | None = None

    @property
    def n_moves(self) -> int:
        return int(self.line.shape[0])


@dataclass
class SimulatedMoves:
    """One operation's moves as they were run on the carried stock while the paths were planned
    (:func:`planning.toolpath.guard.run_on_stock`, the guard's last, accepted run), kept so that the
    verification can take them instead of running the program again (:mod:`planning.simulate.single_pass`).

    ``tool``: the T number; ``source`` (n,) int: the toolpath move each segment belongs to (an arc is
    several chords); ``start_mm`` / ``end_mm`` (n,3): tool tip (part frame); ``axis`` (n,3):
    unit tool axis; ``kind`` (n,) :data:`RAPID` / :data:`FEED`; ``removed_mm3`` (n,) what each move
    cut; ``rapid_depth_mm`` / ``holder_depth_mm`` / ``fixture_depth_mm`` (n,) as
    :class:`planning.simulate.run.MoveFigures` (a rapid measured with the tool grown by
    ``rapid_clearance_mm``); ``fixture`` (n,) bool: the tool in a fixture, the riser or the table;
    ``travel`` (n,) bool: a move end beyond the machine's travel; ``stock_before`` / ``stock_after``
    (:class:`~planning.simulate.dexel.TriDexel`): the stock the moves met and the one they left
    (references; nobody changes them afterwards)."""

    tool: int
    source: np.ndarray
    start_mm: np.ndarray
    end_mm: np.ndarray
    axis: np.ndarray
    kind: np.ndarray
    removed_mm3: np.ndarray
    rapid_depth_mm: np.ndarray
    holder_depth_mm: np.ndarray
    fixture: np.ndarray
    travel: np.ndarray
    rapid_clearance_mm: float
    stock_before: object = None
    stock_after: object = None

    @property
    def n_moves(self) -> int:
        return int(self.kind.shape[0])

    @property
    def clean(self) -> bool:
        """No offence of any class on any move."""
        return not (np.any(self.rapid_depth_mm > 0) or np.any(self.holder_depth_mm > 0)
                    or np.any(self.fixture) or np.any(self.travel))
