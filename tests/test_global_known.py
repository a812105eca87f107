"""Known answers of the global visibility (Makki 2010 §2.2.4): slot floor, post beside a wall,
deep cavity with a holder, and the visibility stage of the pipeline on them."""

from __future__ import annotations

import numpy as np
import pytest

from planning.inputs import samples
from planning.geometry.collision import brute_force_collision_free, cloud_collision_free
from planning.orientations.candidates import candidate_axes
from planning.visibility.chain import global_visibility
from planning.orientations.kinematics import load_profile, machine_visibility
from planning.geometry.tool import Segment, ToolAssembly, ball_tool
from planning.visibility.cone import cone_visibility
from schemas.params import FixturesParams


def _bare(R, length=80.0):
    """A ball-end cutter with long flutes and nothing else (no holder)."""
    return ToolAssembly(R, (Segment(0.0, length, R, "cutter"),), 200.0)


def _tilted(ths_deg, sign=1.0):
    th = np.radians(np.asarray(ths_deg, float))
    return np.stack([sign * np.sin(th), np.zeros_like(th), np.cos(th)], 1)


def _edge(x, z, y0=-12.0, y1=12.0, step=0.05):
    y = np.arange(y0, y1 + 1e-9, step)
    return np.stack([np.full_like(y, x), y, np.full_like(y, z)], 1)


def _free_at(pts, p, n, axes, tool):
    pts = np.concatenate([pts, [p]])
    nrm = np.asarray([n], float)
    i = pts.shape[0] - 1
    fast = cloud_collision_free(pts, [i], nrm, axes, tool)[0]
    return fast


@pytest.mark.parametrize("w, h, R", [(12.0, 15.0, 3.0), (10.0, 20.0, 2.0), (16.0, 8.0, 5.0)])
def test_slot_floor_visible_only_within_derived_tilt(w, h, R):
    s = samples.slot(slot_width_mm=w, slot_depth_mm=h, density_per_mm2=2.0, seed=1)
    Z = s.meta["top_z_mm"]
    # the slot's top edges as exact lines (a jittered grid only approaches them)
    pts = np.concatenate([s.points, _edge(-w / 2, Z), _edge(w / 2, Z)])
    th_star = samples.slot_floor_max_tilt_deg(w, h, R)
    assert 0 < th_star < 90
    ths = np.concatenate([np.linspace(0, th_star - 0.3, 7), np.linspace(th_star + 0.3, 85, 7)])
    floor = np.array([0.0, 0.0, Z - h])
    for sign in (1.0, -1.0):
        free = _free_at(pts, floor, (0, 0, 1), _tilted(ths, sign), _bare(R))
        assert np.array_equal(free, ths < th_star), (sign, ths[free != (ths < th_star)])
    # tilting along the slot never meets a wall (through slot, long in y: the end is far away)
    along = np.stack([np.zeros(5), np.sin(np.radians([10, 20, 30, 40, 45])), np.cos(np.radians([10, 20, 30, 40, 45]))], 1)
    assert _free_at(pts, floor, (0, 0, 1), along, _bare(R, 10.0)).all()


def test_post_beside_wall_tilt_limits():
    s = samples.post_wall(density_per_mm2=2.0, seed=2)
    m = s.meta
    T, rp, gap = m["plate_top_z_mm"], m["post_radius_mm"], m["gap_mm"]
    xw, zw, zp = m["wall_face_x_mm"], m["wall_top_z_mm"], m["post_top_z_mm"]
    # exact features: the wall's top edge and the post rim point facing the gap
    pts = np.concatenate([s.points, _edge(xw, zw), [[rp, 0.0, zp]]])
    R = 2.0
    x = rp + gap / 2.0                        # the plate point midway in the gap
    p = np.array([x, 0.0, T])
    # towards the wall (+x): the wall's top edge; towards the post (-x): its rim
    th_wall = samples.slot_floor_max_tilt_deg(2 * (xw - x), zw - T, R)
    th_post = samples.slot_floor_max_tilt_deg(2 * (x - rp), zp - T, R)
    assert 0 < th_wall < th_post < 30
    for sign, th_star in ((1.0, th_wall), (-1.0, th_post)):
        ths = np.concatenate([np.linspace(0, th_star - 0.3, 6), np.linspace(th_star + 0.3, 80, 6)])
        free = _free_at(pts, p, (0, 0, 1), _tilted(ths, sign), _bare(R))
        assert np.array_equal(free, ths < th_star), (sign, th_star)
    # a tool wider than the gap cannot reach the point at all
    assert not _free_at(pts, p, (0, 0, 1), _tilted([0.0]), _bare(gap / 2 + 0.5)).any()


