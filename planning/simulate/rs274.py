"""LinuxCNC's own interpreter as an independent reader of the LinuxCNC programs (issue 15).

:func:`run_rs274` runs Debian's standalone RS274/NGC interpreter ``rs274`` (package
``linuxcnc-uspace``) on a LinuxCNC-dialect program and turns its canonical machining commands into
the same :class:`~planning.simulate.motion.ProgramMotion` as :func:`planning.simulate.program.read_program`,
through the same machine model (:mod:`planning.simulate.kinematics`) but none of its text parsing:
what a LinuxCNC control would execute, read by LinuxCNC's code.

How rs274 is run (``rs274 -t TOOL_TABLE -v PARAMETERS -g INPUT OUTPUT``, in a temporary folder)
------------------------------------------------------------------------------------------------
* The input is the program with every non-empty line (but ``%`` lines) given the block number
  ``N<line>`` (an existing leading ``N`` word is replaced), because rs274 prints each canonical
  command with the ``N`` word of its block: that is how a command maps back to its 1-based line.
* Without an INI file the standalone interpreter's machine units are INCHES: the tool table and
  the parameter file are written in inches (values / 25.4). The program's ``G21`` makes the
  canonical output millimetres (``USE_LENGTH_UNITS(CANON_UNITS_MM)``; inches raise).
* Tool table: ``T<n> P<n> Z<gauge length> D<diameter>`` for every tool of ``tools`` (the control's
  tool lengths are the gauge lengths, as :func:`~planning.simulate.program.read_program` assumes);
  without ``tools`` every T number of the program with length 0. rs274 loads it into a memory-mapped
  file, ``$HOME/.tool.mmap``, which every rs274 under the same HOME shares: each run is given the
  temporary folder as its HOME, so that runs at the same time (test workers, service jobs) keep
  their own tool lengths.
* Parameters: G54 (5221-5223) = minus the machine home of
  :data:`~planning.simulate.kinematics.HOME_NOTE`, so that LinuxCNC's machine coordinates (what
  ``G53`` addresses, 0 at home) are the machine frame less the home, and G54 is the machine frame
  the post writes in.

Reading its output
------------------
Each line is ``<count> N<block> COMMAND(args)``. ``STRAIGHT_TRAVERSE``/``STRAIGHT_FEED(x, y, z, a,
b, c)`` and ``ARC_FEED(first_end, second_end, first_axis, second_axis, rotation, axis_end, a, b,
c)`` (plane from ``SELECT_PLANE``: XY = (x, y; z), XZ = (z, x; y), YZ = (y, z; x); ``rotation``
> 0 counter-clockwise, ``|rotation| - 1`` extra turns) are in program coordinates: the machine
frame position of the controlled point is ``canonical + G5x offset + G92 offset + tool length
offset (USE_TOOL_LENGTH_OFFSET) + home``. ``CHANGE_TOOL`` puts the tool of the last ``SELECT_TOOL(T)``
in the spindle (its own argument is the tool table's slot). Rotary
values are the printed words; the signs they were printed with come from the post's header
comment (``signs: B flipped, C as planned``, seen as a ``COMMENT``) unless ``rotary_sign`` is given.
rs274 prints 4 decimals (0.1 micrometre; 1e-4 degree on the rotary axes).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from planning.errors import PlanningError
from planning.simulate.kinematics import (
    HOME_NOTE,
    MachineModel,
    arc_chords,
    interpolate_moves,
)
from planning.simulate.motion import FEED, RAPID, ProgramMotion

__all__ = ["INSTALL_HINT", "Rs274Error", "rs274_available", "run_rs274"]

INSTALL_HINT = ("LinuxCNC's standalone interpreter rs274 is not installed: on Debian / Ubuntu run "
                "`apt-get install linuxcnc-uspace` (it provides /usr/bin/rs274)")

_MM_PER_INCH = 25.4
_OUT_LINE = re.compile(r"^\s*\d+\s+N(\d+|\.+)\s*([A-Z_0-9]+)\((.*)\)\s*$")
_SIGNS = re.compile(r"signs:\s*([ABC])\s+(flipped|as planned)\s*,\s*([ABC])\s+(flipped|as planned)",
                    re.IGNORECASE)
_PLANES = {"CANON_PLANE_XY": (0, 1, 2), "CANON_PLANE_XZ": (2, 0, 1), "CANON_PLANE_YZ": (1, 2, 0)}
_IGNORED = {"COMMENT", "SET_FEED_RATE", "SET_FEED_MODE", "SET_FEED_REFERENCE", "ON_RESET",
            "START_CHANGE", "STOP_SPINDLE_TURNING", "START_SPINDLE_CLOCKWISE", "START_SPINDLE_COUNTERCLOCKWISE",
            "SET_SPINDLE_SPEED", "SET_SPINDLE_MODE", "FLOOD_ON", "FLOOD_OFF", "MIST_ON", "MIST_OFF",
            "SET_MOTION_CONTROL_MODE", "SET_NAIVECAM_TOLERANCE", "PALLET_SHUTTLE", "PROGRAM_END", "PROGRAM_STOP",
            "SET_XY_ROTATION", "ENABLE_FEED_OVERRIDE", "ENABLE_SPEED_OVERRIDE", "SET_TRAVERSE_RATE",
            "SET_CUTTER_RADIUS_COMPENSATION", "STOP_CUTTER_RADIUS_COMPENSATION", "CHANGE_TOOL_NUMBER"}


class Rs274Error(PlanningError):
    """rs274 is missing, refused the program, or printed something this reader does not know."""

    code = "rs274_error"
    status = 422


def rs274_available() -> bool:
    """True when LinuxCNC's standalone interpreter ``rs274`` is on the PATH."""
    return shutil.which("rs274") is not None


