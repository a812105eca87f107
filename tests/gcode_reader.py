"""A small, strict G-code interpreter for the post-processor tests (no import from ``planning``).

It reads the subset the scanmill posts emit and returns every motion as a tool-tip position in the
PART frame, undoing what the program does:

* comments ``( ... )`` and ``; ...``, ``%`` lines, ``O`` program numbers, ``N`` line numbers;
* modal ``G0 G1 G2 G3``, planes ``G17 G18 G19``, ``G90``/``G91`` (G91 only with G28), ``G21``,
  ``G94``, ``G40``, ``G80``, ``G54``, ``G64 P``; ``G43 H`` / ``G49``; ``F S T M``;
* ``G28`` (reference return) and ``G53`` (machine coordinates): the position becomes unknown and
  no tip is recorded;
* ISO mode (``machine=None``): G54 is the part frame; ``G68.2 X Y Z I J K`` sets a feature frame,
  ``q_part = Rz(I) Rx(J) Rz(K) q + (X, Y, Z)`` (Fanuc: rotate about Z, then the new X, then the new
  Z); ``G53.1`` must follow before any motion; ``G69`` cancels it; motion needs G43 (tip);
* machine mode (``machine=Machine(...)``): ``A``/``B``/``C`` words position the rotary axes (signs
  flipped back where the machine says so), X Y Z are in the machine frame and are mapped back:
  table-table ``p = M^T (X - (I - R_tilt) P) - placement`` with ``M = R_tilt(tilt) Rz(C)`` (needs
  G43); head-head ``p = X - (G + L) t - placement`` with ``t = Rz(C) R_tilt(tilt) +Z`` (needs G49).

Arcs are returned with their end point, centre (in-plane offsets from the start, the normal
coordinate of the start), direction and plane, the plane's normal in the part frame and the start
and end radii. Anything outside the subset raises :class:`ReaderError`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

PLANE_AXES = {17: (0, 1, 2), 18: (2, 0, 1), 19: (1, 2, 0)}

_WORD = re.compile(r"([A-Z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")


class ReaderError(ValueError):
    pass


def rx(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def ry(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def rz(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


@dataclass
class Machine:
    """What the reader needs to undo a machine-frame (LinuxCNC) program."""

    kinematics: str                      # table_table_ac / _bc, head_head_ac / _bc
    placement_mm: tuple
    pivot_mm: tuple = (0.0, 0.0, 0.0)    # table-table: a point of the tilt axis
    head_pivot_length_mm: float = 0.0    # head-head: gauge line to rotation centre
    gauge_length_mm: dict = field(default_factory=dict)   # head-head: by tool number
    flip_tilt: bool = False
    flip_rotary: bool = False

    @property
    def tilt_letter(self) -> str:
        return self.kinematics[-2].upper()

    @property
    def table(self) -> bool:
        return self.kinematics.startswith("table_table")

    def r_tilt(self, tilt_deg: float) -> np.ndarray:
        return rx(tilt_deg) if self.tilt_letter == "A" else ry(tilt_deg)


@dataclass
class Move:
    line: int                  # 1-based line of the program text
    kind: str                  # "rapid" | "feed" | "arc"
    end: np.ndarray            # tool tip, part frame, mm
    prog_end: np.ndarray       # X Y Z as programmed (after modal fill)
    feed: float | None
    segment: int               # number of tool changes (M6) before this move
    tool: int | None
    centre: np.ndarray | None = None     # arcs: part frame
    direction: str | None = None         # arcs: "cw" | "ccw"
    plane: int | None = None             # arcs: programmed plane 17/18/19
    normal: np.ndarray | None = None     # arcs: the programmed plane's normal in the part frame
    radius_start: float = math.nan
    radius_end: float = math.nan


@dataclass
class Program:
    moves: list = field(default_factory=list)
    blocks: list = field(default_factory=list)          # (line, code text without comments)
    comments: list = field(default_factory=list)
    g68: list = field(default_factory=list)              # (line, origin (3,), (I, J, K))
    rotary: list = field(default_factory=list)           # (line, {letter: word value})
    program_number: int | None = None
    ended: bool = False


def _gkey(v: str) -> str:
    f = float(v)
    return f"{f:g}"


def read_program(text: str, machine: Machine | None = None) -> Program:
    prog = Program()
    pos = np.full(3, np.nan)
    motion = None
    plane = 17
    absolute = True
    feed = None
    tlc = "G49"
    h = None
    frame = None                # (R, origin) of G68.2
    oriented = False
    angles = {"tilt": 0.0, "rotary": 0.0}
    t_word = None
    tool = None
    segment = 0

    def linear_and_offset():
        """(L, f) with part = L @ X + f for the current state."""
        if machine is None:
            if tlc != "G43":
                raise ReaderError("motion without tool length compensation G43")
            if frame is None:
                return np.eye(3), np.zeros(3)
            if not oriented:
                raise ReaderError("motion in a G68.2 plane before G53.1")
            return frame
        place = np.asarray(machine.placement_mm, dtype=float)
        Rt = machine.r_tilt(angles["tilt"])
        if machine.table:
            if tlc != "G43":
                raise ReaderError("table-table motion without G43")
            M = Rt @ rz(angles["rotary"])
            P = np.asarray(machine.pivot_mm, dtype=float)
            off = (np.eye(3) - Rt) @ P
            return M.T, -M.T @ off - place
        if tlc == "G43":
            raise ReaderError("head-head program must not use G43")
        t = rz(angles["rotary"]) @ Rt @ np.array([0.0, 0.0, 1.0])
        G = machine.gauge_length_mm[tool]
        return np.eye(3), -(G + machine.head_pivot_length_mm) * t - place

    for ln, raw in enumerate(text.splitlines(), start=1):
        s = raw.strip()
        if not s or s == "%":
            continue
        prog.comments.extend(re.findall(r"\(([^)]*)\)", s))
        code = re.sub(r"\([^)]*\)", " ", s)
        if "(" in code or ")" in code:
            raise ReaderError(f"line {ln}: unbalanced parentheses")
        code = code.split(";", 1)[0].strip().upper()
        if not code:
            continue
        words = _WORD.findall(code)
        if _WORD.sub("", code).strip():
            raise ReaderError(f"line {ln}: cannot parse {code!r}")
        if prog.ended:
            raise ReaderError(f"line {ln}: blocks after M30")
        prog.blocks.append((ln, code))
        gs = [_gkey(v) for k, v in words if k == "G"]
        ms = [int(float(v)) for k, v in words if k == "M"]
        vals: dict = {}
        for k, v in words:
            if k in ("G", "M", "N"):
                continue
            if k in vals:
                raise ReaderError(f"line {ln}: word {k} twice")
            vals[k] = float(v)
        if "O" in vals:
            prog.program_number = int(vals.pop("O"))
        known = {"0", "1", "2", "3", "17", "18", "19", "21", "90", "91", "94", "40", "49", "43", "80", "54",
                 "28", "53", "68.2", "69", "53.1", "64"}
        for g in gs:
            if g not in known:
                raise ReaderError(f"line {ln}: G{g} is not in the subset")
        # --- settings, in execution order
        if "F" in vals:
            feed = vals.pop("F")
        if "S" in vals:
            vals.pop("S")
        if "T" in vals:
            t_word = int(vals.pop("T"))
        if "P" in vals and "64" in gs:
            vals.pop("P")
        for g in gs:
            if g in ("17", "18", "19"):
                plane = int(g)
            elif g == "90":
                absolute = True
            elif g == "91":
                absolute = False
            elif g == "49":
                tlc = "G49"
            elif g == "43":
                if "H" not in vals:
                    raise ReaderError(f"line {ln}: G43 without H")
                h = int(vals.pop("H"))
                if h != tool:
                    raise ReaderError(f"line {ln}: G43 H{h} but tool {tool} is in the spindle")
                tlc = "G43"
            elif g == "69":
                frame, oriented = None, False
        for m in ms:
            if m == 6:
                if t_word is None:
                    raise ReaderError(f"line {ln}: M6 without T")
                tool = t_word
                segment += 1
            elif m == 30 or m == 2:
                prog.ended = True
            elif m not in (3, 4, 5, 8, 9):
                raise ReaderError(f"line {ln}: M{m} is not in the subset")
        if "68.2" in gs:
            if machine is not None:
                raise ReaderError(f"line {ln}: G68.2 in a machine-frame program")
            try:
                o = np.array([vals.pop(k) for k in "XYZ"])
                ijk = tuple(vals.pop(k) for k in "IJK")
            except KeyError:
                raise ReaderError(f"line {ln}: G68.2 needs X Y Z I J K") from None
            R = rz(ijk[0]) @ rx(ijk[1]) @ rz(ijk[2])
            frame, oriented = (R, o), False
            prog.g68.append((ln, o, ijk))
            pos = np.full(3, np.nan)
        if "53.1" in gs:
            if frame is None:
                raise ReaderError(f"line {ln}: G53.1 without G68.2")
            oriented = True
        for g in gs:
            if g in ("0", "1", "2", "3"):
                motion = g
        if "28" in gs:
            if absolute:
                raise ReaderError(f"line {ln}: G28 is expected with G91")
            for k in "XYZ":
                vals.pop(k, None)
            pos = np.full(3, np.nan)
            continue
        if "53" in gs:
            if motion != "0":
                raise ReaderError(f"line {ln}: G53 only with G0")
            for k in "XYZ":
                vals.pop(k, None)
            pos = np.full(3, np.nan)
            continue
        rot_words = {k: vals.pop(k) for k in "ABC" if k in vals}
        if rot_words:
            if machine is None:
                raise ReaderError(f"line {ln}: rotary words in a tilted-plane program")
            if any(k in vals for k in "XYZ"):
                raise ReaderError(f"line {ln}: rotary and linear motion in one block")
            for k, v in rot_words.items():
                if k == "C":
                    angles["rotary"] = -v if machine.flip_rotary else v
                elif k == machine.tilt_letter:
                    angles["tilt"] = -v if machine.flip_tilt else v
                else:
                    raise ReaderError(f"line {ln}: {k} is not an axis of {machine.kinematics}")
            prog.rotary.append((ln, rot_words))
            continue
        has_xyz = any(k in vals for k in "XYZ")
        has_ijk = any(k in vals for k in "IJK")
        if not has_xyz and not has_ijk:
            if vals:
                raise ReaderError(f"line {ln}: unused words {sorted(vals)}")
            continue
        if not absolute:
            raise ReaderError(f"line {ln}: incremental motion is not in the subset")
        if motion is None:
            raise ReaderError(f"line {ln}: coordinates without a motion mode")
        start = pos.copy()
        end = pos.copy()
        for i, k in enumerate("XYZ"):
            if k in vals:
                end[i] = vals.pop(k)
        if not np.all(np.isfinite(end)):
            raise ReaderError(f"line {ln}: the position is not fully known after a reference return")
        L, f = linear_and_offset()
        mv = Move(line=ln, kind={"0": "rapid", "1": "feed"}.get(motion, "arc"), end=L @ end + f,
                  prog_end=end.copy(), feed=None if motion == "0" else feed, segment=segment, tool=tool)
        if motion in ("1", "2", "3") and feed is None:
            raise ReaderError(f"line {ln}: feed move without F")
        if motion in ("2", "3"):
            if not np.all(np.isfinite(start)):
                raise ReaderError(f"line {ln}: arc from an unknown position")
            a, b, n = PLANE_AXES[plane]
            off = np.zeros(3)
            for i, k in enumerate("IJK"):
                if k in vals:
                    if i == n:
                        raise ReaderError(f"line {ln}: {k} is not in the plane G{plane}")
                    off[i] = vals.pop(k)
            c = start.copy()
            c[a] += off[a]
            c[b] += off[b]
            mv.centre = L @ c + f
            mv.direction = "ccw" if motion == "3" else "cw"
            mv.plane = plane
            e_n = np.zeros(3)
            e_n[n] = 1.0
            mv.normal = L @ e_n
            mv.radius_start = math.hypot(start[a] - c[a], start[b] - c[b])
            mv.radius_end = math.hypot(end[a] - c[a], end[b] - c[b])
        elif has_ijk:
            raise ReaderError(f"line {ln}: I J K on a straight move")
        if vals:
            raise ReaderError(f"line {ln}: unused words {sorted(vals)}")
        pos = end
        prog.moves.append(mv)
    return prog
