"""The guard of issue 16 (planning/toolpath/guard.py): a set-up's moves run on the carried stock, the
obstacles and the travel before posting; what offends is repaired or cut out, never written."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planning.orientations.kinematics import machine_visibility
from planning.simulate.dexel import TriDexel, simulate_moves
from planning.simulate.kinematics import MachineModel
from planning.simulate.motion import ToolShape
from planning.toolpath.frames import AreaFrame
from planning.toolpath.guard import SetupMachine, guard_toolpath, part_moves, run_on_stock
from planning.toolpath.moves import ARC_CCW, FEED, PLANE_XY, RAPID, USE_CUT, USE_PLUNGE, USE_RAPID, Toolpath
from planning.visibility.travel import travel_feasible

FLAT = ToolShape(number=2, kind="flat", radius_mm=3.0, corner_radius_mm=0.0, flute_length_mm=20.0,
                 pieces=((20.0, math.inf, 10.0),), gauge_length_mm=100.0)


def _frame(axis=(0.0, 0.0, 1.0)) -> AreaFrame:
    z = np.asarray(axis, float) / np.linalg.norm(axis)
    x = np.cross([0.0, 1.0, 0.0], z) if abs(z[1]) < 0.9 else np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return AreaFrame(rotation=np.stack([x, y, z]), origin_mm=np.zeros(3))


def _tp(xyz, kind, use=None, centre=None, plane=None) -> Toolpath:
    xyz = np.asarray(xyz, float)
    kind = np.asarray(kind, np.int8)
    P = len(kind)
    use = np.where(kind == RAPID, USE_RAPID, USE_CUT).astype(np.int8) if use is None else np.asarray(use, np.int8)
    centre = np.full((P, 3), np.nan) if centre is None else np.asarray(centre, float)
    plane = np.zeros(P, np.int8) if plane is None else np.asarray(plane, np.int8)
    return Toolpath(xyz_mm=xyz, kind=kind, centre_mm=centre, plane=plane, use=use, tip_offset_mm=0.0)


def test_part_moves_chords_lie_on_the_arc_in_the_part_frame():
    f = _frame((0.3, -0.2, 0.9))
    # a quarter circle of radius 10 about (0, 0, -5) in the XY plane, counter-clockwise
    tp = _tp([[10, 0, -5], [0, 10, -5]], [FEED, ARC_CCW], centre=[[np.nan] * 3, [0, 0, -5]], plane=[0, PLANE_XY])
    pm = part_moves(tp, f)
    assert pm.source[0] == 0 and np.all(pm.source[1:] == 1) and pm.source.size > 8
    back = f.to_frame(pm.end[1:])
    r = np.hypot(back[:, 0], back[:, 1])
    assert np.allclose(r, 10.0, atol=1e-9) and np.allclose(back[:, 2], -5.0)
    assert np.all(np.diff(np.arctan2(back[:, 1], back[:, 0])) > 0)          # counter-clockwise
    assert np.allclose(pm.end[-1], f.to_part([[0, 10, -5]])[0])
    # every chord's midpoint within the chord tolerance of the arc
    mid = f.to_frame(0.5 * (pm.start[1:] + pm.end[1:]))
    assert np.all(10.0 - np.hypot(mid[:, 0], mid[:, 1]) <= 0.005 + 1e-12)
    assert np.allclose(pm.axis, f.rotation[2])


@pytest.mark.parametrize("profile", ["compact_trunnion_bc", "fork_head_ac"])
def test_travel_of_the_guard_is_the_travel_of_the_visibility_filter(profile):
    """The guard's travel (simulate.kinematics, the posts' and the verification's model) and the
    visibility stage's filter (orientations.positions) agree on random tips and set-ups."""
    rng = np.random.default_rng(4)
    axes = rng.normal(size=(12, 3))
    axes[:, 2] = np.abs(axes[:, 2]) + 0.2
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    mv = machine_visibility(axes, profile)
    R, G, place = 3.0, 110.0, np.array([10.0, -20.0, 80.0])
    model = MachineModel(profile, place)
    tips = rng.uniform([-400, -300, -200], [400, 300, 300], size=(3000, 3))
    checked = 0
    for j in np.flatnonzero(mv.feasible):
        ang = mv.angles_deg[j]
        t = model.axis(ang)[0]
        guard_ok = SetupMachine(model, ang).travel_ok(tips, G)
        vis_ok = travel_feasible(tips + R * t, t[None, :], ang[None, :], profile, placement_mm=place,
                                 tool_radius_mm=R, gauge_length_mm=G)[:, 0]
        assert np.array_equal(guard_ok, vis_ok)
        checked += 1
        assert 0 < guard_ok.sum() < tips.shape[0]           # both kinds of answers are exercised
    assert checked >= 6