def _numbered(text: str) -> str:
    """The program with ``N<line>`` (1-based) at the head of every block."""
    out = []
    for ln, raw in enumerate(text.splitlines(), start=1):
        s = raw.strip()
        if not s or s[0] == "%":
            out.append(s)
        elif s[0] in "Nn":
            out.append(f"N{ln} " + re.sub(r"^[Nn]\s*\d+\s*", "", s))
        else:
            out.append(f"N{ln} {s}")
    return "\n".join(out) + "\n"


def _tool_table(text: str, tools) -> str:
    """The tool table (inches: the standalone interpreter's machine units)."""
    if tools is None:
        numbers = sorted({int(n) for n in re.findall(r"[Tt]\s*(\d+)", re.sub(r"\([^)]*\)", "", text))})
        rows = [(n, 0.0, 0.0) for n in numbers if n > 0]
    else:
        rows = [(int(n), float(t.gauge_length_mm), 2.0 * float(t.radius_mm)) for n, t in sorted(tools.items())]
    return "".join(f"T{n} P{n} Z{g / _MM_PER_INCH!r} D{d / _MM_PER_INCH!r} ;\n" for n, g, d in rows)


def _parameters(home: np.ndarray) -> str:
    """The parameter file: G54 active (5220 = 1) at minus the home (inches)."""
    g54 = -home / _MM_PER_INCH
    return "5220\t1\n" + "".join(f"{5221 + i}\t{float(v) + 0.0!r}\n" for i, v in enumerate(g54))


def _run(text: str, tools, home: np.ndarray, program: str, timeout_s: float | None) -> str:
    """rs274's canonical output for ``text``."""
    exe = shutil.which("rs274")
    if exe is None:
        raise Rs274Error(INSTALL_HINT, program=program)
    with tempfile.TemporaryDirectory(prefix="scanmill-rs274-") as tmp:
        d = Path(tmp)
        (d / "in.ngc").write_text(_numbered(text))
        (d / "tools.tbl").write_text(_tool_table(text, tools))
        (d / "params.var").write_text(_parameters(home))
        # rs274 keeps its tool table in a memory-mapped file, $HOME/.tool.mmap, shared by every rs274
        # running under that HOME: two at once read each other's tool lengths (seen as machine Z off by
        # the difference of two tests' gauge lengths, 13-14 mm). Each run gets its own HOME.
        env = {**os.environ, "HOME": str(d)}
        proc = subprocess.run([exe, "-t", "tools.tbl", "-v", "params.var", "-g", "in.ngc", "out.txt"], cwd=d, env=env,
                              stdin=subprocess.DEVNULL, capture_output=True, check=False, text=True, timeout=timeout_s)
        out = (d / "out.txt").read_text() if (d / "out.txt").is_file() else ""
    if proc.returncode != 0:
        msg = " ".join((proc.stdout + " " + proc.stderr).replace("executing", " ").split())
        raise Rs274Error(f"{program}: rs274 refused the program (exit {proc.returncode}): {msg}", program=program)
    return out