def _cavity(D=20.0, rc=6.0, seed=0):
    """A block top at z = D with a round pocket of radius rc and depth D (floor at z = 0)."""
    rng = np.random.default_rng(seed)
    g = np.arange(-30, 30.01, 0.5)
    X, Y = np.meshgrid(g, g)
    top = np.stack([X.ravel(), Y.ravel(), np.full(X.size, D)], 1)
    top = top[np.hypot(top[:, 0], top[:, 1]) >= rc]
    ph = np.linspace(0, 2 * np.pi, 120, endpoint=False)
    zz = np.arange(0.25, D + 1e-9, 0.5)
    P, Zz = np.meshgrid(ph, zz)
    wall = np.stack([rc * np.cos(P.ravel()), rc * np.sin(P.ravel()), Zz.ravel()], 1)
    r = np.sqrt(rng.uniform(0, (rc - 0.5) ** 2, 400))
    a = rng.uniform(0, 2 * np.pi, 400)
    floor = np.stack([r * np.cos(a), r * np.sin(a), np.zeros(400)], 1)
    return np.concatenate([top, wall, floor])


def test_deep_cavity_holder_collides_where_bare_cutter_does_not():
    D, rc, R = 20.0, 6.0, 3.0
    pts = _cavity(D, rc)
    p = np.array([0.0, 0.0, 0.0])
    up = np.array([[0.0, 0.0, 1.0]])
    # a bare cutter fits (R < rc) whatever its length
    assert _free_at(pts, p, (0, 0, 1), up, _bare(R, 100.0)).all()
    # a holder of radius 12 > rc: it enters the pocket, and hits the rim, iff the stick-out S < D
    # (the holder face is S above the floor, the rim D above it)
    for S, expect in ((D - 0.5, False), (D + 0.5, True)):
        tool = ball_tool(R, flute_length_mm=10.0, stickout_mm=S, holder=[(12.0, 40.0, None)])
        assert bool(_free_at(pts, p, (0, 0, 1), up, tool)[0]) is expect, S
    # same answer as the brute-force reference on tilted axes too
    tool = ball_tool(R, flute_length_mm=10.0, stickout_mm=15.0, holder=[(12.0, 40.0, None)])
    axes = _tilted(np.linspace(0, 40, 9))
    pts1 = np.concatenate([pts, [p]])
    i = pts1.shape[0] - 1
    assert np.array_equal(cloud_collision_free(pts1, [i], [[0, 0, 1.0]], axes, tool),
                          brute_force_collision_free(pts1, [i], [[0, 0, 1.0]], axes, tool))


def _slot_case(density, seed, every):
    """A slot sample, every ``every``-th point sampled, the machine-feasible axes of a 15/45 deg grid
    on the default trunnion, and the cone [10, 80] visibility."""
    s = samples.slot(density_per_mm2=density, seed=seed)
    idx = np.arange(0, s.points.shape[0], every)
    normals = s.normals[idx]
    prof = load_profile("compact_trunnion_bc")
    cand = candidate_axes("phi_theta", phi_step_deg=15, theta_step_deg=45)
    mv = machine_visibility(cand.axes, prof)
    axes, angles = cand.axes[mv.feasible], np.asarray(mv.angles_deg)[mv.feasible]
    return s, idx, normals, prof, axes, angles, cone_visibility(normals, axes, (10, 80))