def _slab() -> TriDexel:
    return TriDexel.box([-30, -30, -10], [30, 30, 0], 1.0, domain_lo=[-60, -60, -40], domain_hi=[60, 60, 60])


def test_a_rapid_into_material_goes_over_the_stock_and_comes_down_as_a_feed():
    f = _frame()
    # rapid at z 10, then a RAPID down into the slab to z -2, feed across, retract
    tp = _tp([[0, 0, 10], [0, 0, -2], [20, 0, -2], [20, 0, 10]], [RAPID, RAPID, FEED, FEED])
    off, _, _ = run_on_stock(tp, f, FLAT, _slab(), None, None, rapid_clearance_mm=0.0)
    assert off.rapid[1] and not off.rapid[0]
    g = guard_toolpath(tp, f, FLAT, _slab(), None, None, safe_z_mm=10.0, rapid_clearance_mm=0.0)
    assert g.rapids_to_feed == 1 and g.truncated == 0
    # over the stock: rapid down only to where the column meets the slab (its top z 0, plus the
    # clearance), then a plunge feed to the same end point; no null moves are left
    tp2 = g.toolpath
    j = int(np.flatnonzero(np.all(np.isclose(tp2.xyz_mm, [0, 0, -2]), axis=1))[0])
    assert tp2.kind[j] == FEED and tp2.use[j] == USE_PLUNGE
    assert tp2.kind[j - 1] == RAPID and 0.5 <= tp2.xyz_mm[j - 1, 2] <= 2.0
    assert np.all(np.linalg.norm(np.diff(tp2.xyz_mm, axis=0), axis=1) > 1e-9)
    again, _, _ = run_on_stock(g.toolpath, f, FLAT, _slab(), None, None, rapid_clearance_mm=0.0)
    assert not again.any.any()
    assert g.removed_mm3 > 0 and g.stock.volume_mm3() < _slab().volume_mm3()


def test_the_guard_leaves_the_given_stock_alone_and_a_clean_path_unchanged():
    f = _frame()
    tp = _tp([[0, 0, 10], [0, 0, 1], [20, 0, 1], [20, 0, 10]], [RAPID, RAPID, FEED, FEED])
    s = _slab()
    v0 = s.volume_mm3()
    g = guard_toolpath(tp, f, FLAT, s, None, None, safe_z_mm=10.0, rapid_clearance_mm=0.0)
    assert s.volume_mm3() == v0
    assert g.rounds == 1 and g.dropped == 0 and g.rapids_to_feed == 0 and g.truncated == 0
    assert g.toolpath is tp


def test_rapid_clearance_is_a_margin_over_the_material():
    f = _frame()
    tp = _tp([[-40, 0, 0.4], [40, 0, 0.4]], [RAPID, RAPID])        # 0.4 mm over the slab's top
    clean, _, _ = run_on_stock(tp, f, FLAT, _slab(), None, None, rapid_clearance_mm=0.0)
    near, _, _ = run_on_stock(tp, f, FLAT, _slab(), None, None, rapid_clearance_mm=0.5)
    assert not clean.rapid.any() and near.rapid[1]


def test_simulation_of_the_guarded_path_matches_a_fresh_run():
    """The stock the guard hands on is the stock a fresh run of its path leaves."""
    f = _frame((0.2, 0.1, 1.0))
    tp = _tp([[-25, -5, 15], [-25, -5, -3], [25, -5, -3], [25, 5, -3], [-25, 5, -3], [-25, 5, 15]],
             [RAPID, FEED, FEED, FEED, FEED, FEED])
    g = guard_toolpath(tp, f, FLAT, _slab(), None, None, safe_z_mm=15.0, rapid_clearance_mm=0.0)
    pm = part_moves(g.toolpath, f)
    s = _slab()
    simulate_moves(s, pm.start, pm.end, np.broadcast_to(pm.axis, pm.start.shape), FLAT, pm.kind)
    assert s.volume_mm3() == pytest.approx(g.stock.volume_mm3(), rel=1e-12)


def test_column_clear_height_is_the_slab_top_plus_the_clearance():
    from planning.toolpath.guard import column_clear_z

    f = _frame()
    pts = np.array([[0.0, 0.0, -5.0], [0.0, 0.0, 3.0], [45.0, 0.0, -5.0]])    # in, above, beside the slab
    z = column_clear_z(f, FLAT, _slab(), pts, 20.0, 0.0, 0.5, step_mm=0.1)
    assert 0.5 - 1e-9 <= z[0] <= 0.6 + 1e-9          # the slab's top (0) + the clearance, to one step
    assert z[1] == pytest.approx(3.0)                  # already clear
    assert z[2] == pytest.approx(-5.0)                 # beside the slab (tool radius 3, clearance 0.5): clear


