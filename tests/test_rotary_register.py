"""The C register and the rotary feed limits of simultaneous 5-axis programs (issue 33 item 3).

Checked: passes that keep turning a continuous C the same way are posted with C turned back in the
air between them (each pass starts within [-180, 180], where the walk alone reaches 1,800 degrees), and
LinuxCNC's own rs274 reads the unwound program with the planned tool tips; the turn back is made
with the tool at machine Z0, as an operation's start positions the rotary axes; a C beyond the profile's register is
a travel excursion; every feed move of a posted program turns its axes at most at the profile's
limits, measured from the program as read back; a program whose F words are raised is caught on
exactly the lines whose turns bound their time; the verdict fails on such a line; the profile
refuses a register on a limited C."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from pydantic import ValidationError

from planning.orientations.kinematics import load_profile
from planning.post.simultaneous import (
    FiveAxisOperation,
    iso_5axis_program,
    linuxcnc_5axis_program,
    rotary_path,
)
from planning.simulate.program import check_travel, read_program
from planning.simulate.rotary_speed import rotary_feed_excesses
from planning.simulate.rs274 import INSTALL_HINT, rs274_available, run_rs274
from planning.simulate.verify import move_minutes, verification_status
from planning.toolpath.moves import (
    FEED,
    RAPID,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
)
from schemas.machine import MachineProfile
from schemas.params import parse_config
from schemas.plan import Verification
from tests.test_post_simultaneous import (
    GAUGE,
    PLACE,
    SPHERE,
    STEP,
    TOOLS,
    R,
    centre_deviation,
    tip_error,
)

NAME = "compact_trunnion_bc"
#: the bundled profile with a register of three turns: C is turned back beyond one turn
#: (planning.post.simultaneous.unwind_deg: the register less two turns; the default ten turns wait
#: until eight)
SMALL = MachineProfile(**{**load_profile(NAME).model_dump(), "name": "register_1080", "rotary_register_deg": 1080.0})


def winding_op(n_passes: int = 7, span_deg: float = 300.0, phi_deg: float = 50.0, safe_mm: float = 40.0,
               step_deg: float = 5.0) -> FiveAxisOperation:
    """Passes along one latitude ring of the hemisphere, each ``span_deg`` long and all in the same
    direction, so that each starts where a continuous C must have turned on by 360 - span more:
    per pass a rapid across at the safe height (frame z + ``safe_mm``) to above its start, a rapid
    down, a plunge, the cut, a retract and a rapid up; the axis along the surface normal."""
    C, A, K, U = [], [], [], []
    ph = math.radians(phi_deg)
    for k in range(n_passes):
        t = np.radians(np.arange(0.0, span_deg + 1e-9, step_deg))
        n = np.stack([np.sin(ph) * np.cos(t), np.sin(ph) * np.sin(t), np.full_like(t, math.cos(ph))], 1)
        c = (SPHERE + R) * n
        top0 = c[0] + np.array([0.0, 0.0, safe_mm])
        top1 = c[-1] + np.array([0.0, 0.0, safe_mm])
        if k:
            C += [top0]
            A += [n[0]]
            K += [RAPID]
            U += [USE_RAPID]
        C += [c[0] + 10 * n[0], c[0], *c[1:], c[-1] + 10 * n[-1], top1]
        A += [n[0], n[0], *n[1:], n[-1], n[-1]]
        K += [RAPID, FEED] + [FEED] * (len(c) - 1) + [FEED, RAPID]
        U += [USE_RAPID, USE_PLUNGE] + [USE_CUT] * (len(c) - 1) + [USE_RETRACT, USE_RAPID]
    return FiveAxisOperation("winding", np.array(C), np.array(A), np.array(K, np.int8), np.array(U, np.int8),
                             1, R, 10000.0, 1500.0, 500.0, GAUGE)


def c_words(text: str) -> np.ndarray:
    return np.array([float(v) for v in re.findall(r"\bC(-?\d+(?:\.\d*)?)", text)])


def test_c_is_turned_back_only_where_the_register_needs_it():
    from planning.post.simultaneous import unwind_deg

    assert unwind_deg(NAME) == 2880.0 and unwind_deg(SMALL) == 360.0
    op = winding_op()
    _, [fig] = linuxcnc_5axis_program(op, profile=NAME, placement_mm=PLACE, return_figures=True)
    assert fig["n_unwound"] == 0 and fig["rotary_range_deg"][0] < -1800.0      # within ten turns: left as it is


def test_without_unwinding_the_winding_passes_accumulate_turns():
    op = winding_op()
    ang, ok = rotary_path(op.axis, NAME)
    assert ok.all() and np.abs(ang[:, 1]).max() > 1800.0          # the walk alone: five turns and more
    assert np.abs(np.diff(ang[:, 1])).max() < 180.0


def test_the_post_turns_c_back_between_passes_and_rs274_reads_it():
    assert rs274_available(), INSTALL_HINT
    op = winding_op()
    text, [fig] = linuxcnc_5axis_program(op, profile=SMALL, placement_mm=PLACE, return_figures=True)
    c = c_words(text)
    # every pass starts with C in [-180, 180] and turns 300 degrees on: 480 at most, where the walk
    # alone reaches over 1,800
    plunge = op.use[fig["move"]] == USE_PLUNGE
    assert np.abs(fig["angles_deg"][plunge, 1]).max() <= 180.0 + 1e-9
    assert np.abs(c).max() <= 480.0 + 1e-6 and fig["n_unwound"] == 6
    assert fig["rotary_range_deg"][1] - fig["rotary_range_deg"][0] <= 360.0 + 1e-9
    # within a pass C still runs on: the cut blocks turn by less than 180 degrees each
    cut = op.use[fig["move"]] == USE_CUT
    both = np.flatnonzero(cut[1:] & cut[:-1]) + 1
    assert np.abs(fig["angles_deg"][both, 1] - fig["angles_deg"][both - 1, 1]).max() < 180.0
    for reader in (None, "rs274"):
        kw = dict(program="t.nc", area=0, profile=SMALL, placement_mm=PLACE, tools=TOOLS, rotary_step_deg=STEP)
        m = run_rs274(text, **kw) if reader else read_program(text, dialect="linuxcnc", **kw)
        assert tip_error(m, fig, op) < 1e-3
        assert not check_travel(m, NAME)
        # the ball centre stays on the planned segments on every feed block (the unwinding is a rapid)
        feed_lines = set(fig["line"][op.kind[fig["move"]] == FEED].tolist())
        keep = np.isin(m.line, list(feed_lines))
        assert centre_deviation(m, fig, op)[keep[np.isin(m.line, fig["line"])]].max() < 0.002 + 1e-3
    iso, [fi] = iso_5axis_program(op, profile=SMALL, placement_mm=PLACE, return_figures=True)
    assert np.abs(c_words(iso)).max() <= 480.0 + 1e-6 and fi["n_unwound"] == fig["n_unwound"]


@pytest.mark.parametrize("dialect", ["linuxcnc", "iso"])
def test_c_is_turned_back_with_the_tool_at_machine_z0(dialect):
    """The turn back is written as an operation's start positions the rotary axes: up to machine Z0,
    the rotary axes turned there, then down; read back, every move that turns C by a whole turn's
    share runs with the controlled point at the top of its travel, and the tips are the planned ones."""
    op = winding_op(n_passes=4)
    post = linuxcnc_5axis_program if dialect == "linuxcnc" else iso_5axis_program
    text, [fig] = post(op, profile=SMALL, placement_mm=PLACE, return_figures=True)
    n = fig["n_unwound"]
    assert n == 3
    home = "G53 G0 Z0" if dialect == "linuxcnc" else "G91 G28 Z0."
    assert text.count(home) == n + 2            # and the operation's start and end (ISO: the program's start)
    m = read_program(text, dialect=dialect, program="t", area=0, profile=SMALL, placement_mm=PLACE, tools=TOOLS,
                     rotary_step_deg=STEP)
    assert tip_error(m, fig, op) < 1e-3
    turn = np.abs(np.diff(np.r_[m.rotary_deg[:1, 1], m.rotary_deg[:, 1]]))
    lines = np.unique(m.line[turn > 0])
    per_line = np.array([turn[m.line == ln].sum() for ln in lines])
    big = lines[per_line >= 180.0]
    assert big.size >= n                       # the turns back, and the operation's start and end positioning
    top = m.machine_mm[:, 2].max()
    for ln in big:
        assert np.allclose(m.machine_mm[m.line == ln, 2], top, atol=1e-6)


def test_c_beyond_the_register_is_a_travel_excursion():
    base = load_profile(NAME).model_dump()
    small = MachineProfile(**{**base, "name": "small_register", "rotary_register_deg": 500.0})
    op = winding_op(n_passes=3)
    ang, _ = rotary_path(op.axis, NAME)
    assert np.abs(ang[:, 1]).max() > 500.0
    # the reader takes the program's C words as they are: a program written without unwinding
    text = linuxcnc_5axis_program(op, profile=SMALL, placement_mm=PLACE)
    m = read_program(text, dialect="linuxcnc", program="t", area=0, profile=small, placement_mm=PLACE, tools=TOOLS)
    found = [f for f in check_travel(m, small) if f["axis"] == "C"]
    assert not found                                    # the post unwound it: within +-500
    wound = re.sub(r"\bC(-?\d+(?:\.\d*)?)", lambda g: f"C{float(g.group(1)) + 720.0:.7f}", text)
    m = read_program(wound, dialect="linuxcnc", program="t", area=0, profile=small, placement_mm=PLACE, tools=TOOLS)
    found = [f for f in check_travel(m, small) if f["axis"] == "C"]
    assert found and all(f["value"] > 500.0 and f["limit"] == 500.0 for f in found)
    # the default register is ten turns: C words raised by 3,700 degrees count only beyond 3600
    assert load_profile(NAME).rotary_limits_deg == (-3600.0, 3600.0)
    assert not [f for f in check_travel(m, NAME) if f["axis"] == "C"]
    wound = re.sub(r"\bC(-?\d+(?:\.\d*)?)", lambda g: f"C{float(g.group(1)) + 3700.0:.7f}", text)
    m = read_program(wound, dialect="linuxcnc", program="t", area=0, profile=NAME, placement_mm=PLACE, tools=TOOLS)
    beyond = [f for f in check_travel(m, NAME) if f["axis"] == "C"]
    assert beyond and all(f["value"] > 3600.0 for f in beyond)
    assert (m.rotary_deg[:, 1] > 3600.0 + 1e-6).sum() == len(beyond) < m.n_moves


def test_a_register_on_a_limited_c_is_refused():
    base = load_profile("compact_trunnion_ac").model_dump()
    limited = {**base, "rotary_continuous": False, "rotary_min_deg": -360.0, "rotary_max_deg": 360.0,
               "rotary_register_deg": 400.0}
    with pytest.raises(ValidationError, match="rotary_register_deg"):
        MachineProfile(**limited)


# ------------------------------------------------------------------------------------------------
# rotary speeds of the feed moves


def fast_turn_op() -> FiveAxisOperation:
    """The hemisphere's ring passes with the axis turning fast along them: the lead swings by 40
    degrees back and forth every 3 degrees of the ring, so many moves are timed by their turn."""
    C, A, K, U = [], [], [], []
    ph = math.radians(45.0)
    t = np.radians(np.arange(0.0, 180.0 + 1e-9, 1.0))
    n = np.stack([np.sin(ph) * np.cos(t), np.sin(ph) * np.sin(t), np.full_like(t, math.cos(ph))], 1)
    tang = np.stack([-np.sin(t), np.cos(t), 0 * t], 1)
    lead = np.radians(np.where(np.arange(t.size) % 2 == 0, 0.0, 40.0))
    a = np.cos(lead)[:, None] * n + np.sin(lead)[:, None] * tang
    c = (SPHERE + R) * n
    C += [c[0] + 10 * a[0], *c, c[-1] + 10 * a[-1]]
    A += [a[0], *a, a[-1]]
    K += [RAPID] + [FEED] * len(c) + [FEED]
    U += [USE_RAPID, USE_PLUNGE] + [USE_CUT] * (len(c) - 1) + [USE_RETRACT]
    return FiveAxisOperation("fast turns", np.array(C), np.array(A), np.array(K, np.int8), np.array(U, np.int8),
                             1, R, 10000.0, 1500.0, 500.0, GAUGE)


@pytest.mark.parametrize("dialect", ["linuxcnc", "iso"])
def test_posted_feed_moves_keep_to_the_profiles_rotary_limits(dialect):
    op = fast_turn_op()
    cfg = parse_config({})
    post = linuxcnc_5axis_program if dialect == "linuxcnc" else iso_5axis_program
    text, [_fig] = post(op, profile=NAME, placement_mm=PLACE, return_figures=True)
    m = read_program(text, dialect=dialect, program="t", area=0, profile=NAME, placement_mm=PLACE, tools=TOOLS)
    minutes = move_minutes(m, cfg)
    assert rotary_feed_excesses(m, minutes, NAME) == []
    # by hand from the program text alone: per G1 block the printed B and C against the previous
    # block's, over the block's time (1 / F under G93; the printed tip path over the F in force under
    # G94, ISO's X Y Z being the tip); the limit binds on many blocks
    bound, prev, f_now = 0, None, None
    for line in text.splitlines():
        words = dict(re.findall(r"\b([XYZBCF])(-?\d+(?:\.\d*)?)", line))
        if not all(k in words for k in "XYZBC"):
            continue
        f_now = float(words["F"]) if "F" in words else f_now
        cur = np.array([float(words[k]) for k in "XYZBC"])
        if prev is not None and re.search(r"\bG1\b", line):
            dt, dc = np.abs(cur[3:] - prev[3:])
            L = np.linalg.norm(cur[:3] - prev[:3])
            if dialect == "iso" and L < 1e-9:
                prev = cur
                continue
            t = 1.0 / f_now if dialect == "linuxcnc" else L / f_now
            assert dt / t <= 5400.0 * (1 + 1e-6) and dc / t <= 7200.0 * (1 + 1e-6), line
            bound += dt / t > 5400.0 * 0.99 or dc / t > 7200.0 * 0.99
        prev = cur
    assert bound >= 20


def test_raised_feeds_are_caught_on_exactly_the_lines_their_turns_time():
    op = fast_turn_op()
    cfg = parse_config({})
    text, [fig] = linuxcnc_5axis_program(op, profile=NAME, placement_mm=PLACE, return_figures=True)
    fast = re.sub(r"F([\d.]+)", lambda g: f"F{float(g.group(1)) * 1.5:.3f}", text)
    m = read_program(fast, dialect="linuxcnc", program="t", area=0, profile=NAME, placement_mm=PLACE, tools=TOOLS)
    found = rotary_feed_excesses(m, move_minutes(m, cfg), NAME)
    got = {f["line"] for f in found}
    # by hand from the figures: a line whose turn over the limit is more than 1/1.5 of its time
    lim = (5400.0, 7200.0)
    ang, tips = fig["angles_deg"], fig["tip_mm"]
    want, unsure = set(), set()
    for k in np.flatnonzero(op.kind[fig["move"]] == FEED):
        if k == 0:
            continue
        L = np.linalg.norm(tips[k] - tips[k - 1])
        feed = 500.0 if op.use[fig["move"][k]] == USE_PLUNGE else 1500.0
        dt, dc = np.abs(ang[k] - ang[k - 1])
        turn_t = max(dt / lim[0], dc / lim[1])
        t = max(L / feed, turn_t, 1e-5)
        ratio = 1.5 * turn_t / t
        if ratio > 1.0 + 1e-3:
            want.add(int(fig["line"][k]))
        elif ratio > 1.0 - 1e-3:
            unsure.add(int(fig["line"][k]))
    assert len(want) >= 20
    assert want <= got <= want | unsure
    assert {f["axis"] for f in found} <= {"B", "C"}


def test_a_rotary_feed_excess_fails_the_verdict():
    v = Verification(status="passed", message="")
    assert verification_status(v) == "passed"
    v.rotary_feed_excesses = 1
    assert verification_status(v) == "failed"


# ------------------------------------------------------------------------------------------------
# the planner: links where C must turn back go through the safe height


def zigzag_ring_path(n_passes: int = 6, span_deg: float = 300.0, phi_deg: float = 50.0, step_deg: float = 5.0,
                     short_links: bool = False):
    """A 5-axis finishing path (frame = part frame) of ring passes all in the same direction, each
    starting where the last ended plus a step-over: a feed step-over point (pass_index -1) or, with
    ``short_links``, a retract, one rapid and a plunge. Returns (Toolpath, pass_index)."""
    from planning.toolpath.moves import Toolpath

    ph = math.radians(phi_deg)
    X, A, K, U, PI = [], [], [], [], []
    for k in range(n_passes):
        t = np.radians(np.arange(0.0, span_deg + 1e-9, step_deg)) + math.radians(k * (span_deg + 30.0))
        n = np.stack([np.sin(ph) * np.cos(t), np.sin(ph) * np.sin(t), np.full_like(t, math.cos(ph))], 1)
        c = (SPHERE + R) * n
        if k == 0:
            X += [c[0] + 10 * n[0]]
            A += [n[0]]
            K += [RAPID]
            U += [USE_RAPID]
            PI += [-1]
        elif short_links:
            X += [X[-1] + 2.0 * A[-1], c[0] + 2.0 * n[0]]
            A += [A[-1], n[0]]
            K += [FEED, RAPID]
            U += [USE_RETRACT, USE_RAPID]
            PI += [-1, -1]
        else:
            mid = (SPHERE + R + 0.5) * (n[0] + np.asarray(A[-1])) / np.linalg.norm(n[0] + np.asarray(A[-1]))
            X += [mid]
            A += [(n[0] + np.asarray(A[-1])) / np.linalg.norm(n[0] + np.asarray(A[-1]))]
            K += [FEED]
            U += [USE_CUT]
            PI += [-1]
        X += list(c)
        A += list(n)
        K += [FEED] * len(c)
        U += [USE_PLUNGE if (k == 0 or short_links) else USE_CUT] + [USE_CUT] * (len(c) - 1)
        PI += [k] * len(c)
    X += [X[-1] + 10 * A[-1]]
    A += [A[-1]]
    K += [FEED]
    U += [USE_RETRACT]
    PI += [-1]
    P = len(X)
    tp = Toolpath(xyz_mm=np.array(X), kind=np.array(K, np.int8), centre_mm=np.full((P, 3), np.nan),
                  plane=np.zeros(P, np.int8), use=np.array(U, np.int8), axis=np.array(A))
    return tp, np.array(PI)


@pytest.mark.parametrize("short_links", [False, True])
def test_links_where_c_must_turn_back_are_routed_through_the_safe_height(short_links):
    from planning.toolpath.fiveaxis.register import route_unwinding_links

    tp, pi = zigzag_ring_path(short_links=short_links)
    prof = SMALL

    def posted_c(path):
        op = FiveAxisOperation("p", path.xyz_mm, path.axis, path.kind, path.use, 1, R, 10000.0, 1500.0, 500.0, GAUGE)
        text, [fig] = linuxcnc_5axis_program(op, profile=SMALL, placement_mm=PLACE, return_figures=True)
        return c_words(text), fig

    before, _ = posted_c(tp)
    assert np.abs(before).max() > 1400.0                       # no link the post could unwind on
    out, pi2, n = route_unwinding_links(tp, pi, profile=prof, rotation=np.eye(3), safe_z_mm=80.0)
    assert n >= 2 and pi2.shape[0] == out.n_moves
    after, fig = posted_c(out)
    # a link starting beyond one turn is routed and unwound; a pass and its step-over turn 330 more
    assert np.abs(after).max() <= 360.0 + 330.0 + 1e-6 and fig["n_unwound"] >= n
    # every point of every pass is kept, in order, with its axis
    on = pi >= 0
    kept = pi2 >= 0
    assert kept.sum() == on.sum()
    assert np.allclose(out.xyz_mm[kept], tp.xyz_mm[on]) and np.allclose(out.axis[kept], tp.axis[on])
    # the routed links reach the safe height
    assert (out.xyz_mm[out.kind == RAPID, 2] >= 80.0 - 1e-9).sum() >= 2 * n
    # a path that never winds is left as it is
    one, pi1 = zigzag_ring_path(n_passes=1)
    same, _, n1 = route_unwinding_links(one, pi1, profile=prof, rotation=np.eye(3), safe_z_mm=80.0)
    assert n1 == 0 and same is one


def test_a_rapid_that_changes_rotary_solution_goes_through_machine_z0():
    """Two passes joined by one rapid, on a C limited to [-90, 90]: the second pass's axis (tilt 30 at
    C 180) is reached only by the other solution (tilt -30, C 0), so the table swings through the
    pole between them, and does so at machine Z0."""
    from planning.orientations.kinematics import tool_axis_from_angles

    base = load_profile(NAME).model_dump()
    p = MachineProfile(**{**base, "name": "limited_c", "rotary_continuous": False, "rotary_min_deg": -90.0,
                          "rotary_max_deg": 90.0})
    a0, a1 = tool_axis_from_angles(np.array([[30.0, 0.0], [30.0, 180.0]]), p)
    c0 = (SPHERE + R) * a0
    c1 = (SPHERE + R) * a1
    C = [c0 + 10 * a0, c0, c0 + 1.0 * np.cross(a0, [0, 1, 0]), c0 + 10 * a0, c1 + 10 * a1, c1,
         c1 + 1.0 * np.cross(a1, [0, 1, 0]), c1 + 10 * a1]
    A = [a0, a0, a0, a0, a1, a1, a1, a1]
    K = [RAPID, FEED, FEED, FEED, RAPID, FEED, FEED, FEED]
    U = [USE_RAPID, USE_PLUNGE, USE_CUT, USE_RETRACT, USE_RAPID, USE_PLUNGE, USE_CUT, USE_RETRACT]
    op = FiveAxisOperation("flip", np.array(C), np.array(A), np.array(K, np.int8), np.array(U, np.int8),
                           1, R, 10000.0, 1500.0, 500.0, GAUGE)
    for post, dialect, home in ((linuxcnc_5axis_program, "linuxcnc", "G53 G0 Z0"),
                                (iso_5axis_program, "iso", "G91 G28 Z0.")):
        text, [fig] = post(op, profile=p, placement_mm=PLACE, return_figures=True)
        assert fig["n_home"] == 1 and fig["n_unwound"] == 0
        assert fig["angles_deg"][:, 0].min() < -29.0 and fig["angles_deg"][:, 0].max() > 29.0     # the flip
        lines = text.splitlines()
        at = fig["line"][np.flatnonzero(fig["move"] == 4)[-1]] - 1     # the rapid's block (0-based)
        assert any(home in ln for ln in lines[at - 3:at])
        m = read_program(text, dialect=dialect, program="t", area=0, profile=p, placement_mm=PLACE, tools=TOOLS,
                         rotary_step_deg=STEP)
        assert tip_error(m, fig, op) < 1e-3
        turning = np.abs(np.diff(np.r_[m.rotary_deg[:1], m.rotary_deg], axis=0)).max(axis=1) > 0
        top = m.machine_mm[:, 2].max()
        mid = turning & (m.line > fig["line"][0]) & (m.line < fig["line"][-1]) & (m.kind == RAPID)
        assert mid.any() and np.allclose(m.machine_mm[mid, 2], top, atol=1e-6)