def test_visibility_stage_counts_and_order():
    """global_visibility on the slot: the filters only remove pairs, their counts add up, and the
    travel filter follows the placement (a part placed far off the table is out of travel)."""
    s, idx, normals, prof, axes, angles, cone = _slot_case(0.5, 3, 3)
    tool = ball_tool(3.0, flute_length_mm=12.0, stickout_mm=30.0, holder=[(12.5, 45.0, None)])
    gv = global_visibility(s.points, idx, normals, axes, angles, cone, tool=tool, profile=prof,
                           fixtures_params=FixturesParams())
    assert not np.any(gv.visible & ~cone)
    removed = sum(v for v in gv.removed.values())
    assert np.array_equal(cone.sum(0) - removed, gv.visible.sum(0))
    assert gv.removed["cloud_collision"].sum() > 0        # the slot floor loses its tilted axes
    assert gv.table_z_mm == pytest.approx(-gv.placement_mm[2])
    # the same with the part placed 2 m away: nothing is within travel
    far = global_visibility(s.points, idx, normals, axes, angles, cone, tool=tool, profile=prof,
                            fixtures_params=FixturesParams(placement_mm=(2000.0, 0.0, 50.0)))
    assert not far.visible.any() and far.removed["travel"].sum() == cone.sum()
    # global off, travel off: the cone visibility unchanged
    off = global_visibility(s.points, idx, normals, axes, angles, cone, tool=tool, profile=prof,
                            fixtures_params=FixturesParams(), check_global=False, check_travel=False)
    assert np.array_equal(off.visible, cone)
    # a forbidden point cloud hovering over the block removes pairs, never adds any
    grid = [[x, y, 45.0] for x in range(-40, 41, 2) for y in range(-30, 31, 2)]
    hover = FixturesParams.model_validate({"items": [{"type": "points", "points_mm": grid}]})
    hv = global_visibility(s.points, idx, normals, axes, angles, cone, tool=tool, profile=prof,
                           fixtures_params=hover)
    assert not np.any(hv.visible & ~gv.visible) and hv.visible.sum() < gv.visible.sum()


def test_all_obstacles_never_free_more_than_sampled():
    """Every input point as an obstacle (default) is the exact answer; the sampled subset can only
    call more pairs free."""
    s, idx, normals, prof, axes, angles, cone = _slot_case(1.0, 4, 4)
    tool = ball_tool(3.0, flute_length_mm=20.0)
    kw = dict(tool=tool, profile=prof, fixtures_params=FixturesParams(), check_travel=False)
    full = global_visibility(s.points, idx, normals, axes, angles, cone, obstacles="all", **kw)
    sub = global_visibility(s.points, idx, normals, axes, angles, cone, obstacles="sampled", **kw)
    assert not np.any(full.visible & ~sub.visible)
    assert full.n_obstacles == s.points.shape[0] and sub.n_obstacles == idx.size
    ref = brute_force_collision_free(s.points, idx[:40], normals[:40], axes, tool, candidates=cone[:40])
    assert np.array_equal(full.visible[:40], ref)


def test_along_is_the_travel_of_each_facing_pair_by_the_simulation_kinematics():
    """``along_swing_deg`` (simultaneous 5-axis): for every (sample, axis) pair whose normal lies within
    the swing of the axis, whether the machine can present that axis itself there within X/Y/Z travel,
    without the cone; the others False. Checked pair by pair against the simulation's own kinematics
    (:class:`planning.simulate.kinematics.MachineModel`, tip = ball centre - R * axis), on a placement
    that puts some of the pairs out of travel and keeps others in."""
    from planning.simulate.kinematics import MachineModel

    s, idx, normals, prof, axes, angles, cone = _slot_case(0.5, 3, 6)
    tool = ball_tool(3.0, flute_length_mm=12.0, stickout_mm=30.0, holder=[(12.5, 45.0, None)])
    swing = 70.0
    fx = FixturesParams(placement_mm=(0.0, 0.0, 40.0))
    gv = global_visibility(s.points, idx, normals, axes, angles, cone, tool=tool, profile=prof, fixtures_params=fx,
                           check_global=False, along_swing_deg=swing)
    facing = np.degrees(np.arccos(np.clip(normals @ axes.T, -1, 1))) <= swing
    model = MachineModel(prof, gv.placement_mm)
    (x0, x1), (y0, y1), (z0, z1) = prof.linear_limits_mm
    lo, hi = np.array([x0, y0, z0]) - 1e-6, np.array([x1, y1, z1]) + 1e-6
    want = np.zeros_like(facing)
    R = tool.radius_mm
    for i in range(idx.size):
        for j in np.flatnonzero(facing[i]):
            tip = s.points[idx[i]] + R * normals[i] - R * axes[j]
            mpos = model.machine_from_tip(tip[None], angles[j][None], tool.gauge_length_mm)[0]
            want[i, j] = bool(np.all((mpos >= lo) & (mpos <= hi)))
    assert np.array_equal(gv.along, want)
    assert 0 < gv.along.sum() < facing.sum()                   # some pairs in travel, some out
    assert (gv.along & ~cone).any()                             # not limited to the cone's pairs
    # none asked, or the travel not checked: not computed
    assert global_visibility(s.points, idx, normals, axes, angles, cone, tool=tool, profile=prof,
                             fixtures_params=fx, check_global=False).along is None
    assert global_visibility(s.points, idx, normals, axes, angles, cone, tool=tool, profile=prof, fixtures_params=fx,
                             check_global=False, check_travel=False, along_swing_deg=swing).along is None