def test_what_still_offends_after_the_last_round_is_cut_off_with_a_retract():
    """With no repair round allowed, the path is cut off before its first offending move (a feed
    whose holder goes 30 mm into the slab) and ends with a retract; what is left runs clean."""
    f = _frame()
    deep = -35.0                                  # the holder starts 20 mm above the tip: it enters the slab
    tp = _tp([[-40, 0, 10], [-40, 0, 1], [-35, 0, 1], [-35, 0, deep], [0, 0, deep], [0, 0, 10]],
             [RAPID, RAPID, FEED, FEED, FEED, FEED])
    slab = TriDexel.box([-30, -30, -40], [30, 30, 0], 1.0, domain_lo=[-60, -60, -60], domain_hi=[60, 60, 60])
    g = guard_toolpath(tp, f, FLAT, slab, None, None, safe_z_mm=10.0, rapid_clearance_mm=0.0, max_rounds=0)
    assert g.truncated > 0 and g.toolpath.n_moves < tp.n_moves + 1
    assert g.toolpath.xyz_mm[-1, 2] == pytest.approx(10.0)           # the retract to the safe height
    again, _, _ = run_on_stock(g.toolpath, f, FLAT, slab, None, None, rapid_clearance_mm=0.0)
    assert not again.any.any()


def test_the_underside_counts_only_inside_the_footprint():
    """A disc of radius 50 on z = 0 (the half sphere's foot): a ball of radius 5 dipping 2 mm below
    the underside is refused over the disc and within reach of its rim, allowed clear of it; the
    boundary follows sqrt(R^2 - h^2) (brute force over the disc's points)."""
    from planning.toolpath.carried import footprint

    rng = np.random.default_rng(1)
    r = 50 * np.sqrt(rng.uniform(0, 1, 20000))
    a = rng.uniform(0, 2 * np.pi, 20000)
    pts = np.c_[r * np.cos(a), r * np.sin(a), np.zeros_like(r)]
    fp = footprint(pts, cell_mm=0.25)
    R = 5.0
    x = np.linspace(0, 60, 601)
    for z in (-2.0, 0.0, 3.0, 6.0):
        c = np.c_[x, np.zeros_like(x), np.full_like(x, z)]
        got = fp.below_floor(c, R, 0.01)
        h = z + 0.01
        reach = np.sqrt(max(R * R - max(h, 0.0) ** 2, 0.0)) if h < R else -1.0
        want = (x - 50.0 < reach) if h < R else np.zeros_like(x, dtype=bool)
        # exact but for the raster: allow one cell and a half either side of the boundary
        near = np.abs(x - 50.0 - reach) < 0.4
        assert np.array_equal(got[~near], want[~near]), z
    assert not fp.below_floor(np.array([[0.0, 0.0, 5.5]]), R, 0.01)[0]        # ball above the floor


def test_progress_moves_from_0_to_1_and_leaves_the_outcome_alone():
    """issue 17: ``progress(fraction, message)`` per round, fractions rising in [0, 1] and ending at 1;
    the outcome is the one without it. The obstacle check, kept across the rounds, finds the same."""
    f = _frame()
    tp = _tp([[0, 0, 10], [0, 0, -2], [20, 0, -2], [20, 5, 10]], [RAPID, RAPID, FEED, RAPID])
    table = TriDexel.box([-60, -60, -60], [60, 60, -50], 1.0, domain_lo=[-60, -60, -60], domain_hi=[60, 60, 60])
    calls = []
    g = guard_toolpath(tp, f, FLAT, _slab(), table, None, safe_z_mm=10.0, rapid_clearance_mm=0.0,
                       progress=lambda x, msg: calls.append((x, msg)))
    ref = guard_toolpath(tp, f, FLAT, _slab(), table, None, safe_z_mm=10.0, rapid_clearance_mm=0.0)
    assert g.rounds == ref.rounds >= 2
    assert np.array_equal(g.toolpath.xyz_mm, ref.toolpath.xyz_mm) and g.removed_mm3 == ref.removed_mm3
    fr = [c[0] for c in calls]
    assert len(calls) >= 2 and fr[-1] == 1.0 and all(0.0 <= x <= 1.0 for x in fr)
    assert all(b >= a for a, b in zip(fr, fr[1:]))
    assert all(isinstance(c[1], str) and c[1] for c in calls)
