"""The 5-axis guard runs the moves the posted LinuxCNC program makes (issue 33,
planning/toolpath/fiveaxis/program_moves.py): against the verification's own reader on the posted
text, on a path whose C winds far enough to be turned back at machine Z0 between passes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from planning.post.options import PostOptions
from planning.post.simultaneous import (
    FiveAxisOperation,
    linuxcnc_5axis_program,
    unwind_deg,
)
from planning.simulate.motion import ToolShape
from planning.simulate.program import read_program
from planning.toolpath.fiveaxis.program_moves import program_part_moves
from planning.toolpath.fiveaxis.register import air_moves
from planning.toolpath.frames import AreaFrame
from planning.toolpath.guard import part_moves
from planning.toolpath.moves import USE_CUT, USE_PLUNGE, USE_RAPID, USE_RETRACT, lines

R = 3.0
SAFE = 40.0
PROFILE = "compact_trunnion_bc"
PLACE = np.array([0.0, 0.0, 60.0])
SHAPE = ToolShape(number=1, kind="ball", radius_mm=R, corner_radius_mm=R, flute_length_mm=12.0,
                  pieces=((12.0, 40.0, 4.0), (40.0, 90.0, 16.0)), gauge_length_mm=115.0)
FEEDS = {"feed_mm_min": 1500.0, "plunge_mm_min": 500.0, "spindle_rpm": 12000.0}


def _winding_path(n_passes: int):
    """Passes round a ring (ball centres at radius 20, z 0), the axis leaning 20 degrees out towards
    the ball: each pass turns C once more the same way; between passes up to the safe height and down."""
    frame = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
    phi = np.radians(np.arange(0.0, 361.0, 10.0))
    ring = np.stack([20.0 * np.cos(phi), 20.0 * np.sin(phi), np.zeros_like(phi)], axis=1)
    lean = np.radians(20.0)
    ax_ring = np.stack([np.sin(lean) * np.cos(phi), np.sin(lean) * np.sin(phi), np.full_like(phi, np.cos(lean))], axis=1)
    xyz, axes, use = [], [], []
    for _ in range(n_passes):
        xyz += [ring[0] + [0, 0, SAFE], ring[0] + [0, 0, 2.0]]
        axes += [ax_ring[0], ax_ring[0]]
        use += [USE_RAPID, USE_PLUNGE]
        xyz += list(ring)
        axes += list(ax_ring)
        use += [USE_CUT] * len(ring)
        xyz += [ring[-1] + [0, 0, 2.0], ring[-1] + [0, 0, SAFE]]
        axes += [ax_ring[-1], ax_ring[-1]]
        use += [USE_RETRACT, USE_RAPID]
    tp = dataclasses.replace(lines(np.array(xyz), np.array(use), tip_offset_mm=R), axis=np.array(axes))
    return tp, frame


def _options() -> PostOptions:
    return PostOptions(safe_z_mm=SAFE - R, decimals=4)


def _operation(tp, frame):
    return FiveAxisOperation(name="finishing 5-axis", centre_mm=frame.to_part(tp.xyz_mm), axis=tp.axis @ frame.rotation,
                             kind=tp.kind.copy(), use=tp.use.copy(), tool_number=1, radius_mm=R,
                             gauge_length_mm=SHAPE.gauge_length_mm, unwind=air_moves(tp, SAFE), **FEEDS)


def _program_moves(tp, frame, options):
    return program_part_moves(_operation(tp, frame), profile=PROFILE, placement_mm=PLACE, options=options)


def _reader_moves(tp, frame, options):
    """The posted text read by the verification's reader, from the approach point (the block before the
    first posted point: the way down to it from the tool change is not the path's) to the last point."""
    op = _operation(tp, frame)
    text, figs = linuxcnc_5axis_program([op], profile=PROFILE, placement_mm=PLACE, options=options,
                                        return_figures=True)
    motion = read_program(text, dialect="linuxcnc", program="t", area=0, profile=PROFILE, placement_mm=PLACE,
                          tools={1: SHAPE})
    first, last = int(figs[0]["line"][0]), int(figs[0]["line"][-1])
    keep = (motion.line >= first) & (motion.line <= last)
    return text.splitlines()[first - 1:last], motion, keep


