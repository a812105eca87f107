"""Read a posted NC program back as a control would run it (issue 15): every move of the tool tip in
the PART frame, with its tool axis and where the machine's axes are (:class:`ProgramMotion`).

The reader interprets the program TEXT block by block (not the planner's move list), for the
subset the posts emit (:mod:`planning.post.iso`, :mod:`planning.post.linuxcnc` and the simultaneous
5-axis posts of :mod:`planning.post.simultaneous`); anything else raises :class:`ProgramError`
naming the line. It tokenises the whole text at once and runs the plain motion blocks (``G0 G1 G2
G3 G17 G18 G19 X Y Z I J K F``) between two other blocks as whole arrays; the other blocks are
interpreted one by one, and the moves of the axes they command are split into their steps together,
as whole arrays, before the next plain motion block.

Words (both dialects)
---------------------
Comments ``( ... )`` (LinuxCNC also ``; ...``), ``%`` lines, ``N`` numbers, ``O`` numbers (ISO);
modal ``G0 G1 G2 G3``, ``G17 G18 G19``, ``G90`` (``G91`` only with ``G28``), ``G21`` (``G20``
raises: millimetres only), ``G40 G49 G54 G64 [P] G80 G94``, ``G43 H`` (tool length offset =
``tools[H].gauge_length_mm``: the tool table holds the gauge lengths, so programmed points are
tool-tip positions), ``F S T M6 M3 M4 M5 M7 M8 M9 M30 M2``. ``G2``/``G3``: centre as ``I J K``
offsets from the start in the active plane (ISO 6983: counter-clockwise seen from the positive end
of the plane's normal; ``G18`` is the Z-X plane), split into chords no farther than
``chord_tol_mm`` from the arc (a start and end radius that differ give a spiral, as LinuxCNC;
more than 0.002 mm and 0.1 % apart raises). ``G64 P`` blending is not simulated (the programmed
path is followed).

``G53`` (machine coordinates, with ``G0``/``G1``) and the machine home: see
:mod:`planning.simulate.kinematics` (:data:`~planning.simulate.kinematics.HOME_NOTE`): ``G53 X0 Y0
Z0`` is the controlled point at the centre of the X/Y limits and the TOP of the Z travel
(``z_limits_mm[1]``), whatever tool offset is active; a program starts there with the rotary axes
at 0. A G53 move is a real (straight, machine-frame) move; rotary words in it (the profile's
letters, printed signs as below) put those axes at that machine angle, all axes moving together
(``G53 G0 B0 C0``: the rotary axes home, as the LinuxCNC programs end).

ISO / Fanuc (``dialect="iso"``)
-------------------------------
``G54`` is the PART frame (as :mod:`planning.post.iso` assumes): its origin is the part origin,
which sits at ``placement_mm`` in the table frame, axes parallel to the machine's with the rotary
axes at 0; on a table-table machine it turns with the table. ``G68.2 X Y Z I J K`` (Fanuc's
definition): the feature frame's origin is ``(X, Y, Z)`` in G54 and its axes are the columns of
``R = Rz(I) Rx(J) Rz(K)`` (rotate about Z by I, then about the NEW X by J, then the NEW Z by K;
degrees; omitted words are 0); ``G53.1`` turns the rotary axes so that the tool lies along the
feature +Z, the linear axes standing still (the rotary solution: the planner's rule,
:meth:`~planning.simulate.kinematics.MachineModel.orient`); ``G69`` cancels the feature frame (the
rotary axes stay). With ``G43 H`` active, ``X Y Z`` are the tool tip in the feature frame (in G54
when no G68.2 is active, which needs the rotary axes at 0). ``G91 G28 X0 / Y0 / Z0`` and the
profile's rotary letters (``G91 G28 B0. C0.``, as the ISO programs end): rapid of the named axes to
the reference point (= machine home; the rotary axes at 0).

``G43.4 H`` (tool centre point control, "type 1", as :mod:`planning.post.simultaneous` assumes): the
length offset of tool H as with ``G43``, and the programmed ``X Y Z`` are the tool TIP in G54 = the
part frame whatever the rotary axes are (no G68.2 plane may be active: G68.2 under G43.4 and
G43.4 under G68.2 raise). ``G0``/``G1`` blocks may then carry the profile's rotary words (planner
angles, no sign change): the tip moves STRAIGHT in the part frame while the angles move linearly,
split into steps of at most ``rotary_step_deg`` (tip and angles interpolated linearly, the machine
position of each step end :meth:`~planning.simulate.kinematics.MachineModel.machine_from_tip`, for
the travel check). ``G49`` (or ``G43``) cancels it. Rotary words without G43.4 are not in this subset
(G53.1 turns the rotary axes in a G68.2 plane; ``G53 G0 B.. C..`` positions them in machine
coordinates, as above).

LinuxCNC (``dialect="linuxcnc"``)
---------------------------------
``G54`` is the machine frame (:mod:`planning.post.linuxcnc`). ``A``/``B``/``C`` words position the
machine's rotary axes (the profile's tilt letter and C), moving together with any ``X Y Z`` of the
block in ``G0`` or ``G1`` (trivial kinematics: every axis linear in joint space, as the
simultaneous 5-axis programs move); the printed values are the planner's angles times
``rotary_sign`` (read from the post's header comment ``signs: B flipped, C as planned`` unless
given). ``X Y Z`` are the machine position of the controlled point less the active length offset
along machine Z: with ``G43 H`` on a table-table machine the tool tip, with ``G49`` on a head-head
machine the head's rotation centre. A move that turns the rotary axes is split into steps of at most
``rotary_step_deg`` (RAPID for G0, FEED for G1), each with the tool axis at its end. ``G93``
(inverse-time feed: ``F`` = 1 / the move's time in minutes) needs an ``F`` word on every feed block,
as LinuxCNC does; ``G94`` returns to mm/min. A change of feed mode forgets the feed rate (a feed
move then needs a new ``F``). Feed rates are checked, not simulated.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from planning.errors import PlanningError
from planning.simulate.kinematics import (
    HOME_NOTE,
    MachineModel,
    arc_chords,
    interpolate_moves,
)
from planning.simulate.motion import FEED, RAPID, ProgramMotion

__all__ = ["DIALECTS", "ProgramError", "check_travel", "read_program"]

DIALECTS = ("iso", "linuxcnc")

#: G codes (x10, so that G53.1 is 531) each dialect accepts.
_G_COMMON = {0, 10, 20, 30, 170, 180, 190, 200, 210, 400, 430, 490, 530, 540, 640, 800, 900, 910, 940}
_G_ISO = _G_COMMON | {280, 434, 531, 682, 690}
_G_LINUXCNC = _G_COMMON | {930}
_G_GROUPS = ({0, 10, 20, 30}, {170, 180, 190}, {200, 210}, {430, 434, 490}, {900, 910}, {682, 690}, {930, 940})
_M_ALLOWED = {2, 3, 4, 5, 6, 7, 8, 9, 30}
_PLANE_AXES = {17: (0, 1, 2), 18: (2, 0, 1), 19: (1, 2, 0)}

# Arcs whose start and end radii differ by more than both of these raise.
_ARC_RADIUS_ABS_MM, _ARC_RADIUS_REL = 0.002, 0.001

_NUM = rb"[-+]?+(?:\d++(?:\.\d*+)?+|\.\d++)"
_LINE = rb"[ \t]*+(?:%[ \t]*+|(?:[A-Z][ \t]*+" + _NUM + rb"[ \t]*+)*+)\r?"
_VALID = re.compile(rb"(?:" + _LINE + rb"\n)*+" + _LINE)
_VALID_LINE = re.compile(_LINE)
_COMMENT = re.compile(rb"\([^()\n]*\)")
_SEMICOLON = re.compile(rb";[^\n]*")
_BLANK_LETTERS = bytes(32 if 65 <= c <= 90 or c == 37 else c for c in range(256))
_SIGNS = re.compile(r"signs:\s*([ABC])\s+(flipped|as planned)\s*,\s*([ABC])\s+(flipped|as planned)",
                    re.IGNORECASE)


_NO_INVERSE_F = "inverse-time feed (G93): every feed move needs its own F word"


class ProgramError(PlanningError):
    """A program the reader cannot run: outside the subset, or not what a control accepts."""

    code = "nc_program_error"
    status = 422


# ------------------------------------------------------------------------------------------------
# the text as arrays


@dataclass
class _Text:
    """The program's words: per token (letter, value, 0-based line), per line the plain motion words."""

    n_lines: int
    letter: np.ndarray      # (T,) uint8
    value: np.ndarray       # (T,) float64
    line: np.ndarray        # (T,) int64, ascending
    xyz: np.ndarray         # (n,3) NaN where absent
    ijk: np.ndarray         # (n,3)
    feed: np.ndarray        # (n,)
    motion: np.ndarray      # (n,) float: 0..3 or NaN
    plane: np.ndarray       # (n,) float: 17..19 or NaN
    control: np.ndarray     # 0-based lines with any other word, ascending