def _floats(args: str) -> list[float]:
    return [float(v) for v in re.findall(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?", args)]


class _Canon:
    """The canonical commands as moves of the machine (module docstring, Reading its output)."""

    def __init__(self, model: MachineModel, program: str, rotary_sign):
        self.model, self.program = model, program
        self.sign = None if rotary_sign is None else tuple(float(v) for v in rotary_sign)
        self.sign_source = "argument" if rotary_sign is not None else "default"
        self.g5x, self.g92 = (0.0,) * 6, (0.0,) * 6     # x y z a b c
        self.tool_z = (0.0,) * 3                        # tool length offset x y z
        self.axes = _PLANES["CANON_PLANE_XY"]
        self.tool = self.selected = 0
        self.mm = False
        # (line, kind, canonical xyz, canonical abc, linear offset (3), rotary offset (3), tool, arc or None)
        self.moves: list[tuple] = []
        names = model.profile.axis_names
        self.rot_index = ("ABC".index(names[0]), 2)

    def fail(self, line: int, message: str) -> Rs274Error:
        return Rs274Error(f"{self.program} line {line}: {message}", program=self.program, line=line)

    def command(self, line: int, name: str, args: str) -> None:
        if name in ("STRAIGHT_TRAVERSE", "STRAIGHT_FEED", "ARC_FEED"):
            if not self.mm:
                raise self.fail(line, "motion in inches: the reader takes millimetre programs (G21) only")
            self._motion(line, name, args)
        elif name == "USE_LENGTH_UNITS":
            self.mm = "CANON_UNITS_MM" in args
        elif name == "SET_G5X_OFFSET":
            self.g5x = tuple(_floats(args)[1:7])
        elif name == "SET_G92_OFFSET":
            self.g92 = tuple(_floats(args)[:6])
        elif name == "USE_TOOL_LENGTH_OFFSET":
            self.tool_z = tuple(_floats(args)[:3])
        elif name == "SELECT_TOOL":
            self.selected = int(_floats(args)[0])
        elif name == "CHANGE_TOOL":              # its argument is the tool table's slot: take the selected T
            self.tool = self.selected
        elif name == "SELECT_PLANE":
            if args.strip() not in _PLANES:
                raise self.fail(line, f"plane {args} is not in the subset")
            self.axes = _PLANES[args.strip()]
        elif name == "COMMENT":
            self._comment(args)
        elif name not in _IGNORED:
            raise self.fail(line, f"canonical command {name} is not in the subset")

    def _comment(self, args: str) -> None:
        m = _SIGNS.search(args)
        if m is None or self.sign_source == "argument":
            return
        got = {m.group(1).upper(): m.group(2).lower(), m.group(3).upper(): m.group(4).lower()}
        self.sign = tuple(-1.0 if got.get(a) == "flipped" else 1.0 for a in self.model.profile.axis_names)
        self.sign_source = "header comment"

    def _motion(self, line: int, name: str, args: str) -> None:
        try:
            v = [float(x) for x in args.split(",")]
        except ValueError:
            raise self.fail(line, f"cannot read {name}({args})") from None
        off = self.g5x + self.g92
        lin = (off[0] + self.tool_z[0], off[1] + self.tool_z[1], off[2] + self.tool_z[2])
        if name == "ARC_FEED":
            if len(v) < 9:
                raise self.fail(line, "ARC_FEED with too few arguments")
            ia, ib, inn = self.axes
            end, centre = [0.0] * 3, [0.0] * 3
            end[ia], end[ib], end[inn] = v[0], v[1], v[5]
            centre[ia], centre[ib] = v[2], v[3]
            arc = ([c + o for c, o in zip(centre, lin)], self.axes, int(v[4]))
            self.moves.append((line, FEED, end, v[6:9], lin, off[3:6], self.tool, arc))
            return
        if len(v) < 6:
            raise self.fail(line, f"{name} with too few arguments")
        kind = RAPID if name == "STRAIGHT_TRAVERSE" else FEED
        self.moves.append((line, kind, v[:3], v[3:6], lin, off[3:6], self.tool, None))


def _angles(canon: _Canon) -> np.ndarray:
    """(m,2) planner angles (tilt, rotary) at the end of each move."""
    words = np.array([mv[3] for mv in canon.moves], dtype=np.float64).reshape(-1, 3)
    words += np.array([mv[5] for mv in canon.moves], dtype=np.float64).reshape(-1, 3)
    ti = canon.rot_index[0]
    other = [j for j in range(3) if j not in (ti, 2)]
    moved = np.flatnonzero(np.any(np.abs(words[:, other]) > 1e-9, axis=1))
    if moved.size:
        name = "ABC"[other[0]]
        raise canon.fail(canon.moves[int(moved[0])][0], f"{name} moves, which {canon.model.profile.kinematics} lacks")
    s = canon.sign or (1.0, 1.0)
    return np.stack([words[:, ti] * s[0], words[:, 2] * s[1]], axis=1)


def _steps(canon: _Canon, tol: float, step_deg: float):
    """``(owner, q0, q1, b0, b1)``: every move as steps (rotary turns) or chords (arcs), in order."""
    mv = canon.moves
    m = len(mv)
    p1 = np.array([x[2] for x in mv]).reshape(m, 3) + np.array([x[4] for x in mv]).reshape(m, 3) + canon.model.home
    a1 = _angles(canon)
    p0 = np.vstack([canon.model.home[None, :], p1[:-1]])
    a0 = np.vstack([np.zeros((1, 2)), a1[:-1]])
    is_arc = np.array([x[7] is not None for x in mv], dtype=bool)
    S, A = np.flatnonzero(~is_arc), np.flatnonzero(is_arc)
    own_s, q0s, q1s, b0s, b1s = interpolate_moves(p0[S], p1[S], a0[S], a1[S], step_deg)
    turning = A[np.any(np.abs(a1[A] - a0[A]) > 1e-12, axis=1)]
    if turning.size:
        raise canon.fail(mv[int(turning[0])][0], "an arc with rotary motion is not in the subset")
    centre = np.array([mv[i][7][0] for i in A]).reshape(-1, 3) + canon.model.home
    axes = np.array([mv[i][7][1] for i in A], dtype=np.int64).reshape(-1, 3)
    turns = np.array([mv[i][7][2] for i in A], dtype=np.int64)
    own_a, pts = arc_chords(p0[A], p1[A], centre, axes, turns, tol)
    counts = np.zeros(m, dtype=np.int64)
    counts[S] = np.bincount(own_s, minlength=S.size)
    counts[A] = np.bincount(own_a, minlength=A.size)
    first = np.cumsum(counts) - counts
    N = int(counts.sum())
    q0, q1, b0, b1 = np.empty((N, 3)), np.empty((N, 3)), np.empty((N, 2)), np.empty((N, 2))
    ks = first[S][own_s] + np.arange(own_s.size) - (np.cumsum(counts[S]) - counts[S])[own_s]
    q0[ks], q1[ks], b0[ks], b1[ks] = q0s, q1s, b0s, b1s
    ka = first[A][own_a] + np.arange(own_a.size) - (np.cumsum(counts[A]) - counts[A])[own_a]
    q1[ka] = pts
    is_first = ka == first[A][own_a]
    q0[ka] = np.where(is_first[:, None], p0[A][own_a], np.roll(pts, 1, axis=0))
    b0[ka] = b1[ka] = a1[A][own_a]
    return np.repeat(np.arange(m), counts), q0, q1, b0, b1


def _motion(canon: _Canon, *, program: str, area: int, tools, tol: float, step_deg: float) -> ProgramMotion:
    """The moves of ``canon`` as :class:`ProgramMotion`."""
    model, mv = canon.model, canon.moves
    if not mv:
        z3 = np.zeros((0, 3))
        return ProgramMotion(program=program, area=area, line=np.zeros(0, np.int64), kind=np.zeros(0, np.int8),
                             tool=np.zeros(0, np.int64), start_mm=z3, end_mm=z3.copy(), axis=z3.copy(),
                             machine_mm=z3.copy(), rotary_deg=np.zeros((0, 2)), notes=[])
    owner, q0, q1, b0, b1 = _steps(canon, tol, step_deg)
    tool = np.array([x[6] for x in mv], dtype=np.int64)[owner]
    gauge = np.zeros(tool.shape)
    if tools is not None:
        for t in np.unique(tool):
            if t != 0 and int(t) not in tools:
                raise canon.fail(mv[int(owner[np.argmax(tool == t)])][0], f"tool T{t} is not among the tools given")
            gauge[tool == t] = 0.0 if t == 0 else float(tools[int(t)].gauge_length_mm)
    t0, _ = model.tip_from_machine(q0, b0, gauge)
    t1, axis = model.tip_from_machine(q1, b1, gauge)
    line = np.array([x[0] for x in mv], dtype=np.int64)[owner]
    kind = np.array([x[1] for x in mv], dtype=np.int8)[owner]
    return ProgramMotion(program=program, area=area, line=line, kind=kind, tool=tool, start_mm=t0, end_mm=t1,
                         axis=axis, machine_mm=q1, rotary_deg=b1, notes=[])


def _read_output(out: str, canon: _Canon, program: str) -> None:
    """Feed every canonical command of rs274's output to ``canon``, with its 1-based program line."""
    for raw in out.splitlines():
        m = _OUT_LINE.match(raw)
        if m is None:
            if raw.strip():
                raise Rs274Error(f"{program}: cannot read rs274's output line {raw!r}", program=program)
            continue
        n, name, args = m.groups()
        if n.startswith(".") and name in ("STRAIGHT_TRAVERSE", "STRAIGHT_FEED", "ARC_FEED"):
            raise Rs274Error(f"{program}: rs274 printed a move without a block number", program=program)
        canon.command(0 if n.startswith(".") else int(n), name, args)


def run_rs274(text: str, *, program: str, area: int, profile, placement_mm, tools: dict | None = None,
              chord_tol_mm: float = 0.005, rotary_step_deg: float = 1.0, rotary_sign=None,
              timeout_s: float | None = None) -> ProgramMotion:
    """Run a LinuxCNC-dialect program through LinuxCNC's ``rs274`` and return its moves in the part frame.

    Arguments and result as :func:`planning.simulate.program.read_program` (``dialect="linuxcnc"``):
    ``profile`` / ``placement_mm`` the machine and the part on it (mm); ``tools`` ``{T: ToolShape}``
    whose ``gauge_length_mm`` fill rs274's tool table (None: lengths 0); ``chord_tol_mm`` (mm) and
    ``rotary_step_deg`` (deg) split arcs and rotary turns the same way; ``rotary_sign`` the printed
    rotary words' signs (None: the header comment, else (1, 1)). ``line`` is the 1-based program
    line of the canonical command (from the ``N`` numbers this function adds). ``timeout_s``: limit
    on rs274's run, seconds (None: none). Raises :class:`Rs274Error` when rs274 is missing (the
    message says how to install it: ``apt-get install linuxcnc-uspace``), refuses the program, or
    prints a canonical command outside the subset.
    """
    model = MachineModel(profile, placement_mm)
    out = _run(text, tools, model.home, program, timeout_s)
    canon = _Canon(model, program, rotary_sign)
    _read_output(out, canon, program)
    motion = _motion(canon, program=program, area=int(area), tools=tools, tol=float(chord_tol_mm),
                     step_deg=float(rotary_step_deg))
    s = canon.sign or (1.0, 1.0)
    names = model.profile.axis_names
    motion.notes = [HOME_NOTE, (f"rs274 (LinuxCNC's interpreter) read the program; rotary words = planner angles "
                                f"x sign ({names[0]} {s[0]:+g}, {names[1]} {s[1]:+g}, from the {canon.sign_source})")]
    if tools is None:
        motion.notes.append("no tools given: every tool length taken as 0")
    return motion
