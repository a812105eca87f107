"""Simultaneous 5-axis posts (planning.post.simultaneous) and the readers that run them.

Checked: the rotary angles along a path are continuous (no jump of 180 degrees or more on a
continuous C, only wraps within travel on a limited one), hold C through the pole, report axes out
of travel; a synthetic finishing path on a hemisphere (axes 15 degrees off the normal, C turning
well over 30 degrees) posted for LinuxCNC runs through LinuxCNC's own interpreter rs274 and the text
reader with the planned tool tip at every planned point and the ball centre within the linearisation
tolerance of the planned segments at every simulated step, and without the inserted points it does
not; the ISO G43.4 program read back gives the same; table-table B/C and A/C and head-head A/C.
rs274 is required: where it is missing the rs274 tests FAIL and say how to install it."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from planning.errors import ParameterError
from planning.orientations.kinematics import load_profile, tool_axis_from_angles
from planning.orientations.positions import default_placement
from planning.post import PostOptions
from planning.post.blocks import BlockWriter
from planning.post.simultaneous import (
    MIN_MOVE_TIME_MIN,
    FiveAxisOperation,
    iso_5axis_program,
    linuxcnc_5axis_blocks,
    linuxcnc_5axis_program,
    rotary_path,
)
from planning.simulate.motion import ToolShape
from planning.simulate.program import ProgramError, check_travel, read_program
from planning.simulate.rs274 import INSTALL_HINT, rs274_available, run_rs274
from planning.toolpath.moves import (
    FEED,
    RAPID,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
)

PROFILES = ("compact_trunnion_bc", "compact_trunnion_ac", "fork_head_ac")
R, GAUGE, SPHERE = 3.0, 100.0, 30.0
TOL = 0.002                       # linearisation tolerance (PostOptions.chord_tol_mm default), mm
TOOLS = {1: ToolShape(1, "ball", R, R, 12.0, (), GAUGE)}
STEP = 0.1                        # the readers' rotary step here: dense samples of the control's motion, deg


def require_rs274():
    assert rs274_available(), INSTALL_HINT


def hemisphere_op(rings=(50.0, 40.0), th=(0.0, 120.0), step=3.0, lead=15.0) -> FiveAxisOperation:
    """Ball-end finishing on latitude rings of a hemisphere of radius SPHERE (centre at the part
    origin): per ring a rapid to 10 mm above the start along the axis, a plunge, the cut along the
    ring (zig-zag), a retract of 10 mm; tool axis = the surface normal turned ``lead`` degrees
    towards the direction of travel."""
    C, A, K, U = [], [], [], []
    for r, phi in enumerate(rings):
        t = np.radians(np.arange(th[0], th[1] + 1e-9, step))
        d = 1.0
        if r % 2:
            t, d = t[::-1], -1.0
        ph = math.radians(phi)
        n = np.stack([np.sin(ph) * np.cos(t), np.sin(ph) * np.sin(t), np.full_like(t, math.cos(ph))], 1)
        tang = d * np.stack([-np.sin(t), np.cos(t), 0 * t], 1)
        a = math.cos(math.radians(lead)) * n + math.sin(math.radians(lead)) * tang
        a /= np.linalg.norm(a, axis=1)[:, None]
        c = (SPHERE + R) * n
        C += [c[0] + 10 * a[0], c[0], *c[1:], c[-1] + 10 * a[-1]]
        A += [a[0], a[0], *a[1:], a[-1]]
        K += [RAPID, FEED] + [FEED] * (len(c) - 1) + [FEED]
        U += [USE_RAPID, USE_PLUNGE] + [USE_CUT] * (len(c) - 1) + [USE_RETRACT]
    return FiveAxisOperation("finishing", np.array(C), np.array(A), np.array(K, np.int8), np.array(U, np.int8),
                             1, R, 10000.0, 1500.0, 500.0, GAUGE)


def placement():
    g = np.random.default_rng(0).normal(size=(2000, 3))
    g[:, 2] = np.abs(g[:, 2])
    pts = SPHERE * g / np.linalg.norm(g, axis=1)[:, None]
    return default_placement(pts, fixture_height_mm=80.0)


PLACE = placement()
OP = hemisphere_op()


def ends_of(motion, lines):
    """Index of the last move of each program line in ``lines``."""
    last = {}
    for i, ln in enumerate(motion.line.tolist()):
        last[ln] = i
    return np.array([last[int(ln)] for ln in lines])


def centre_deviation(motion, fig, op) -> np.ndarray:
    """Distance of the ball centre at every simulated step end of the path's blocks from the planned
    centre segment of the planned move the block lies on (mm)."""
    line2move = dict(zip(fig["line"].tolist(), fig["move"].tolist()))
    keep = np.isin(motion.line, fig["line"])
    j = np.array([line2move[ln] for ln in motion.line[keep].tolist()])
    q = motion.end_mm[keep] + R * motion.axis[keep]
    c = np.asarray(op.centre_mm)
    p0, p1 = c[np.maximum(j - 1, 0)], c[j]
    d = p1 - p0
    dd = np.einsum("ij,ij->i", d, d)
    s = np.clip(np.einsum("ij,ij->i", q - p0, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    return np.linalg.norm(q - (p0 + s[:, None] * d), axis=1)


def tip_error(motion, fig, op) -> float:
    """Largest distance between the read tool tip at the end of each planned point's block and the
    planned tip centre - R axis (mm)."""
    planned = np.flatnonzero(fig["u"] == 1.0)
    e = ends_of(motion, fig["line"][planned])
    tips = np.asarray(op.centre_mm) - R * np.asarray(op.axis)
    return float(np.linalg.norm(motion.end_mm[e] - tips[fig["move"][planned]], axis=1).max())


def read(text, dialect, profile, reader=None, **kw):
    kw = dict(program="t.nc", area=0, profile=profile, placement_mm=PLACE, tools=TOOLS, rotary_step_deg=STEP, **kw)
    if reader == "rs274":
        return run_rs274(text, **kw)
    return read_program(text, dialect=dialect, **kw)


# ------------------------------------------------------------------------------------------------
# rotary angles along a path


def cone(tilt_deg: float, turns: float, n: int = 200) -> np.ndarray:
    th = np.radians(np.linspace(0.0, 360.0 * turns, n))
    s = math.sin(math.radians(tilt_deg))
    return np.stack([s * np.cos(th), s * np.sin(th), np.full_like(th, math.cos(math.radians(tilt_deg)))], 1)


@pytest.mark.parametrize("name", PROFILES)
def test_rotary_path_is_continuous_and_presents_every_axis(name):
    p = load_profile(name)
    # the fork head's C has 720 degrees of travel and starts at 90: 1.2 turns the way C goes down
    turns = 3.0 if p.rotary_continuous else -1.2
    axes = cone(40.0, turns)
    ang, ok = rotary_path(axes, p)
    assert ok.all()
    assert np.abs(tool_axis_from_angles(ang, p) - axes).max() < 1e-9
    dc = np.abs(np.diff(ang[:, 1]))
    if p.rotary_continuous:
        assert dc.max() < 10.0                               # unwrapped: the table follows, never spins round
        assert np.ptp(ang[:, 1]) > 360.0 * turns - 10.0      # and leaves [-180, 180) to do so
    else:
        assert ang[:, 1].min() >= p.rotary_min_deg and ang[:, 1].max() <= p.rotary_max_deg
        assert dc.max() < 10.0 and np.ptp(ang[:, 1]) > 400.0
    # three turns on the fork head need more than its C travel: only wraps within travel, the other
    # solution where the travel ends (a jump, reported by the turn, never a C beyond the limit)
    if not p.rotary_continuous:
        ang3, ok3 = rotary_path(cone(40.0, 3.0), p)
        assert ok3.all() and ang3[:, 1].min() >= -360.0 and ang3[:, 1].max() <= 360.0
        assert np.abs(np.diff(ang3[:, 1])).max() > 90.0


@pytest.mark.parametrize("name", PROFILES)
def test_path_through_the_pole_keeps_c_steady(name):
    p = load_profile(name)
    s = np.radians(np.linspace(-10.0, 10.0, 41))              # a great circle through +Z, azimuth 30 deg
    az = math.radians(30.0)
    axes = np.stack([np.sin(s) * math.cos(az), np.sin(s) * math.sin(az), np.cos(s)], 1)
    ang, ok = rotary_path(axes, p)
    assert ok.all()
    assert np.ptp(ang[:, 1]) < 1e-9                           # C stands still over the whole pass
    assert ang[0, 0] * ang[-1, 0] < 0                          # the tilt goes through 0 and changes sign
    assert np.abs(tool_axis_from_angles(ang, p) - axes).max() < 1e-9
    # without the pole rule the solver's C = 0 at the pole point makes C jump there and back
    ang0, _ = rotary_path(axes, p, pole_deg=0.0)
    assert np.abs(np.diff(ang0[:, 1])).max() > 20.0


def test_path_beside_the_pole_holds_c_in_the_cone_and_starts_from_the_next_valid_c():
    p = load_profile("compact_trunnion_bc")
    s = np.radians(np.linspace(-2.0, 2.0, 41))
    off = math.radians(0.2)                                     # passes 0.2 deg from the pole
    axes = np.stack([np.sin(s), np.full_like(s, math.sin(off)), np.cos(s)], 1)
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    ang, ok = rotary_path(axes, p, pole_deg=0.5)
    assert ok.all()
    polar = np.degrees(np.arccos(axes[:, 2]))
    inside = np.flatnonzero(polar < 0.5)
    assert inside.size > 3
    assert np.all(ang[inside, 1] == ang[inside[0] - 1, 1])     # the C of the last point before the cone
    # in the cone the axis is the nearest one with that C: within the cone's half-angle
    t = tool_axis_from_angles(ang, p)
    dev = np.degrees(np.arctan2(np.linalg.norm(np.cross(t, axes), axis=1), np.einsum("ij,ij->i", t, axes)))
    assert dev.max() < 0.5 and dev[np.setdiff1d(np.arange(41), inside)].max() < 1e-6
    # a path starting in the cone takes the C of its first point outside it
    ang2, _ = rotary_path(axes[inside[0] + 1:], p)
    k = np.flatnonzero(np.degrees(np.arccos(axes[inside[0] + 1:, 2])) >= 0.5)[0]
    assert np.all(ang2[:k, 1] == ang2[k, 1])


def test_start_deg_picks_the_closest_solution():
    p = load_profile("compact_trunnion_bc")                    # B -35..120: both solutions of a 20 deg axis
    axes = cone(20.0, 0.1, 5)
    a_plain, _ = rotary_path(axes, p)
    assert a_plain[0, 0] > 0                                    # choose_rotary: tilt >= 0
    a_neg, ok = rotary_path(axes, p, start_deg=(-18.0, 365.0))   # near (-20, 360): the other solution, wrapped
    assert ok.all() and a_neg[0, 0] < 0 and abs(a_neg[0, 1] - 365.0) < 10.0
    assert np.abs(tool_axis_from_angles(a_neg, p) - axes).max() < 1e-9


def test_axes_out_of_travel_are_reported_not_clamped():
    p = load_profile("compact_trunnion_ac")                     # A -120..+30
    tilt = np.r_[np.linspace(60.0, 130.0, 15), np.linspace(130.0, 60.0, 15)]
    axes = np.stack([np.sin(np.radians(tilt)), 0 * tilt, np.cos(np.radians(tilt))], 1)
    ang, ok = rotary_path(axes, p)
    assert np.array_equal(ok, tilt <= 120.0 + 1e-9)
    assert np.abs(np.abs(ang[:, 0]) - tilt).max() < 1e-9        # the angles needed, not the limit
    op = hemisphere_op(rings=(50.0,))
    bad = FiveAxisOperation(op.name, np.vstack([op.centre_mm, [[40.0, 0.0, -5.0]]]),
                            np.vstack([op.axis, axes[14]]), np.r_[op.kind, FEED].astype(np.int8),
                            np.r_[op.use, USE_CUT].astype(np.int8), 1, R, 10000.0, 1500.0, 500.0, GAUGE)
    with pytest.raises(ParameterError, match=f"point {len(op.centre_mm)} .*no rotary position"):
        linuxcnc_5axis_program(bad, profile=p, placement_mm=PLACE)
    with pytest.raises(ParameterError, match="no rotary position"):
        iso_5axis_program(bad, profile=p, placement_mm=PLACE)


# ------------------------------------------------------------------------------------------------
# the programs


@pytest.fixture(scope="module")
def posted():
    """{(profile, what): (text, figures of the operation)} for the hemisphere path."""
    out = {}
    for name in PROFILES:
        out[name, "linuxcnc"] = linuxcnc_5axis_program(OP, profile=name, placement_mm=PLACE, return_figures=True)
        out[name, "linuxcnc4"] = linuxcnc_5axis_program(OP, profile=name, placement_mm=PLACE, return_figures=True,
                                                        options=PostOptions(angle_decimals=4))
        out[name, "raw"] = linuxcnc_5axis_program(OP, profile=name, placement_mm=PLACE, return_figures=True,
                                                  linearise=False)
        out[name, "iso"] = iso_5axis_program(OP, profile=name, placement_mm=PLACE, return_figures=True)
    return out


@pytest.mark.parametrize("name", PROFILES)
def test_the_path_really_turns_the_rotary_axes(posted, name):
    _, [fig] = posted[name, "linuxcnc"]
    assert np.ptp(fig["angles_deg"][:, 1]) > 30.0
    assert fig["n_inserted"] > 0 and fig["n_points"] == fig["n_moves"] + fig["n_inserted"]
    assert fig["max_deviation_mm"] <= TOL < fig["max_deviation_unlinearised_mm"]


@pytest.mark.parametrize("name", PROFILES)
def test_linuxcnc_program_through_rs274(posted, name):
    require_rs274()
    text, [fig] = posted[name, "linuxcnc"]
    m = read(text, "linuxcnc", name, reader="rs274")
    assert tip_error(m, fig, OP) < 1e-3
    assert centre_deviation(m, fig, OP).max() < TOL + 1e-3
    assert check_travel(m, name) == []
    # the text reader runs the same moves; with 4-decimal angles (what rs274 prints) to 1e-4 mm
    ours = read(text, "linuxcnc", name)
    assert np.array_equal(ours.line, m.line) and np.array_equal(ours.kind, m.kind)
    assert np.abs(ours.end_mm - m.end_mm).max() < 1e-3
    text4, [fig4] = posted[name, "linuxcnc4"]
    a, b = read(text4, "linuxcnc", name), read(text4, "linuxcnc", name, reader="rs274")
    assert np.array_equal(a.line, b.line) and np.array_equal(a.kind, b.kind) and np.array_equal(a.tool, b.tool)
    for f in ("start_mm", "end_mm", "machine_mm"):
        assert np.abs(getattr(a, f) - getattr(b, f)).max() < 1e-4, f
    assert np.abs(a.axis - b.axis).max() < 1e-9 and np.abs(a.rotary_deg - b.rotary_deg).max() < 1e-9
    assert tip_error(b, fig4, OP) < 1e-3 and centre_deviation(b, fig4, OP).max() < TOL + 1e-3


@pytest.mark.parametrize("name", PROFILES)
def test_without_inserted_points_the_ball_leaves_the_planned_segments(posted, name):
    require_rs274()
    text, [fig] = posted[name, "raw"]
    assert fig["n_inserted"] == 0
    m = read(text, "linuxcnc", name, reader="rs274")
    assert tip_error(m, fig, OP) < 1e-3                         # the planned points are still exact
    dev = centre_deviation(m, fig, OP)
    assert dev.max() > 3 * TOL                                  # but between them the ball wanders off
    # on the cuts alone, too (not only the rapid between the rings)
    cut = np.isin(m.line, fig["line"][OP.use[fig["move"]] == USE_CUT])
    assert centre_deviation(m, fig, OP)[cut[np.isin(m.line, fig["line"])]].max() > TOL


@pytest.mark.parametrize("name", PROFILES)
def test_iso_tcp_program_through_the_reader(posted, name):
    text, [fig] = posted[name, "iso"]
    m = read(text, "iso", name)
    assert tip_error(m, fig, OP) < 1e-3
    assert centre_deviation(m, fig, OP).max() < TOL + 1e-3
    assert check_travel(m, name) == []
    assert fig["max_deviation_unlinearised_mm"] > TOL         # the rapid between the rings needed points
    # the programmed X Y Z are the planned tips (part frame) at the planned points
    planned = np.flatnonzero(fig["u"] == 1.0)
    lines = text.splitlines()
    xyz = np.array([[float(re.search(rf"{k}(-?[\d.]+)", lines[ln - 1]).group(1)) for k in "XYZ"]
                    for ln in fig["line"][planned]])
    tips = OP.centre_mm - R * OP.axis
    assert np.abs(xyz - tips[fig["move"][planned]]).max() < 1e-4


def test_program_layout_and_inverse_time_feeds(posted):
    text, [fig] = posted["compact_trunnion_bc", "linuxcnc"]
    lines = text.splitlines()
    assert "signs: B as planned, C as planned" in text
    assert lines.index("G21 G90 G94 G17 G40 G49 G80") < lines.index("G64 P0.002") < lines.index("G54")
    assert lines[-2:] == ["G53 G0 B0 C0", "M30"]
    blocks = [lines[ln - 1] for ln in fig["line"]]
    for b in blocks:                                            # every block: X Y Z and both rotary words
        assert all(re.search(rf"\b{k}-?[\d.]+", b) for k in "XYZBC"), b
    feed = [b for b in blocks if "G1" in b.split()]
    assert feed and all(re.search(r"F[\d.]+$", b) for b in feed)
    assert blocks[1].startswith("G93 G1")                      # the plunge opens inverse time
    rapid_after = [b for b in blocks if b.startswith("G94 G0")]
    assert len(rapid_after) == 1                               # the rapid between the two rings
    assert lines[lines.index(blocks[-1]) + 1] == "G94"
    # F = 1 / time, time = tip length / feed, at least each axis's turn over the profile's limit for it
    # (B 5400, C 7200 deg/min on this profile) (1/min), rounded down to the 3 decimals
    lim = (5400.0, 7200.0)
    assert fig["feed_limits_deg_min"] == lim
    tips, ang = fig["tip_mm"], fig["angles_deg"]
    n_tip = 0
    for k in np.flatnonzero(OP.kind[fig["move"]] == FEED):
        L = np.linalg.norm(tips[k] - tips[k - 1])
        dt, dc = np.abs(ang[k] - ang[k - 1])
        feed = 500.0 if OP.use[fig["move"][k]] == USE_PLUNGE else 1500.0
        F = float(re.search(r"F([\d.]+)", blocks[k]).group(1))
        exact = 1.0 / max(L / feed, dt / lim[0], dc / lim[1], MIN_MOVE_TIME_MIN)
        assert exact - 1e-3 - 1e-9 <= F <= exact + 1e-9
        n_tip += L / feed > max(dt / lim[0], dc / lim[1])
    assert n_tip > 10                                          # most moves: the feed of the tip
    # ISO: G43.4 once per operation, G94 F of the tip, rotary homes at the end
    iso, _ = posted["compact_trunnion_bc", "iso"]
    assert re.search(r"^G0 G43\.4 H1 X", iso, re.MULTILINE) and "G93" not in iso
    assert "G91 G28 B0. C0." in iso and iso.rstrip().endswith("M30\n%")


def test_a_move_that_only_turns_gets_its_time_from_the_rotary_feed():
    p = load_profile("compact_trunnion_bc")
    tip = np.array([10.0, 0.0, 20.0])
    a0 = tool_axis_from_angles([30.0, 0.0], p)[0]
    a1 = tool_axis_from_angles([30.0, 20.0], p)[0]
    c = np.array([tip + 10 * R * a0, tip + R * a0, tip + R * a1])       # approach, plunge, turn about the tip
    op = FiveAxisOperation("turn", c, np.array([a0, a0, a1]), np.array([RAPID, FEED, FEED], np.int8),
                           np.array([USE_RAPID, USE_PLUNGE, USE_CUT], np.int8), 1, R, 8000.0, 1500.0, 500.0, GAUGE)
    w = BlockWriter(PostOptions())
    fig = linuxcnc_5axis_blocks(w, PostOptions(), op, p, PLACE, linearise=False, rotary_feed_deg_min=600.0)
    last = w.lines[fig["line"][-1] - 1]
    assert float(re.search(r"F([\d.]+)", last).group(1)) == pytest.approx(600.0 / 20.0, rel=1e-6)


def test_flipped_rotary_signs_read_back_the_same(posted):
    require_rs274()
    name = "compact_trunnion_bc"
    text, [fig] = linuxcnc_5axis_program(OP, profile=name, placement_mm=PLACE, return_figures=True,
                                         options=PostOptions(rotary_sign=(-1, -1)))
    assert "signs: B flipped, C flipped" in text
    for reader in (None, "rs274"):
        m = read(text, "linuxcnc", name, reader=reader)
        assert tip_error(m, fig, OP) < 1e-3 and centre_deviation(m, fig, OP).max() < TOL + 1e-3


def test_two_operations_in_one_program():
    require_rs274()
    name = "fork_head_ac"
    op2 = hemisphere_op(rings=(30.0,), th=(200.0, 260.0))
    for post, dialect in ((linuxcnc_5axis_program, "linuxcnc"), (iso_5axis_program, "iso")):
        text, figs = post([OP, op2], profile=name, placement_mm=PLACE, return_figures=True)
        assert len(figs) == 2
        readers = (None, "rs274") if dialect == "linuxcnc" else (None,)
        for reader in readers:
            m = read(text, dialect, name, reader=reader)
            for op, fig in zip((OP, op2), figs):
                assert tip_error(m, fig, op) < 1e-3 and centre_deviation(m, fig, op).max() < TOL + 1e-3
            assert check_travel(m, name) == []


def test_travel_excursion_is_reported_on_the_program_line():
    name = "compact_trunnion_bc"
    place = PLACE + np.array([0.0, 0.0, 400.0])                    # the part far too high: Z beyond its limit
    text, [fig] = linuxcnc_5axis_program(OP, profile=name, placement_mm=place, return_figures=True)
    m = read_program(text, dialect="linuxcnc", program="t", area=0, profile=name, placement_mm=place, tools=TOOLS)
    found = check_travel(m, name)
    assert found and {f["axis"] for f in found} <= {"X", "Y", "Z"}
    assert set(fig["line"].tolist()) & {f["line"] for f in found}


def meridian_op(off_deg: float, half_deg: float = 25.0) -> FiveAxisOperation:
    """A pass over the top of the hemisphere passing ``off_deg`` from its pole, the tool axis along
    the normal: through (0) or beside the pole cone of the rotary axis."""
    s = np.radians(np.linspace(-half_deg, half_deg, 51))
    off = math.radians(off_deg)
    n = np.stack([np.sin(s) * math.cos(off), np.full_like(s, math.sin(off)), np.cos(s) * math.cos(off)], 1)
    n /= np.linalg.norm(n, axis=1)[:, None]
    c = (SPHERE + R) * n
    return FiveAxisOperation("over the pole", np.array([c[0] + 10 * n[0], *c, c[-1] + 10 * n[-1]]),
                             np.array([n[0], *n, n[-1]]), np.array([RAPID] + [FEED] * (len(c) + 1), np.int8),
                             np.array([USE_RAPID, USE_PLUNGE] + [USE_CUT] * (len(c) - 1) + [USE_RETRACT], np.int8),
                             1, R, 10000.0, 1500.0, 500.0, GAUGE)


@pytest.mark.parametrize("off", [0.0, 0.2])
@pytest.mark.parametrize("name", PROFILES)
def test_pass_over_the_pole_is_posted_and_read_back(name, off):
    require_rs274()
    op = meridian_op(off)
    cone_pts = np.degrees(np.arccos(np.clip(op.axis[:, 2], -1, 1))) < 0.5
    for post, dialect, reader in ((linuxcnc_5axis_program, "linuxcnc", "rs274"), (iso_5axis_program, "iso", None)):
        text, [fig] = post(op, profile=name, placement_mm=PLACE, return_figures=True)
        assert fig["n_pole"] == cone_pts.sum() > 0
        assert np.ptp(fig["angles_deg"][:, 1]) < (1e-9 if off == 0 else 90.0)   # C stands still through the pole
        m = read(text, dialect, name, reader=reader)
        assert centre_deviation(m, fig, op).max() < TOL + 1e-3, dialect
        # the tip is the planned one outside the cone; inside it the axis is the nearest with C held
        planned = np.flatnonzero(fig["u"] == 1.0)
        e = ends_of(m, fig["line"][planned])
        err = np.linalg.norm(m.end_mm[e] - (op.centre_mm - R * op.axis)[fig["move"][planned]], axis=1)
        inside = cone_pts[fig["move"][planned]]
        assert err[~inside].max() < 1e-3
        assert err[inside].max() < R * math.radians(0.5) + 1e-3
        assert (err[inside].max() < 1e-3) == (off == 0.0)


def test_a_rotary_flip_on_the_surface_is_refused():
    # A -120..+30 on the A/C trunnion: the pass over the pole runs into A+30 and the other solution
    # (A-30, C turned 180 degrees) is needed between two points of the cut
    with pytest.raises(ParameterError, match="rotary solution at a travel limit"):
        linuxcnc_5axis_program(meridian_op(0.2, half_deg=31.0), profile="compact_trunnion_ac", placement_mm=PLACE)


def beside_the_pole_op() -> FiveAxisOperation:
    """One 18 mm cut whose tool axis turns 62 degrees, from B55.8 to B6.8 on the B/C trunnion, its arc
    passing about 3 degrees from the pole: C turns 152 degrees, most of it in the move's last fifth
    (a step down a wall of the range femur, issue 33, whose post failed)."""
    a0, a1 = np.array([-0.4306, -0.7059, 0.5625]), np.array([0.1024, 0.0602, 0.9929])
    a0, a1 = a0 / np.linalg.norm(a0), a1 / np.linalg.norm(a1)
    c0, c1 = np.array([0.0, -9.0, SPHERE + R + 5.0]), np.array([0.0, 9.0, SPHERE + R - 1.0])
    return FiveAxisOperation("beside the pole", np.array([c0 + 10 * a0, c0, c1, c1 + 10 * a1]),
                             np.array([a0, a0, a1, a1]), np.array([RAPID, FEED, FEED, FEED], np.int8),
                             np.array([USE_RAPID, USE_PLUNGE, USE_CUT, USE_RETRACT], np.int8),
                             1, R, 10000.0, 1500.0, 500.0, GAUGE)


def test_a_turn_beside_the_pole_keeps_the_branch_of_both_ends():
    # the points inserted into the cut take the solution on the ends' side of the pole (B > 0): a
    # reference interpolated between the ends' angles lies nearer the other branch for part of the move,
    # which broke the posted path into halves that no halving could join
    require_rs274()
    op = beside_the_pole_op()
    name = "compact_trunnion_bc"
    for post, dialect, reader in ((linuxcnc_5axis_program, "linuxcnc", "rs274"), (iso_5axis_program, "iso", None)):
        text, [fig] = post(op, profile=name, placement_mm=PLACE, return_figures=True)
        on_cut = fig["move"] == 2
        assert on_cut.sum() > 8 and (fig["angles_deg"][on_cut, 0] > 0).all()
        assert np.ptp(fig["angles_deg"][on_cut, 1]) > 140.0
        assert fig["max_deviation_mm"] <= TOL
        m = read(text, dialect, name, reader=reader)
        assert centre_deviation(m, fig, op).max() < TOL + 1e-3, dialect
        assert tip_error(m, fig, op) < 1e-3, dialect


# ------------------------------------------------------------------------------------------------
# the readers' new words


def test_reader_g93_needs_f_on_every_feed_block():
    base = ["G21 G90 G94", "T1 M6", "G43 H1", "G0 X0 Y0 Z50 B0 C0"]
    kw = {"program": "t", "area": 0, "profile": "compact_trunnion_bc", "placement_mm": PLACE, "tools": TOOLS}
    ok = read_program("\n".join(base + ["G93 G1 X1 B1 C1 F100", "G1 X2 F100", "G94 G0 Z60", "M30"]),
                      dialect="linuxcnc", **kw)
    assert ok.n_moves > 3
    for tail, where in ((["G93 G1 X1 B1 C1 F100", "G1 X2 B2"], 6), (["G93 G1 X1 B1 C1 F100", "G1 X2"], 6),
                        (["G93 G1 X1 B1 C1"], 5), (["G1 X1 F100", "G93", "G1 X2"], 7),
                        (["G93 G1 X1 F10", "G94", "G1 X2"], 7)):
        with pytest.raises(ProgramError, match="F") as e:
            read_program("\n".join(base + tail + ["M30"]), dialect="linuxcnc", **kw)
        assert e.value.details["line"] == where, tail


def test_reader_g43_4_is_iso_only_and_not_with_a_tilted_plane():
    kw = {"program": "t", "area": 0, "profile": "compact_trunnion_bc", "placement_mm": PLACE, "tools": TOOLS}
    with pytest.raises(ProgramError, match="G43.4"):
        read_program("G21\nT1 M6\nG0 G43.4 H1 X0 Y0 Z10 B0 C0\n", dialect="linuxcnc", **kw)
    with pytest.raises(ProgramError, match="G68.2"):
        read_program("G21\nT1 M6\nG68.2 X0 Y0 Z0 I0 J30 K0\nG53.1\nG43.4 H1\n", dialect="iso", **kw)
    with pytest.raises(ProgramError, match="G68.2"):
        read_program("G21\nT1 M6\nG43.4 H1\nG68.2 X0 Y0 Z0 I0 J30 K0\n", dialect="iso", **kw)
    with pytest.raises(ProgramError, match="G43.4"):                 # rotary words need TCP
        read_program("G21\nT1 M6\nG43 H1\nG0 X0 Y0 Z10 B10. C0\n", dialect="iso", **kw)
    # TCP: a pure rotary turn keeps the tip where it is, the machine position moves
    m = read_program("G21\nT1 M6\nG0 G43.4 H1 X10. Y0 Z20.\nG1 B30. C45. F500\nG49\nM30\n", dialect="iso", **kw)
    turn = m.line == 4
    assert turn.sum() == 45 and np.abs(m.end_mm[turn] - [10.0, 0.0, 20.0]).max() < 1e-9
    assert np.abs(m.rotary_deg[turn][-1] - [30.0, 45.0]).max() < 1e-12
    assert np.ptp(m.machine_mm[turn], axis=0).max() > 5.0


def test_the_3_plus_2_iso_post_takes_a_simultaneous_operation_only_with_the_profile_and_placement():
    from planning.post import iso_program
    from planning.toolpath.frames import AreaFrame

    frame = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
    with pytest.raises(ParameterError, match="needs the machine profile and the placement"):
        iso_program([], frame, tool_axis=[0, 0, 1], five_axis=[OP])
    with pytest.raises(ParameterError, match="needs the machine profile and the placement"):
        iso_program([], frame, tool_axis=[0, 0, 1], profile=PROFILES[0], five_axis=[OP])
    text = iso_program([], frame, tool_axis=[0, 0, 1], profile=PROFILES[0], placement_mm=PLACE, five_axis=[OP])
    assert text.count("G43.4") == 1
    with pytest.raises(ParameterError, match="at least one operation"):
        iso_program([], frame, tool_axis=[0, 0, 1], profile=PROFILES[0], placement_mm=PLACE)
