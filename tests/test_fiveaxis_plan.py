"""Simultaneous 5-axis finishing through the whole plan (issue 19): a deep narrow slot no fixed axis
finishes, finished from one set-up with an axis per position, verified on the simulated machine and
read back by LinuxCNC's interpreter."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from planning.inputs import Cloud, samples
from planning.pipeline import run_plan
from planning.simulate.program import check_travel, read_program
from planning.simulate.rs274 import INSTALL_HINT, rs274_available, run_rs274
from planning.simulate.verify import tool_shapes
from planning.toolpath.fiveaxis.axes import contact_normals, turn_deg
from planning.toolpath.moves import FEED, USE_CUT
from planning.visibility.five_axis import five_axis_visibility
from schemas.params import apply_overrides, parse_config

CONE = (10.0, 45.0)
SETS = [f"visibility.cone_deg=[{CONE[0]},{CONE[1]}]", "normals.method=input", "paths.finishing.scallop_mm=0.2",
        "paths.roughing.step_down_mm=5", "simulate.resolution_mm=1.0"]


def _slot():
    return samples.draft_slot(density_per_mm2=1.0, seed=1, include_sides=False)


def _plan(mode: str, max_setups: int, extra=()):
    s = _slot()
    cfg = parse_config(apply_overrides({}, SETS + [f"paths.finishing.mode={mode}",
                                                   f"setups.max_setups={max_setups}", *extra]))
    return s, cfg, run_plan(Cloud(points=s.points, normals=s.normals, source_format="generated"), cfg, name="draft_slot")


@pytest.fixture(scope="module")
def five():
    return _plan("5axis", 1)


def test_no_fixed_axis_has_the_floor_and_both_walls_in_its_cone():
    a = math.radians(_slot().meta["wall_deg"])
    normals = np.array([[0, 0, 1.0], [math.sin(a), 0, math.cos(a)], [-math.sin(a), 0, math.cos(a)]])
    # every axis of a fine near-uniform sampling of the sphere (about 0.5 degree apart)
    n = 200_000
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    th = math.pi * (1 + 5 ** 0.5) * i
    axes = np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], axis=1)
    ang = np.degrees(np.arccos(np.clip(axes @ normals.T, -1, 1)))
    in_cone = (ang >= CONE[0]) & (ang <= CONE[1])
    assert in_cone.any(axis=0).all()               # each face alone has axes
    assert not in_cone.all(axis=1).any()           # no axis has all three
    # the nearest miss is a whole 5 degrees: the two walls need the axis 70 - 45 = 25 deg each way
    assert (ang[:, 1:] - CONE[1]).clip(0).max(axis=1).min() > 5.0


def test_3_plus_2_from_one_set_up_cannot_cover_the_slot():
    _, _, out = _plan("3+2", 1, ["simulate.enabled=false", "paths.roughing.enabled=false",
                                 "paths.finishing.enabled=false"])
    assert out.result.status == "infeasible"
    assert out.result.selection.coverage < 0.8


def test_5_axis_finishes_the_slot_from_one_set_up_and_verifies_clean(five):
    s, cfg, out = five
    r = out.result
    # the set-up reaches the coverage; whether the programs finish that much of the scan is the status
    # ('unfinished' below setups.coverage: the inner corners no ball reaches, see below)
    assert r.selection.status == "optimal" and r.selection.k == 1 and r.coverage >= 0.95
    assert r.status == ("planned" if r.figures.finished_share >= 0.95 else "unfinished")
    v = r.verification
    assert v.status == "passed", v.message
    assert (v.rapids_into_material, v.holder_collisions, v.fixture_collisions, v.travel_excursions) == (0, 0, 0, 0)
    assert v.deviation.n_gouged == 0 and v.unreadable_programs == 0
    assert v.deviation.finished_share > 0.85
    # the floor and both walls are finished within tolerance, not just the top: every point a ball of
    # radius R can touch at all (the inner corners it cannot: the ball in the corner touches the floor
    # at |x| = w/2 - R (1 - cos a) / sin a and the wall at z = floor + R (1 - cos a)), 0.3 mm margin
    dev = out.extra["simulation"].deviation_mm
    limit = cfg.paths.finishing.tolerance_mm + cfg.paths.finishing.scallop_mm + v.measuring_bound_mm
    lab, names = s.meta["labels"], s.meta["label_names"]
    R, a, zf = cfg.tool.diameter_mm / 2, math.radians(s.meta["wall_deg"]), s.meta["floor_z_mm"]
    x_reach = s.meta["floor_width_mm"] / 2 - R * (1 - math.cos(a)) / math.sin(a)
    reach = {"slot_floor": np.abs(s.points[:, 0]) < x_reach - 0.3,
             "slot_wall": s.points[:, 2] > zf + R * (1 - math.cos(a)) + 0.3}
    for face in ("slot_floor", "slot_wall"):
        on = (lab == names.index(face)) & reach[face]
        for side in (s.points[:, 0] < 0, s.points[:, 0] > 0):
            share = float((np.abs(dev[on & side]) <= limit).mean())
            assert share > 0.85, (face, share)
    fin = r.setups[0].path.finishing
    assert fin.mode == "5axis" and fin.five_axis is not None and fin.gouge_free and fin.holder_collisions == 0


def test_every_position_s_axis_is_in_the_cone_within_the_swing_and_under_the_rate(five):
    s, cfg, out = five
    fp = cfg.paths.finishing
    ap = out.extra["area_paths"][0]
    tp = ap.finishing
    touch = (tp.kind == FEED) & (tp.use == USE_CUT)
    idx = np.flatnonzero(touch)
    centres_p = ap.frame.to_part(tp.xyz_mm[idx])
    axes_p = tp.axis[idx] @ ap.frame.rotation
    nrm = contact_normals(centres_p, s.points)
    ang = turn_deg(axes_p, nrm)
    # the cone about the contact normal (a little slack: the normal is read from the nearest scan point)
    assert ang.min() >= CONE[0] - 1.0 and ang.max() <= CONE[1] + 1.0
    assert np.degrees(np.arccos(tp.axis[idx, 2].min())) <= fp.max_swing_deg + 1e-9
    pair = np.flatnonzero(touch[1:] & touch[:-1]) + 1
    d = np.linalg.norm(tp.xyz_mm[pair] - tp.xyz_mm[pair - 1], axis=1)
    turn = turn_deg(tp.axis[pair], tp.axis[pair - 1])
    assert (turn <= fp.max_axis_rate_deg_per_mm * d + 1e-6).all()
    # the axes really vary: they follow the floor and the two walls
    assert np.ptp(axes_p[:, 0]) > 0.8
    f5 = out.result.setups[0].path.finishing.five_axis
    assert f5.biarc_max_error_mm <= fp.tolerance_mm + 1e-9
    assert f5.biarc_min_clearance_mm >= cfg.tool.diameter_mm / 2 - fp.tolerance_mm - 1e-9
    assert 0 < f5.n_arcs < f5.n_moves_before_biarcs


def _planned_tips(out, cfg):
    ap = out.extra["area_paths"][0]
    tp = ap.finishing
    touch = (tp.kind == FEED) & (tp.use == USE_CUT)
    R = cfg.tool.diameter_mm / 2
    return ap.frame.to_part(tp.xyz_mm[touch] - R * tp.axis[touch])


@pytest.mark.skipif(not rs274_available(), reason=INSTALL_HINT)
def test_rs274_reads_the_5_axis_program_and_its_tips_are_the_planned_ones(five):
    s, cfg, out = five
    prog = out.extra["programs"]["area_0.linuxcnc.nc"]
    assert "G93" in prog
    gv_place = out.result.visibility.placement_mm
    tools = tool_shapes(cfg, cfg.tool.assembly())
    motion = run_rs274(prog, program="area_0.linuxcnc.nc", area=0, profile=cfg.machine.profile,
                       placement_mm=gv_place, tools=tools)
    assert check_travel(motion, cfg.machine.profile) == []
    fin = motion.tool == cfg.post.finishing_tool_number
    ends = motion.end_mm[fin & (motion.kind == 1)]
    planned = _planned_tips(out, cfg)
    d, _ = cKDTree(ends).query(planned)
    assert d.max() <= 0.001, d.max()
    # and the text reader runs the same program to the same tips
    text = read_program(prog, dialect="linuxcnc", program="area_0.linuxcnc.nc", area=0,
                        profile=cfg.machine.profile, placement_mm=gv_place, tools=tools)
    d2, _ = cKDTree(text.end_mm[(text.tool == cfg.post.finishing_tool_number) & (text.kind == 1)]).query(planned)
    assert d2.max() <= 0.001


def test_the_slot_program_turns_c_back_between_passes_and_keeps_to_the_rotary_limits(five):
    """Issue 33 item 3: the slot's passes each swing C half a turn the same way round the pole, so
    the walk alone winds C up beyond the profile's register (ten turns); the program's C stays within
    it, and its feed moves turn the axes no faster than the profile allows."""
    import re

    from planning.post.simultaneous import rotary_path
    from planning.simulate.rotary_speed import rotary_feed_excesses
    from planning.simulate.verify import move_minutes

    s, cfg, out = five
    ap = next(a for a in out.extra["area_paths"] if a.finishing is not None and a.finishing.axis is not None)
    walk, _ = rotary_path(ap.finishing.axis @ ap.frame.rotation, cfg.machine.profile)
    from planning.orientations.kinematics import as_profile

    reg = as_profile(cfg.machine.profile).rotary_limits_deg[1]
    assert np.abs(walk[:, 1]).max() > reg
    prog = out.extra["programs"]["area_0.linuxcnc.nc"]
    c = np.array([float(v) for v in re.findall(r"\bC(-?\d+(?:\.\d*)?)", prog)])
    assert np.abs(c).max() <= reg
    v = out.result.verification
    assert v.rotary_feed_excesses == 0
    motion = read_program(prog, dialect="linuxcnc", program="area_0.linuxcnc.nc", area=0,
                          profile=cfg.machine.profile, placement_mm=out.result.visibility.placement_mm,
                          tools=tool_shapes(cfg, cfg.tool.assembly()))
    assert rotary_feed_excesses(motion, move_minutes(motion, cfg), cfg.machine.profile) == []


def test_the_iso_program_drives_the_tool_tip_with_g43_4_to_the_planned_tips(five):
    s, cfg, out = five
    prog = out.extra["programs"]["area_0.iso.nc"]
    assert "G43.4" in prog
    tools = tool_shapes(cfg, cfg.tool.assembly())
    motion = read_program(prog, dialect="iso", program="area_0.iso.nc", area=0, profile=cfg.machine.profile,
                          placement_mm=out.result.visibility.placement_mm, tools=tools)
    assert check_travel(motion, cfg.machine.profile) == []
    ends = motion.end_mm[(motion.tool == cfg.post.finishing_tool_number) & (motion.kind == 1)]
    d, _ = cKDTree(ends).query(_planned_tips(out, cfg))
    assert d.max() <= 0.001, d.max()


def test_five_axis_visibility_matches_a_brute_force_reading_of_its_rule():
    rng = np.random.default_rng(5)
    n, m = 300, 40
    axes = rng.normal(size=(m, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    nrm = rng.normal(size=(n, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    vis = rng.random((n, m)) < 0.08
    swing = 50.0
    got = five_axis_visibility(vis, axes, nrm, swing)
    want = np.zeros((n, m), dtype=bool)
    for i in range(n):
        for j in range(m):
            facing = math.degrees(math.acos(np.clip(nrm[i] @ axes[j], -1, 1))) <= swing
            near = [k for k in range(m) if math.degrees(math.acos(np.clip(axes[k] @ axes[j], -1, 1))) <= swing]
            want[i, j] = facing and bool(vis[i, near].any())
    assert np.array_equal(got, want)
    assert got.sum() > vis.sum() // 4          # a real mix of both outcomes
    # a pass direction the machine cannot present at the point itself (out of travel) finishes nothing there
    along = rng.random((n, m)) < 0.5
    got_along = five_axis_visibility(vis, axes, nrm, swing, along=along)
    assert np.array_equal(got_along, want & along)
    assert 0 < got_along.sum() < got.sum()


def test_an_axis_turn_is_kept_off_the_rotary_pole_along_its_whole_arc():
    from planning.toolpath.fiveaxis.axes import slerp
    from planning.toolpath.fiveaxis.finishing import Admissible

    ad = Admissible.__new__(Admissible)          # only the pole test: no cloud, no machine needed
    ad.pole_f = np.array([0.0, 0.0, 1.0])
    ad.cos_pole = math.cos(math.radians(3.0))
    rng = np.random.default_rng(9)
    a0 = rng.normal(size=(4000, 3)) + [0, 0, 6]
    a1 = rng.normal(size=(4000, 3)) + [0, 0, 6]
    a0 /= np.linalg.norm(a0, axis=1, keepdims=True)
    a1 /= np.linalg.norm(a1, axis=1, keepdims=True)
    got = ad.arc_clear_of_pole(a0, a1)
    # brute force: 2001 points along each great-circle arc
    closest = np.full(4000, -1.0)
    for f in np.linspace(0, 1, 2001):
        closest = np.maximum(closest, slerp(a0, a1, f)[:, 2])
    want = closest < ad.cos_pole
    sure = np.abs(np.degrees(np.arccos(np.clip(closest, -1, 1))) - 3.0) > 0.01   # not on the boundary
    assert np.array_equal(got[sure], want[sure])
    assert 0.05 < got.mean() < 0.95


@pytest.mark.parametrize("leave", [[1, 0, 1], [2, 0, 1]], ids=["straight_retract", "lead_out_ramp"])
def test_the_way_out_keeps_the_axis_of_the_point_it_leaves(leave):
    from planning.toolpath.fiveaxis.finishing import _fill_axes
    from planning.toolpath.moves import USE_RAPID, USE_RETRACT, lines

    # cut, cut, a retract (straight up or a 45-degree lead-out), the rapid up over its end to the safe
    # height, the rapid across, the rapid down, cut
    xyz = np.array([[0, 0, 0], [1, 0, 0], leave, [leave[0], 0, 10], [5, 0, 10], [5, 0, 0.0], [6, 0, 0]], float)
    use = np.array([USE_RAPID, USE_CUT, USE_RETRACT, USE_RAPID, USE_RAPID, USE_RAPID, USE_CUT])
    tp = lines(xyz, use, tip_offset_mm=3.0)
    touch = (tp.kind == FEED) & (tp.use == USE_CUT)
    a_first, a_last = np.array([0.0, 0.6, 0.8]), np.array([0.6, 0.0, 0.8])
    out = _fill_axes(tp, touch, np.array([a_first, a_last]))
    assert np.allclose(out[1:4], a_first)        # the retract and the rapid up to the safe height
    assert np.allclose(out[4:], a_last)          # the rapid across turns the axis; down and on


def test_the_same_scan_gives_the_same_5_axis_plan(five):
    # the default run's determinism check (test_pipeline's femur one is slow): programs and arrays equal
    _, _, again = _plan("5axis", 1)
    _, _, first = five
    assert first.extra["programs"] == again.extra["programs"]
    assert set(first.arrays) == set(again.arrays)
    for key in first.arrays:
        assert np.array_equal(first.arrays[key], again.arrays[key]), key


def test_the_cli_slot_from_two_set_ups_keeps_c_within_its_register(tmp_path):
    """A new user's 5-axis plan (the bundled draft_slot sample, written and planned by the CLI, two
    set-ups): the finishing of set-up 0 winds C by whole turns (the passes go round the rotary pole
    the same way), so links must be routed through the safe height where the post turns C back.
    The guard cuts and relinks that finishing after the routing; it used to replan those links lower
    (it had no pass index to route them again) and the program wound C to -5,878 degrees, far outside
    the +-3,600 register. Every C word of every posted program lies within the register, and the
    finishing that winds turns C back at machine Z0 (``G53 G0 Z0`` between its moves)."""
    import re

    from planning.orientations.kinematics import load_profile
    from scanmill.cli import main

    ply, out = tmp_path / "slot.ply", tmp_path / "plan"
    assert main(["sample", "draft_slot", "--out", str(ply)]) == 0
    main(["plan", str(ply), "--out", str(out), "--set", "paths.finishing.mode=5axis", "--set", "setups.max_setups=2",
          "--set", "simulate.enabled=false"])
    prof = load_profile("compact_trunnion_bc")
    limit = float(prof.rotary_limits_deg[1])
    turned_back = 0
    programs = sorted(out.glob("area_*.linuxcnc.nc"))
    assert len(programs) == 2
    for prog in programs:
        lines = prog.read_text().splitlines()
        start = next(i for i, ln in enumerate(lines) if ln.startswith("(operation") and "5-axis" in ln)
        c = np.array([float(m.group(1)) for ln in lines[start:]
                      for m in [re.search(r"\bC(-?\d+(?:\.\d*)?)", ln.split("(")[0])] if m])
        assert c.size > 1000, prog.name
        assert np.abs(c).max() <= limit, (prog.name, c.min(), c.max())
        homes = sum(ln.strip() == "G53 G0 Z0" for ln in lines[start + 2:-4])     # within the finishing
        if np.abs(c).max() > 360.0 * 2:
            assert homes >= 1, prog.name
        turned_back += homes
    assert turned_back >= 1                       # set-up 0's finishing needs C turned back