@pytest.mark.parametrize("n_passes", [3, 12])
def test_the_guards_moves_are_the_readers_moves_of_the_posted_program(n_passes):
    tp, frame = _winding_path(n_passes)
    options = _options()
    blocks, motion, keep = _reader_moves(tp, frame, options)
    got = _program_moves(tp, frame, options)
    assert got.start.shape[0] == int(keep.sum())
    np.testing.assert_allclose(got.start, motion.start_mm[keep], atol=1e-9)
    np.testing.assert_allclose(got.end, motion.end_mm[keep], atol=1e-9)
    np.testing.assert_allclose(got.axis, motion.axis[keep], atol=1e-12)
    assert np.array_equal(got.kind, motion.kind[keep])
    # every step belongs to a planned move, in order, and every planned move after the first has steps
    assert (np.diff(got.source) >= 0).all() and set(got.source.tolist()) == set(range(tp.n_moves))
    turned_back = "G53 G0 Z0" in blocks
    # 12 passes turn C by 12 x 360 degrees, beyond the register: C is turned back at machine Z0 there,
    # and both read the climb to the top of the Z travel
    assert turned_back == (n_passes * 360.0 > unwind_deg(PROFILE))
    if turned_back:
        assert np.abs(motion.rotary_deg[keep][:, 1]).max() <= unwind_deg(PROFILE) + 360.0
        assert got.end[:, 2].max() > 300.0


def test_the_planned_moves_differ_from_the_program_where_the_axis_turns():
    """Why the guard needs the program's moves: the planned straight moves (each step with its end's
    axis along the great circle) put the tool elsewhere than the program's joint-space steps between
    the planned points (here, 10-degree turns per move: the flutes' top, 12 mm up the axis, lies about
    0.004 mm off the planned steps' sweep), while both end every planned move at its planned ball centre."""
    tp, frame = _winding_path(3)
    prog = _program_moves(tp, frame, _options())
    plan = part_moves(tp, frame)
    assert prog.start.shape[0] > 2 * plan.start.shape[0]           # the post's inserted points
    last_prog = np.r_[prog.source[1:] != prog.source[:-1], True]
    last_plan = np.r_[plan.source[1:] != plan.source[:-1], True]
    np.testing.assert_allclose(prog.end[last_prog] + R * prog.axis[last_prog],
                               plan.end[last_plan] + R * plan.axis[last_plan], atol=2e-4)
    # the flutes' top at every program step end, against the planned steps of the same move
    top = prog.end + 12.0 * prog.axis
    off = np.full(top.shape[0], np.inf)
    a, b = plan.start + 12.0 * plan.axis, plan.end + 12.0 * plan.axis
    for k in range(plan.start.shape[0]):
        mine = np.flatnonzero(prog.source == plan.source[k])
        v = b[k] - a[k]
        t = np.clip((top[mine] - a[k]) @ v / max(float(v @ v), 1e-30), 0.0, 1.0)
        off[mine] = np.minimum(off[mine], np.linalg.norm(top[mine] - (a[k] + t[:, None] * v), axis=1))
    cut = prog.kind == 1
    assert 1e-3 < off[cut].max() < 0.05


@pytest.mark.parametrize("decimals", [4, 8])
def test_the_printed_values_are_the_posts_strings_read_back(decimals):
    """The numbers the guard moves through are the post's words read back (fmt: Python's decimal
    rounding), also at the half units where numpy's own rounding goes the other way."""
    from planning.post.blocks import fmt
    from planning.post.simultaneous import _as_printed

    rng = np.random.default_rng(decimals)
    half = 0.5 * 10.0 ** -decimals
    v = np.concatenate([rng.uniform(-500, 500, 20000),
                        np.round(rng.uniform(-500, 500, 5000), decimals) + half])
    want = np.array([float(fmt(x, decimals)) for x in v])
    assert np.array_equal(_as_printed(v, decimals), want)


@pytest.mark.parametrize("decimals", [0, 3, 4, 8])
def test_the_posts_batch_formatter_writes_what_fmt_writes(decimals):
    """fmt_many (the 5-axis posts' columns of numbers) gives fmt's strings, the points, the trailing
    zeros and the zeros' sign included."""
    from planning.post.blocks import fmt, fmt_many

    rng = np.random.default_rng(decimals + 1)
    v = np.concatenate([rng.uniform(-2000, 2000, 5000), np.round(rng.uniform(-5, 5, 2000), decimals)
                        + 0.5 * 10.0 ** -decimals, [0.0, -0.0, -1e-9, 1e-9, 100.0, -100.0, 0.5, -0.5, 1e12]])
    assert fmt_many(v, decimals) == [fmt(x, decimals) for x in v.tolist()]