def _fail(program: str, line: int, message: str) -> ProgramError:
    return ProgramError(f"{program} line {line}: {message}", program=program, line=line)


def _clean(text: str, dialect: str, program: str) -> bytes:
    """The text as upper-case bytes without comments, checked to be words ``<letter><number>``."""
    data = _COMMENT.sub(b" ", text.encode("utf-8"))
    if dialect == "linuxcnc":
        data = _SEMICOLON.sub(b"", data)
    data = data.upper()
    if _VALID.fullmatch(data) is None:
        for ln, raw in enumerate(data.split(b"\n"), start=1):
            if _VALID_LINE.fullmatch(raw) is None:
                why = "unbalanced parentheses" if (b"(" in raw or b")" in raw) else "cannot parse"
                raise _fail(program, ln, f"{why}: {raw.decode('utf-8', 'replace').strip()!r}")
    return data


def _tokens(data: bytes, program: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """``(letter, value, line, n_lines)`` of every word of the cleaned text."""
    arr = np.frombuffer(data, dtype=np.uint8)
    pos = np.flatnonzero((arr >= 65) & (arr <= 90))
    line = np.cumsum(arr == 10)[pos] if pos.size else np.zeros(0, np.int64)
    letter = arr[pos]
    value = np.fromstring(data.translate(_BLANK_LETTERS), sep=" ") if pos.size else np.zeros(0)
    if value.shape != letter.shape:                              # pragma: no cover - the check above
        raise ProgramError(f"{program}: the words could not be read", program=program)
    return letter, value, line.astype(np.int64), data.count(b"\n") + 1


def _per_line(n: int, letter, value, line, ch: str, program: str) -> np.ndarray:
    """(n,) the value of word ``ch`` on each line (NaN where absent)."""
    out = np.full(n, np.nan)
    m = letter == ord(ch)
    out[line[m]] = value[m]
    return out


def _tokenise(text: str, dialect: str, program: str) -> _Text:
    """The program text as :class:`_Text` (one pass of regular expressions, then numpy)."""
    letter, value, line, n = _tokens(_clean(text, dialect, program), program)
    is_g, is_m = letter == ord("G"), letter == ord("M")
    key = np.sort(line[~(is_g | is_m)] * 32 + (letter[~(is_g | is_m)] - 64))
    dup = np.flatnonzero(key[1:] == key[:-1])
    if dup.size:
        k = int(key[dup[0]])
        raise _fail(program, k // 32 + 1, f"word {chr(k % 32 + 64)} twice in one block")
    g10 = np.where(is_g, np.rint(value * 10.0), -1.0)
    bad = is_g & (np.abs(value * 10.0 - g10) > 1e-6)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise _fail(program, int(line[i]) + 1, f"G{value[i]:g} is not in the subset")
    g_mot = is_g & np.isin(g10, (0, 10, 20, 30))
    g_pl = is_g & np.isin(g10, (170, 180, 190))
    for m, what in ((g_mot, "motion"), (g_pl, "plane")):
        twice = np.flatnonzero(np.bincount(line[m], minlength=n) > 1)
        if twice.size:
            raise _fail(program, int(twice[0]) + 1, f"two {what} G codes in one block")
    simple = g_mot | g_pl | np.isin(letter, np.frombuffer(b"XYZIJKFN", np.uint8))
    motion = np.full(n, np.nan)
    motion[line[g_mot]] = g10[g_mot] / 10.0
    plane = np.full(n, np.nan)
    plane[line[g_pl]] = g10[g_pl] / 10.0
    cols = {c: _per_line(n, letter, value, line, c, program) for c in "XYZIJKF"}
    return _Text(n_lines=n, letter=letter, value=value, line=line,
                 xyz=np.stack([cols["X"], cols["Y"], cols["Z"]], 1),
                 ijk=np.stack([cols["I"], cols["J"], cols["K"]], 1), feed=cols["F"],
                 motion=motion, plane=plane, control=np.unique(line[~simple]))


def _line_feeds(T: _Text) -> np.ndarray:
    """(n_lines,) the modal F word in force on each line (NaN before the first): what a feed move of
    that line runs at (mm/min, or 1 / its time in minutes under G93)."""
    return _ffill(T.feed[:, None], [math.nan])[:, 0]


def _line_inverse_time(T: _Text) -> np.ndarray:
    """(n_lines,) bool: G93 (inverse-time feed) in force on each line (G94 restores mm/min)."""
    is_g = T.letter == ord("G")
    g10 = np.rint(T.value * 10.0)
    mode = np.full(T.n_lines, np.nan)
    for code, val in ((930, 1.0), (940, 0.0)):
        m = is_g & (g10 == code)
        mode[T.line[m]] = val
    return _ffill(mode[:, None], [0.0])[:, 0] > 0.5


def _ffill(rows: np.ndarray, init) -> np.ndarray:
    """Modal fill: each NaN of ``rows`` (k,d) takes the last value above it, the first ones ``init`` (d,)."""
    full = np.vstack([np.asarray(init, dtype=np.float64).reshape(1, -1), rows])
    idx = np.where(np.isnan(full), 0, np.arange(full.shape[0])[:, None])
    np.maximum.accumulate(idx, axis=0, out=idx)
    return np.take_along_axis(full, idx, axis=0)[1:]


def _rz(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rx(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _header_rotary_sign(text: str, profile_axes: tuple[str, str]) -> tuple[float, float] | None:
    """The ``(tilt_sign, rotary_sign)`` a LinuxCNC post printed in its header comment
    (``signs: B flipped, C as planned``), or None when the comment is absent."""
    m = _SIGNS.search(text[:20000])
    if m is None:
        return None
    got = {m.group(1).upper(): m.group(2).lower(), m.group(3).upper(): m.group(4).lower()}
    return tuple(-1.0 if got.get(a) == "flipped" else 1.0 for a in profile_axes)


# ------------------------------------------------------------------------------------------------
# the interpreter


@dataclass
class _State:
    """Where the machine is and the modal state of the program."""

    mpos: np.ndarray                 # controlled point, machine frame, mm
    ang: np.ndarray                  # (tilt, rotary), planner signs, deg
    tool: int = 0                    # T in the spindle
    t_word: int | None = None        # last T word
    tlc: bool = False                # G43 / G43.4 active
    tcp: bool = False                # ISO G43.4 (tool centre point control) active
    inverse_time: bool = False       # LinuxCNC G93: F = 1 / move time (min)
    f_word: bool = False             # the block being interpreted has an F word
    h_tool: int = 0                  # the tool whose length G43 applies
    motion: float = math.nan         # modal 0..3
    plane: float = 17.0
    feed: float = math.nan
    absolute: bool = True
    frame: tuple | None = None       # ISO G68.2: (R (3,3), origin (3,)), part frame
    oriented: bool = False           # ISO: G53.1 after the G68.2
    ended: bool = False


class _Reader:
    """One program's interpretation (:func:`read_program`)."""

    def __init__(self, text, dialect, program, area, profile, placement_mm, tools, chord_tol_mm, rotary_step_deg,
                 rotary_sign):
        if dialect not in DIALECTS:
            raise ProgramError(f"{program}: dialect {dialect!r} is not one of {', '.join(DIALECTS)}", program=program)
        if not (chord_tol_mm > 0 and rotary_step_deg > 0):
            raise ProgramError("chord_tol_mm and rotary_step_deg must be > 0", program=program)
        self.iso = dialect == "iso"
        self.program, self.area = program, int(area)
        self.model = MachineModel(profile, placement_mm)
        self.tools = tools
        self.tol, self.step = float(chord_tol_mm), float(rotary_step_deg)
        self.notes = [HOME_NOTE, self._tool_note()]
        self.sign = self._signs(text, rotary_sign)
        self.t = _tokenise(text, dialect, program)
        self.st = _State(mpos=self.model.home.copy(), ang=np.zeros(2))
        self.chunks: list[tuple] = []
        # machine / TCP moves not yet split into steps: interpolated together by _flush (whole arrays)
        self.pending: list[tuple] = []
        self.tcp_at: tuple | None = None      # (programmed point, the st.mpos object, (g, off)) after a TCP move

    def _tool_note(self) -> str:
        if self.tools is None:
            return ("no tools given: every gauge length taken as 0 (G43 offsets nothing; machine positions are those "
                    "of the tool tip)")
        return "G43 H<n> offsets by tools[n].gauge_length_mm: the control's tool table holds the gauge lengths"

    def _signs(self, text: str, rotary_sign) -> tuple[float, float]:
        p = self.model.profile
        if self.iso:
            self.notes.append("ISO: G54 = the part frame, its origin at placement_mm on the table, axes parallel to "
                              "the machine's with the rotary axes at 0; G68.2 = Fanuc Euler Z-X'-Z'' "
                              "R = Rz(I) Rx(J) Rz(K); G53.1 takes the planner's rotary solution")
            return (1.0, 1.0)
        head = _header_rotary_sign(text, p.axis_names)
        src = "argument" if rotary_sign is not None else ("header comment" if head is not None else "default")
        s = tuple(float(v) for v in (rotary_sign if rotary_sign is not None else head or (1.0, 1.0)))
        self.notes.append(f"LinuxCNC: G54 = the machine frame (table-top centre on the C axis, rotary axes at 0); "
                          f"rotary words = planner angles x sign ({p.axis_names[0]} {s[0]:+g}, "
                          f"{p.axis_names[1]} {s[1]:+g}, from the {src}); G64 P blending is not simulated")
        return s

    def fail(self, line: int, message: str) -> ProgramError:
        return _fail(self.program, int(line), message)

    def gauge(self, tool: int, line: int) -> float:
        """Gauge length of ``tool`` (0 for no tool or without ``tools``), mm."""
        if tool == 0 or self.tools is None:
            return 0.0
        if tool not in self.tools:
            raise self.fail(line, f"tool T{tool} is not among the tools given ({sorted(self.tools)})")
        return float(self.tools[tool].gauge_length_mm)

    def run(self) -> ProgramMotion:
        n = self.t.n_lines
        prev = 0
        for c in self.t.control.tolist() + [n]:
            if c > prev:
                self._run(prev, c)
            if c == n:
                break
            self._control(c)
            prev = c + 1
            if self.st.ended:
                if self.t.line.size and int(self.t.line[-1]) > c:
                    self.notes.append(f"{self.program}: the blocks after the program end on line {c + 1} are not run")
                break
        if not self.st.ended:
            self.notes.append(f"{self.program}: no program end (M30 / M2)")
        return self._result()

    # ---- mapping between program coordinates and the machine

    def _offset(self, line: int) -> float:
        return self.gauge(self.st.h_tool, line) if self.st.tlc else 0.0

    def _check_mapping(self, line: int) -> None:
        st = self.st
        if not self.iso:
            return
        if not st.tlc:
            raise self.fail(line, "ISO motion without tool length compensation G43 H (X Y Z are tool tips)")
        if st.frame is not None and not st.oriented:
            raise self.fail(line, "motion in a G68.2 plane before G53.1 oriented the tool")
        if st.frame is None and not st.tcp and np.any(np.abs(st.ang) > 1e-9):
            raise self.fail(line, "motion in G54 with the rotary axes turned (no G68.2 / G53.1, no G43.4)")

    def _frame(self) -> tuple[np.ndarray, np.ndarray]:
        return self.st.frame if self.st.frame is not None else (np.eye(3), np.zeros(3))

    def _to_machine(self, X: np.ndarray, line: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(tip (n,3), axis (n,3), mpos (n,3))`` of program points ``X`` (n,3) in the current state."""
        st, m = self.st, self.model
        g, off = self.gauge(st.tool, line), self._offset(line)
        if not self.iso:
            mpos = X + np.array([0.0, 0.0, off])
            tip, axis = m.tip_from_machine(mpos, st.ang, g)
            return tip, axis, mpos
        R, o = self._frame()
        axis = np.broadcast_to(m.axis(st.ang), X.shape)
        tip = X @ R.T + o + (off - g) * axis
        return tip, axis, m.machine_from_tip(tip, st.ang, g)

    def _program_position(self, line: int) -> np.ndarray:
        """(3,) the program coordinates of where the machine is now."""
        st = self.st
        g, off = self.gauge(st.tool, line), self._offset(line)
        if not self.iso:
            return st.mpos - np.array([0.0, 0.0, off])
        if st.tcp and self.tcp_at is not None and self.tcp_at[1] is st.mpos and self.tcp_at[2] == (g, off):
            return self.tcp_at[0].copy()
        tip, axis = self.model.tip_from_machine(st.mpos, st.ang, g)
        R, o = self._frame()
        return R.T @ (tip[0] - (off - g) * axis[0] - o)

    # ---- output

    def _emit(self, line, kind, t0, t1, axis, mpos, ang) -> None:
        self._flush()
        k = t0.shape[0]
        self.chunks.append((np.broadcast_to(np.asarray(line, np.int64), (k,)),
                            np.broadcast_to(np.asarray(kind, np.int8), (k,)), np.full(k, self.st.tool, np.int64),
                            t0, t1, np.broadcast_to(axis, (k, 3)), mpos, np.broadcast_to(ang, (k, 2))))

    def _machine_move(self, line: int, kind: int, p1: np.ndarray, a1: np.ndarray) -> None:
        """A move of the machine's axes to ``p1`` (controlled point) and ``a1`` (angles), all axes
        together; rotary turns split into steps of at most ``rotary_step_deg`` (by :meth:`_flush`)."""
        st = self.st
        p1, a1 = np.array(p1, dtype=np.float64), np.array(a1, dtype=np.float64)
        self.pending.append((line, kind, st.tool, self.gauge(st.tool, line), st.mpos, p1, st.ang, a1, math.nan))
        st.mpos, st.ang = p1, a1

    def _flush(self) -> None:
        """Split the pending machine and TCP moves into their steps, all at once, and emit them."""
        if not self.pending:
            return
        P, self.pending = self.pending, []
        line, kind, tool, gauge = (np.array([x[i] for x in P]) for i in range(4))
        p0, p1, a0, a1 = (np.array([x[i] for x in P], dtype=np.float64) for i in range(4, 8))
        shift = np.array([x[8] for x in P], dtype=np.float64)
        owner, q0, q1, b0, b1 = interpolate_moves(p0, p1, a0, a1, self.step)
        g = gauge[owner].astype(np.float64)
        m = self.model
        t0, t1, ax, mpos = np.empty_like(q0), np.empty_like(q0), np.empty_like(q0), q1.copy()
        tcp = np.isfinite(shift)[owner]
        mm = ~tcp
        if mm.any():                                # the controlled point moves linearly with the angles
            t0[mm], _ = m.tip_from_machine(q0[mm], b0[mm], g[mm])
            t1[mm], ax[mm] = m.tip_from_machine(q1[mm], b1[mm], g[mm])
        if tcp.any():                               # G43.4: the programmed point moves linearly with the angles
            sh = shift[owner][tcp][:, None]
            t0[tcp] = q0[tcp] + sh * m.axis(b0[tcp])
            ax[tcp] = m.axis(b1[tcp])
            t1[tcp] = q1[tcp] + sh * ax[tcp]
            mpos[tcp] = m.machine_from_tip(t1[tcp], b1[tcp], g[tcp])
        self.chunks.append((line[owner].astype(np.int64), kind[owner].astype(np.int8), tool[owner].astype(np.int64),
                            t0, t1, ax, mpos, b1))

    def _result(self) -> ProgramMotion:
        self._flush()
        if self.chunks:
            cols = [np.concatenate([c[j] for c in self.chunks]) for j in range(8)]
        else:
            cols = [np.zeros(0, np.int64), np.zeros(0, np.int8), np.zeros(0, np.int64)] + \
                   [np.zeros((0, 3))] * 4 + [np.zeros((0, 2))]
        return ProgramMotion(program=self.program, area=self.area, line=cols[0].astype(np.int64),
                             kind=cols[1].astype(np.int8), tool=cols[2].astype(np.int64),
                             start_mm=np.ascontiguousarray(cols[3], dtype=np.float64),
                             end_mm=np.ascontiguousarray(cols[4], dtype=np.float64),
                             axis=np.ascontiguousarray(cols[5], dtype=np.float64),
                             machine_mm=np.ascontiguousarray(cols[6], dtype=np.float64),
                             rotary_deg=np.ascontiguousarray(cols[7], dtype=np.float64), notes=list(self.notes),
                             line_feed=_line_feeds(self.t), line_inverse_time=_line_inverse_time(self.t))

    # ---- plain motion (whole arrays)

    def _run(self, a: int, b: int) -> None:
        """Lines ``a..b-1`` (0-based), which hold plain motion words only."""
        T, st = self.t, self.st
        mode = _ffill(T.motion[a:b, None], [st.motion])[:, 0]
        plane = _ffill(T.plane[a:b, None], [st.plane])[:, 0]
        feed = _ffill(T.feed[a:b, None], [st.feed])[:, 0]
        st.motion, st.plane, st.feed = float(mode[-1]), float(plane[-1]), float(feed[-1])
        xyz, ijk = T.xyz[a:b], T.ijk[a:b]
        rows = np.flatnonzero(~(np.isnan(xyz).all(axis=1) & np.isnan(ijk).all(axis=1)))
        if st.inverse_time and rows.size:
            no_f = (mode[rows] > 0) & np.isnan(T.feed[a:b][rows])
            if no_f.any():
                raise self.fail(a + int(rows[int(np.argmax(no_f))]) + 1, _NO_INVERSE_F)
        if rows.size:
            self._motion(a + rows, mode[rows], plane[rows], feed[rows], xyz[rows], ijk[rows])

    def _motion(self, lines0, mode, plane, feed, xyz, ijk) -> None:
        """Straight and arc moves of the program lines ``lines0`` (0-based, (m,)) with their modal
        ``mode`` (0..3), ``plane``, ``feed`` and words ``xyz``/``ijk`` (m,3; NaN where absent)."""
        self._check_motion(lines0, mode, plane, feed, ijk)
        line = int(lines0[0]) + 1
        self._check_mapping(line)
        pos0 = self._program_position(line)
        E = _ffill(xyz, pos0)
        S = np.vstack([pos0[None, :], E[:-1]])
        owner, P = self._polyline(lines0, mode, plane, S, E, ijk)
        tip, axis, mpos = self._to_machine(np.vstack([pos0[None, :], P]), line)
        kind = np.where(mode[owner] == 0, RAPID, FEED)
        self._emit(lines0[owner] + 1, kind, tip[:-1], tip[1:], axis[1:], mpos[1:], self.st.ang.copy())
        self.st.mpos = mpos[-1].copy()

    def _check_motion(self, lines0, mode, plane, feed, ijk) -> None:
        def check(bad, message):
            if np.any(bad):
                raise self.fail(int(lines0[int(np.argmax(bad))]) + 1, message)

        check(np.full(len(lines0), not self.st.absolute), "incremental motion (G91) is not in the subset")
        check(np.isnan(mode), "coordinates without a motion mode G0 / G1 / G2 / G3")
        arc = (mode == 2) | (mode == 3)
        has_ijk = ~np.isnan(ijk).all(axis=1)
        check(~arc & has_ijk, "I J K on a straight move")
        check((mode > 0) & ~(feed > 0), "feed move without a feed rate F")
        if arc.any():
            normal = np.where(plane == 17, 2, np.where(plane == 18, 1, 0))
            off_plane = ~np.isnan(ijk[np.arange(len(mode)), normal])
            check(arc & off_plane, "an arc centre word I / J / K across the active plane")
            check(arc & ~has_ijk, "an arc without its centre I J K (the R form is not in the subset)")

    def _polyline(self, lines0, mode, plane, S, E, ijk) -> tuple[np.ndarray, np.ndarray]:
        """``(owner (N,), points (N,3))``: the end point of every straight move and every arc chord,
        in order, program coordinates; ``owner`` indexes the moves."""
        m = len(mode)
        ai = np.flatnonzero((mode == 2) | (mode == 3))
        if ai.size == 0:
            return np.arange(m), E
        table = np.zeros((20, 3), dtype=np.int64)
        for k, v in _PLANE_AXES.items():
            table[k] = v
        axes = table[plane[ai].astype(np.int64)]
        C = S[ai] + np.nan_to_num(ijk[ai])
        r = np.arange(ai.size)
        r0 = np.hypot(*(S[ai][r, axes[:, j]] - C[r, axes[:, j]] for j in (0, 1)))
        r1 = np.hypot(*(E[ai][r, axes[:, j]] - C[r, axes[:, j]] for j in (0, 1)))
        err = np.abs(r1 - r0)
        bad = (err > _ARC_RADIUS_ABS_MM) & (err > _ARC_RADIUS_REL * np.maximum(r0, r1))
        if bad.any():
            i = int(np.argmax(bad))
            raise self.fail(int(lines0[ai[i]]) + 1, f"arc radius to the end {r1[i]:.4f} mm differs from the radius "
                                                     f"to the start {r0[i]:.4f} mm")
        own, pts = arc_chords(S[ai], E[ai], C, axes, np.where(mode[ai] == 3, 1, -1), self.tol)
        counts = np.ones(m, dtype=np.int64)
        per_arc = np.bincount(own, minlength=ai.size)
        counts[ai] = per_arc
        first = np.cumsum(counts) - counts
        P = np.empty((int(counts.sum()), 3))
        straight = np.setdiff1d(np.arange(m), ai)
        P[first[straight]] = E[straight]
        k = np.arange(own.size) - (np.cumsum(per_arc) - per_arc)[own]
        P[first[ai][own] + k] = pts
        return np.repeat(np.arange(m), counts), P

    # ---- other blocks, one at a time

    def _words(self, i: int) -> tuple[set, list, dict]:
        """``(G codes x10, M codes, {letter: value})`` of line ``i`` (0-based), checked against the subset."""
        T = self.t
        lo, hi = np.searchsorted(T.line, [i, i + 1])
        allowed = _G_ISO if self.iso else _G_LINUXCNC
        gs, ms, vals = set(), [], {}
        for L, v in zip(T.letter[lo:hi].tolist(), T.value[lo:hi].tolist()):
            ch = chr(L)
            if ch == "G":
                code = round(v * 10)
                if code not in allowed:
                    raise self.fail(i + 1, f"G{v:g} is not in the {'ISO' if self.iso else 'LinuxCNC'} subset")
                if code in gs:
                    raise self.fail(i + 1, f"G{v:g} twice in one block")
                gs.add(code)
            elif ch == "M":
                if v != int(v) or int(v) not in _M_ALLOWED:
                    raise self.fail(i + 1, f"M{v:g} is not in the subset")
                ms.append(int(v))
            elif ch != "N":
                vals[ch] = v
        for group in _G_GROUPS:
            if len(gs & group) > 1:
                raise self.fail(i + 1, "two G codes of one modal group in one block")
        return gs, ms, vals

    def _control(self, i: int) -> None:
        """Line ``i`` (0-based): settings in the RS274 order of execution, then its motion, then the end."""
        line = i + 1
        gs, ms, vals = self._words(i)
        self._settings(line, gs, ms, vals)
        self._frame_words(line, gs, vals)
        self._block_motion(line, gs, vals)
        if vals:
            raise self.fail(line, f"words {', '.join(sorted(vals))} are not used by this block")
        if 30 in ms or 2 in ms:
            self.st.ended = True

    def _settings(self, line: int, gs: set, ms: list, vals: dict) -> None:
        st = self.st
        if 200 in gs:
            raise self.fail(line, "G20 (inches): the reader takes millimetre programs (G21) only")
        if 930 in gs or 940 in gs:
            inverse = 930 in gs
            if inverse != st.inverse_time:
                st.feed = math.nan                   # a new feed mode needs a new F (as LinuxCNC)
            st.inverse_time = inverse
        st.f_word = "F" in vals
        if "F" in vals:
            st.feed = vals.pop("F")
        vals.pop("S", None)
        if "O" in vals:
            if not self.iso:
                raise self.fail(line, "O words (subroutines) are not in the LinuxCNC subset")
            vals.pop("O")
        if "T" in vals:
            st.t_word = int(vals.pop("T"))
        if 6 in ms:
            if st.t_word is None:
                raise self.fail(line, "M6 without a T word")
            self.gauge(st.t_word, line)
            st.tool = st.t_word
        for g in gs & {170, 180, 190}:
            st.plane = g / 10.0
        if 430 in gs or 434 in gs:
            if "H" not in vals and self.iso:
                raise self.fail(line, f"G43{'.4' if 434 in gs else ''} without H")
            if 434 in gs and st.frame is not None:
                raise self.fail(line, "G43.4 with a G68.2 plane active is not in the subset (G69 first)")
            st.h_tool = int(vals.pop("H")) if "H" in vals else st.tool
            self.gauge(st.h_tool, line)
            st.tlc, st.tcp = True, 434 in gs
        if 490 in gs:
            st.tlc = st.tcp = False
        if 640 in gs:
            vals.pop("P", None)
        if 900 in gs or 910 in gs:
            st.absolute = 900 in gs
        for g in gs & {0, 10, 20, 30}:
            st.motion = g / 10.0

    def _frame_words(self, line: int, gs: set, vals: dict) -> None:
        """ISO ``G69``, ``G68.2`` and ``G53.1``."""
        st = self.st
        if 690 in gs:
            st.frame, st.oriented = None, False
        if 682 in gs:
            if st.frame is not None:
                raise self.fail(line, "G68.2 while a G68.2 plane is active (cancel it with G69 first)")
            if st.tcp:
                raise self.fail(line, "G68.2 with G43.4 active is not in the subset (G49 first)")
            o = np.array([vals.pop(k, 0.0) for k in "XYZ"])
            i, j, k = (vals.pop(w, 0.0) for w in "IJK")
            st.frame, st.oriented = (_rz(i) @ _rx(j) @ _rz(k), o), False
        if 531 in gs:
            if st.frame is None:
                raise self.fail(line, "G53.1 without a G68.2 plane")
            ang, ok = self.model.orient(st.frame[0][:, 2])
            if not ok:
                self.notes.append(f"{self.program} line {line}: G53.1: no rotary position within travel presents "
                                  f"the plane's +Z; the out-of-travel one is taken")
            self._machine_move(line, RAPID, st.mpos, ang)
            st.oriented = True

    def _block_motion(self, line: int, gs: set, vals: dict) -> None:
        st = self.st
        if 280 in gs:
            self._reference_return(line, vals)
        elif 530 in gs:
            self._machine_coordinates(line, vals)
        elif any(k in vals for k in "ABC"):
            self._rotary(line, vals)
        elif any(k in vals for k in "XYZIJK"):
            self._check_inverse_f(line)
            xyz = np.array([vals.pop(k, math.nan) for k in "XYZ"])
            ijk = np.array([vals.pop(k, math.nan) for k in "IJK"])
            self._motion(np.array([line - 1]), np.array([st.motion]), np.array([st.plane]), np.array([st.feed]),
                         xyz[None, :], ijk[None, :])

    def _reference_return(self, line: int, vals: dict) -> None:
        """ISO ``G91 G28 X0 Y0 Z0`` and ``G91 G28 B0 C0`` (the profile's rotary names): the named
        axes rapid to the reference point (machine home; rotary axes at 0), all together."""
        if self.st.absolute:
            raise self.fail(line, "G28 is read with G91 only (G91 G28 Z0.)")
        names = self.model.profile.axis_names
        axes = [i for i, k in enumerate("XYZ") if k in vals]
        rot = [j for j, k in enumerate(names) if k in vals]
        if not (axes or rot) or any(k in vals for k in "IJK") or any(k in vals and k not in names for k in "ABC"):
            raise self.fail(line, f"G28 needs X, Y, Z, {names[0]} or {names[1]} words only")
        if any(vals.pop(k) != 0.0 for k in "XYZ" + "".join(names) if k in vals):
            raise self.fail(line, "G28 through an intermediate point is not in the subset (use G91 G28 Z0.)")
        p1 = self.st.mpos.copy()
        p1[axes] = self.model.home[axes]
        a1 = self.st.ang.copy()
        a1[rot] = 0.0
        self._machine_move(line, RAPID, p1, a1)

    def _machine_coordinates(self, line: int, vals: dict) -> None:
        """``G53 G0/G1 X Y Z`` and rotary words: the controlled point to home + (X, Y, Z) on the
        named axes, the named rotary axes to their machine position (the word times the sign, as
        a rotary positioning; 0 is the rotary zero), all together."""
        st = self.st
        if st.motion not in (0.0, 1.0):
            raise self.fail(line, "G53 needs G0 or G1")
        names = self.model.profile.axis_names
        axes = [i for i, k in enumerate("XYZ") if k in vals]
        rot = [j for j, k in enumerate(names) if k in vals]
        if not (axes or rot) or any(k in vals for k in "IJK") or any(k in vals and k not in names for k in "ABC"):
            raise self.fail(line, f"G53 needs X, Y, Z, {names[0]} or {names[1]} words only")
        if st.motion == 1.0 and not st.feed > 0:
            raise self.fail(line, "feed move without a feed rate F")
        self._check_inverse_f(line)
        p1 = st.mpos.copy()
        for i in axes:
            p1[i] = self.model.home[i] + vals.pop("XYZ"[i])
        a1 = st.ang.copy()
        for j in rot:
            a1[j] = vals.pop(names[j]) * self.sign[j]
        self._machine_move(line, RAPID if st.motion == 0.0 else FEED, p1, a1)

    def _check_inverse_f(self, line: int) -> None:
        """LinuxCNC G93: a feed move needs its own F word."""
        if self.st.inverse_time and self.st.motion > 0 and not self.st.f_word:
            raise self.fail(line, _NO_INVERSE_F)

    def _rotary(self, line: int, vals: dict) -> None:
        """``G0``/``G1`` with rotary words (and optionally X Y Z), all axes moving together:
        LinuxCNC (joint space), ISO with G43.4 (tip straight, angles linear)."""
        st, p = self.st, self.model.profile
        if self.iso and not st.tcp:
            raise self.fail(line, "rotary words are not in the ISO subset without G43.4 (G53.1 turns the rotary axes "
                                  "in a G68.2 plane, G53 / G28 in machine coordinates)")
        a1 = st.ang.copy()
        for k in "ABC":
            if k in vals:
                if k not in p.axis_names:
                    raise self.fail(line, f"{k} is not an axis of {p.kinematics}")
                j = p.axis_names.index(k)
                a1[j] = vals.pop(k) * self.sign[j]
        if st.motion not in (0.0, 1.0) or any(k in vals for k in "IJK"):
            raise self.fail(line, "rotary words need G0 or G1")
        if not st.absolute:
            raise self.fail(line, "incremental motion (G91) is not in the subset")
        if st.motion == 1.0 and not st.feed > 0:
            raise self.fail(line, "feed move without a feed rate F")
        self._check_inverse_f(line)
        kind = RAPID if st.motion == 0.0 else FEED
        X = self._program_position(line)
        for i, k in enumerate("XYZ"):
            if k in vals:
                X[i] = vals.pop(k)
        if self.iso:
            self._tcp_move(line, kind, X, a1)
            return
        p1 = X + np.array([0.0, 0.0, self._offset(line)])
        self._machine_move(line, kind, p1, a1)

    def _tcp_move(self, line: int, kind: int, X1: np.ndarray, a1: np.ndarray) -> None:
        """ISO G43.4: the programmed point (the tip, for ``H`` = the tool in the spindle) moves
        straight to ``X1`` in G54 = the part frame while the angles move linearly to ``a1``, in
        steps of at most ``rotary_step_deg``; the machine position of each step end is
        :meth:`~planning.simulate.kinematics.MachineModel.machine_from_tip` of its tip."""
        st, m = self.st, self.model
        g, off = self.gauge(st.tool, line), self._offset(line)
        X0 = self._program_position(line)                 # the programmed point now
        X1, a1 = np.array(X1, dtype=np.float64), np.array(a1, dtype=np.float64)
        self.pending.append((line, kind, st.tool, g, X0, X1, st.ang, a1, off - g))
        st.mpos = m.machine_from_tip(X1 + (off - g) * m.axis(a1), a1, g)[0]
        st.ang = a1
        self.tcp_at = (X1.copy(), st.mpos, (g, off))


def read_program(text: str, *, dialect: str, program: str, area: int, profile, placement_mm,
                 tools: dict | None = None, chord_tol_mm: float = 0.005, rotary_step_deg: float = 1.0,
                 rotary_sign=None) -> ProgramMotion:
    """Run one posted program on the simulated machine and return its moves in the part frame.

    ``text``: the program; ``dialect``: ``"iso"`` (Fanuc G68.2 / G53.1) or ``"linuxcnc"`` (rotary
    words, machine-frame X Y Z); ``program``: its name (for messages); ``area``: the area it
    machines. ``profile``: MachineProfile (or bundled name / path) whose kinematics and limits the
    machine has; ``placement_mm`` (3,): part origin in the table frame, mm. ``tools``: ``{T number:
    ToolShape}``; their ``gauge_length_mm`` are the control's tool lengths (G43) and place the
    controlled point; None: every length 0 (noted). ``chord_tol_mm``: largest distance of an arc
    chord from its arc, mm; ``rotary_step_deg``: largest rotary turn of one step of a rotary
    repositioning, degrees. ``rotary_sign``: LinuxCNC ``(tilt_sign, rotary_sign)`` the rotary words
    were printed with; None: from the post's header comment, else ``(1, 1)``.

    Returns :class:`ProgramMotion`: every move as a straight segment of the tool tip in the part
    frame (mm), 1-based program ``line``, kind RAPID / FEED, tool, unit tool axis (part frame, tip
    to spindle), the controlled point's machine position (mm; table-table: spindle gauge point,
    head-head: head rotation centre) and the rotary angles (planner signs, deg) at its end; ``notes``
    state what was assumed (the G53 home, G54, signs, tool lengths). Conventions: module docstring.
    Raises :class:`ProgramError` (naming the line) for anything outside the posts' subset.
    """
    return _Reader(text, dialect, program, area, profile, placement_mm, tools, chord_tol_mm, rotary_step_deg,
                   rotary_sign).run()


def check_travel(motion: ProgramMotion, profile) -> list[dict]:
    """Every move end of ``motion`` whose machine position lies beyond the profile's travel.

    Linear axes: ``machine_mm`` (the controlled point) against ``x/y/z_limits_mm``
    (``linear_limits_mm``, 1e-6 mm slack); rotary: ``rotary_deg`` against the tilt travel and the
    rotary travel, for a continuous C its register +-``rotary_register_deg`` (``rotary_limits_deg``;
    1e-6 deg slack). Straight moves between two ends within
    the limits stay within them (the linear axes move linearly and the travel is a box), so the
    ends are enough. Returns one dict per (move, axis) beyond: ``program``, ``line`` (1-based),
    ``move`` (index into ``motion``), ``axis`` (``"X"``, ``"Y"``, ``"Z"`` or the profile's tilt /
    rotary name), ``value`` (mm or deg), ``limit`` (the one passed), ``excess`` (> 0, mm or deg)
    and ``unit`` (``"mm"`` / ``"deg"``), ordered by move then axis.
    """
    from planning.orientations.kinematics import as_profile

    p = as_profile(profile)
    tilt, rot = p.axis_names
    checks = [(motion.machine_mm[:, i], lim, name, "mm", 1e-6)
              for i, (lim, name) in enumerate(zip(p.linear_limits_mm, "XYZ"))]
    checks.append((motion.rotary_deg[:, 0], (p.tilt_min_deg, p.tilt_max_deg), tilt, "deg", 1e-6))
    checks.append((motion.rotary_deg[:, 1], p.rotary_limits_deg, rot, "deg", 1e-6))
    found = []
    for order, (v, (lo, hi), name, unit, slack) in enumerate(checks):
        idx = np.flatnonzero((v < lo - slack) | (v > hi + slack))
        lim = np.where(v[idx] < lo, lo, hi)
        found += [(int(j), order, name, unit, float(v[j]), float(L)) for j, L in zip(idx, lim)]
    found.sort(key=lambda f: (f[0], f[1]))
    return [{"program": motion.program, "line": int(motion.line[j]), "move": j, "axis": name, "value": val,
             "limit": L, "excess": abs(val - L), "unit": unit} for j, _, name, unit, val, L in found]
