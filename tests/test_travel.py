"""Translational travel (planning/visibility/travel.py, positions from planning/orientations/positions.py, Makki 2010 §2.2.2, Fig. 4c) and the profile fields it uses."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import planning.visibility.travel as travel
from planning.errors import ParameterError
from planning.orientations.candidates import phi_theta_axes
from planning.orientations.kinematics import (
    MachineProfile,
    available_profiles,
    load_profile,
    machine_visibility,
    tool_axis_from_angles,
)
from planning.orientations.positions import (
    DEFAULT_FIXTURE_HEIGHT_MM,
    default_placement,
    machine_position_affine,
    machine_positions,
)
from planning.visibility.travel import TRAVEL_TOL_MM, travel_feasible
from schemas.machine import DEFAULT_MIN_GAUGE_HEIGHT_MM

KINEMATICS = ["table_table_ac", "table_table_bc", "head_head_ac", "head_head_bc"]


def make(kin="table_table_bc", *, tilt=(-180, 180), travel_mm=(500, 400, 300), name="t", **extra):
    d = dict(name=name, kinematics=kin, tilt_min_deg=tilt[0], tilt_max_deg=tilt[1], rotary_continuous=True,
             x_travel_mm=travel_mm[0], y_travel_mm=travel_mm[1], z_travel_mm=travel_mm[2])
    d.update(extra)
    return MachineProfile(**d)


def pos(c, angles, p, *, place=(0, 0, 0), R=3.0, G=100.0):
    return machine_positions(np.atleast_2d(c), np.atleast_2d(angles), p, placement_mm=place,
                             tool_radius_mm=R, gauge_length_mm=G)


def feas(c, angles, p, *, place=(0, 0, 0), R=3.0, G=100.0, **kw):
    angles = np.atleast_2d(np.asarray(angles, dtype=float))
    axes = np.zeros((len(angles), 3))
    fin = np.isfinite(angles).all(axis=1)
    axes[fin] = tool_axis_from_angles(angles[fin], p)
    return travel_feasible(np.atleast_2d(c), axes, angles, p, placement_mm=place, tool_radius_mm=R,
                           gauge_length_mm=G, **kw)


# ------------------------------------------------------------------------------------ profile fields


def test_defaults_of_new_fields():
    p = make("table_table_bc")
    assert p.x_limits_mm is None and p.table_pivot_mm is None and p.head_pivot_length_mm is None
    assert p.linear_limits_mm == ((-250, 250), (-200, 200), (DEFAULT_MIN_GAUGE_HEIGHT_MM, DEFAULT_MIN_GAUGE_HEIGHT_MM + 300))
    assert p.pivot_mm == (0, 0, 0) and p.pivot_length_mm == 0
    h = make("head_head_ac", head_pivot_length_mm=200)
    # head-head: the controlled point is the pivot, default Z keeps the gauge line 100 mm up
    assert h.linear_limits_mm[2] == (DEFAULT_MIN_GAUGE_HEIGHT_MM + 200, DEFAULT_MIN_GAUGE_HEIGHT_MM + 500)
    q = make("table_table_ac", x_limits_mm=[-100, 400], z_limits_mm=[50, 350], table_pivot_mm=[0, 10, -80])
    assert q.linear_limits_mm == ((-100, 400), (-200, 200), (50, 350)) and q.pivot_mm == (0, 10, -80)


@pytest.mark.parametrize("change, match", [
    (dict(x_limits_mm=[100, -400]), "x_limits_mm .* minimum must be below"),
    (dict(y_limits_mm=[0, 0]), "y_limits_mm"),
    (dict(z_limits_mm=[100, 300]), "z_limits_mm .* spans 200 mm but z_travel_mm is 300"),
    (dict(x_limits_mm=[-250, 250.01]), "x_limits_mm"),
    (dict(x_limits_mm=[-250]), "x_limits_mm"),
    (dict(x_limits_mm=[-250, float("inf")]), "x_limits_mm"),
    (dict(z_limits_mm=[1e6, 1e6 + 300]), "z_limits_mm"),
    (dict(table_pivot_mm=[0, 0]), "table_pivot_mm"),
    (dict(table_pivot_mm=[0, 0, float("nan")]), "table_pivot_mm"),
    (dict(head_pivot_length_mm=100), "head_pivot_length_mm applies to head-head"),
])
def test_profile_validation_table(change, match):
    with pytest.raises(Exception, match=match):
        make("table_table_bc", **change)


@pytest.mark.parametrize("change, match", [
    (dict(table_pivot_mm=[0, 0, -50]), "table_pivot_mm applies to table-table"),
    (dict(head_pivot_length_mm=-1), "head_pivot_length_mm"),
    (dict(head_pivot_length_mm=float("nan")), "head_pivot_length_mm"),
])
def test_profile_validation_head(change, match):
    with pytest.raises(Exception, match=match):
        make("head_head_bc", **change)


def test_bad_ranges_in_a_file_give_parameter_errors(tmp_path):
    d = make().model_dump()
    d["z_limits_mm"] = [400, 100]
    f = tmp_path / "p.json"
    f.write_text(json.dumps(d))
    with pytest.raises(ParameterError, match="z_limits_mm .*minimum must be below the maximum"):
        load_profile(str(f))
    d["z_limits_mm"] = None
    d["head_pivot_length_mm"] = 250
    f.write_text(json.dumps(d))
    with pytest.raises(ParameterError, match="head_pivot_length_mm applies to head-head kinematics only"):
        load_profile(str(f))


def test_old_style_profile_still_valid_and_unchanged(tmp_path):
    """A profile without the new fields loads, gets the defaults and the same machine visibility."""
    old = dict(name="old", kinematics="table_table_bc", tilt_min_deg=-35, tilt_max_deg=120, rotary_continuous=True,
               rotary_min_deg=None, rotary_max_deg=None, x_travel_mm=762, y_travel_mm=508, z_travel_mm=508)
    f = tmp_path / "old.json"
    f.write_text(json.dumps(old))
    p = load_profile(str(f))
    assert p.linear_limits_mm == ((-381, 381), (-254, 254), (100, 608))
    axes = phi_theta_axes(10, 30).axes
    a, b = machine_visibility(axes, p), machine_visibility(axes, "compact_trunnion_bc")
    np.testing.assert_array_equal(a.feasible, b.feasible)
    np.testing.assert_array_equal(a.angles_deg, b.angles_deg)
    # round trip through model_dump keeps the (null) new fields valid
    f.write_text(json.dumps(p.model_dump()))
    assert load_profile(str(f)) == p


def test_bundled_profiles_have_travel_geometry():
    for name in available_profiles():
        p = load_profile(name)
        assert "illustrative" in p.description.lower()
        for (lo, hi), t in zip(p.linear_limits_mm, (p.x_travel_mm, p.y_travel_mm, p.z_travel_mm)):
            assert hi - lo == pytest.approx(t)
    assert load_profile("compact_trunnion_bc").pivot_mm == (0, 0, -50)
    assert load_profile("compact_trunnion_bc").linear_limits_mm[2] == (102, 610)
    assert load_profile("compact_trunnion_ac").pivot_mm == (0, 0, -75)
    fh = load_profile("fork_head_ac")
    assert fh.pivot_length_mm == 250 and fh.linear_limits_mm == ((-1000, 1000), (-500, 500), (300, 1100))


# ----------------------------------------------------------------------------- known answers by hand


@pytest.mark.parametrize("kin", KINEMATICS)
def test_axis_plus_z_at_zero_angles(kin):
    L = 0.0 if kin.startswith("table") else 170.0
    extra = {} if kin.startswith("table") else dict(head_pivot_length_mm=L)
    if kin.startswith("table"):
        extra["table_pivot_mm"] = [0, 0, -60]            # irrelevant at tilt 0
    p = make(kin, **extra)
    c = np.array([[12.0, -7.0, 33.0], [0.0, 0.0, 0.0]])
    place = np.array([5.0, -4.0, 60.0])
    got = pos(c, [0, 0], p, place=place, R=4, G=120)
    np.testing.assert_allclose(got[:, 0], place + c + np.array([0, 0, 120 - 4 + L]), atol=1e-12)


def test_table_bc_tilt_90_moves_the_top_to_plus_x():
    # B axis 50 mm below the table top; a point 100 mm above the table centre, B = +90:
    # q - P = (0, 0, 150) -> R_y(90) -> (150, 0, 0) -> + P = (150, 0, -50); tool axis part -X.
    p = make("table_table_bc", table_pivot_mm=[0, 0, -50])
    place = np.array([0.0, 0.0, 50.0])
    c = np.array([0.0, 0.0, 50.0])                        # table point (0, 0, 100)
    np.testing.assert_allclose(tool_axis_from_angles([90, 0], p)[0], [-1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(pos(c, [90, 0], p, place=place, R=3, G=100)[0, 0], [150, 0, -50 + 97], atol=1e-12)
    # the same with B = -90: top to -X
    np.testing.assert_allclose(pos(c, [-90, 0], p, place=place, R=3, G=100)[0, 0], [-150, 0, 47], atol=1e-12)


def test_table_ac_tilt_90_moves_the_top_to_minus_y():
    # R_x(90): (x, y, z) -> (x, -z, y); A axis 75 mm below: (0, 0, 175) -> (0, -175, 0) -> (0, -175, -75)
    p = make("table_table_ac", table_pivot_mm=[0, 0, -75])
    got = pos([0, 0, 100], [90, 0], p, R=5, G=80)[0, 0]
    np.testing.assert_allclose(got, [0, -175, -75 + 75], atol=1e-12)


def test_table_c_rotation_and_offset_tilt_axis():
    # C = 90 turns (10, 0, 0) to (0, 10, 0) about the table centre (tilt 0: the pivot plays no part)
    p = make("table_table_ac", table_pivot_mm=[0, 30, -50])
    np.testing.assert_allclose(pos([10, 0, 0], [0, 90], p, R=2, G=50)[0, 0], [0, 10, 48], atol=1e-12)
    # A = 90, C = 90 with the A axis 30 mm off the C axis in Y: rotate C first about the C axis,
    # then A about the offset axis: R_z q = (0, 10, 0); - P = (0, -20, 50); R_x(90) -> (0, -50, -20); + P
    np.testing.assert_allclose(pos([10, 0, 0], [90, 90], p, R=2, G=50)[0, 0], [0, -20, -70 + 48], atol=1e-12)


def test_head_ac_and_bc_tilt_90():
    # head_head_ac at (90, 0): t = (0, -1, 0); the pivot is G + L - R along t from the ball centre
    p = make("head_head_ac", head_pivot_length_mm=250)
    got = pos([1, 2, 3], [90, 0], p, place=(10, 20, 30), R=5, G=120)[0, 0]
    np.testing.assert_allclose(got, [11, 22 - 365, 33], atol=1e-12)
    q = make("head_head_bc", head_pivot_length_mm=100)   # (90, 90): t = (0, 1, 0); (90, 0): t = (1, 0, 0)
    got = pos([0, 0, 0], [[90, 90], [90, 0]], q, R=5, G=120)[0]
    np.testing.assert_allclose(got, [[0, 215, 0], [215, 0, 0]], atol=1e-12)


# ----------------------------------------------- independent reference: explicit 4x4 transforms


def _T(v):
    m = np.eye(4)
    m[:3, 3] = v
    return m


def _R4(axis, deg):
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    m = np.eye(4)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


@pytest.mark.parametrize("kin", KINEMATICS)
def test_matches_homogeneous_transforms(kin):
    rng = np.random.default_rng(KINEMATICS.index(kin))
    tilt_axis = "x" if kin.endswith("ac") else "y"
    for _ in range(40):
        P = rng.uniform(-100, 100, 3)
        L = rng.uniform(0, 400)
        p = make(kin, table_pivot_mm=list(P)) if kin.startswith("table") else make(kin, head_pivot_length_mm=L)
        place = rng.uniform(-200, 200, 3)
        R = rng.uniform(0.5, 10)
        G = R + rng.uniform(0, 200)
        tilt, rot = rng.uniform(-180, 180), rng.uniform(-360, 360)
        c = rng.uniform(-150, 150, (5, 3))
        got = pos(c, [tilt, rot], p, place=place, R=R, G=G)[:, 0]
        ez = np.array([0, 0, 1.0, 0])
        for ci, g in zip(c, got):
            if kin.startswith("table"):
                # machine <- table: C about the table Z through the origin, then the tilt about the axis through P
                M = _T(P) @ _R4(tilt_axis, tilt) @ _T(-P) @ _R4("z", rot) @ _T(place)
                # the spindle is machine +Z: the part-frame tool axis is M^-1 applied to +Z
                t = (np.linalg.inv(M) @ ez)[:3]
                tip = M @ np.r_[ci - R * t, 1.0]
                np.testing.assert_allclose(g, tip[:3] + G * ez[:3], atol=1e-9)
                # and back: the ball centre R above the tip along the spindle maps onto the part point
                back = np.linalg.inv(M) @ np.r_[g - (G - R) * ez[:3], 1.0]
                np.testing.assert_allclose(back[:3], ci, atol=1e-9)
            else:
                # head pose: world <- head, head frame origin at the pivot, tool along head +Z
                H = _T(g) @ _R4("z", rot) @ _R4(tilt_axis, tilt)
                ball = H @ np.array([0, 0, -(G + L) + R, 1.0])
                np.testing.assert_allclose(ball[:3], ci + place, atol=1e-9)
                np.testing.assert_allclose((H @ ez)[:3], tool_axis_from_angles([tilt, rot], p)[0], atol=1e-12)


# ------------------------------------------------------------------------------------- feasibility


def test_reachable_point_becomes_infeasible_with_short_z_or_long_tool():
    # angles 0, gauge z = place_z + c_z + G - R = 50 + 20 + 100 - 3 = 167
    p = make("table_table_bc", z_limits_mm=[100, 400])
    assert feas([0, 0, 20], [0, 0], p, place=(0, 0, 50))[0, 0]
    assert not feas([0, 0, 20], [0, 0], make("table_table_bc", travel_mm=(500, 400, 60), z_limits_mm=[100, 160]),
                    place=(0, 0, 50))[0, 0]
    # long tool: gauge z = 70 + G - 3 > 400 once G > 333
    assert feas([0, 0, 20], [0, 0], p, place=(0, 0, 50), G=333)[0, 0]
    assert not feas([0, 0, 20], [0, 0], p, place=(0, 0, 50), G=334)[0, 0]
    # limits are inclusive within TRAVEL_TOL_MM
    assert feas([0, 0, 20], [0, 0], p, place=(0, 0, 50), G=333 + 0.5 * TRAVEL_TOL_MM)[0, 0]
    assert not feas([0, 0, 20], [0, 0], p, place=(0, 0, 50), G=333 + 3 * TRAVEL_TOL_MM)[0, 0]
    # too short a tool: the spindle would have to go below the Z minimum
    assert not feas([0, 0, 20], [0, 0], p, place=(0, 0, 0), G=80)[0, 0]


def test_large_part_exceeds_x_travel_at_known_distance():
    # fork head, A = 90, C = 90: t = (1, 0, 0); pivot x = c_x + G + L - R = c_x + 120 + 250 - 5
    p = load_profile("fork_head_ac")
    np.testing.assert_allclose(tool_axis_from_angles([90, 90], p)[0], [1, 0, 0], atol=1e-15)
    xs = np.array([[634.999, 0, 400], [635.0, 0, 400], [635.001, 0, 400], [-999.0, 0, 400]])
    np.testing.assert_array_equal(feas(xs, [90, 90], p, R=5, G=120)[:, 0], [True, True, False, True])
    # vertical tool: the part edge at the X limit itself
    np.testing.assert_array_equal(feas([[1000, 0, 0], [1000.01, 0, 0]], [0, 0], p, R=5, G=120)[:, 0], [True, False])
    # trunnion at angles 0: gauge x = c_x + place_x within +-381
    bc = load_profile("compact_trunnion_bc")
    got = feas([[380.9, 0, 0], [381.1, 0, 0], [-381.1, 0, 0]], [0, 0], bc, place=(0, 0, 50))[:, 0]
    np.testing.assert_array_equal(got, [True, False, False])


def _brute(c, angles, p, place, R, G, tol=TRAVEL_TOL_MM):
    x = pos(c, angles, p, place=place, R=R, G=G)
    lims = np.asarray(p.linear_limits_mm)
    return np.all((x >= lims[:, 0] - tol) & (x <= lims[:, 1] + tol), axis=2)


@pytest.mark.parametrize("name", ["compact_trunnion_bc", "compact_trunnion_ac", "fork_head_ac"])
def test_matches_brute_force_and_chunking(name, monkeypatch):
    p = load_profile(name)
    rng = np.random.default_rng(7)
    c = rng.uniform(-120, 120, (3000, 3))
    axes = phi_theta_axes(10, 30).axes
    vis = machine_visibility(axes, p)
    place = default_placement(c)
    ref = _brute(c, vis.angles_deg, p, place, 3.0, 110.0) & vis.feasible[None, :]
    kw = dict(placement_mm=place, tool_radius_mm=3.0, gauge_length_mm=110.0)
    got = travel_feasible(c, axes, vis.angles_deg, p, **kw)
    np.testing.assert_array_equal(got, ref)
    assert 0 < got.mean() < 1
    assert not got[:, ~vis.feasible].any()              # NaN angles: all False
    monkeypatch.setattr(travel, "_CHUNK_ELEMS", 5000)    # tiny chunks: same answer
    np.testing.assert_array_equal(travel_feasible(c, axes, vis.angles_deg, p, **kw), ref)
    # candidates: the others are False, the evaluated ones unchanged
    cand = rng.random(ref.shape) < 0.3
    np.testing.assert_array_equal(travel_feasible(c, axes, vis.angles_deg, p, candidates=cand, **kw), ref & cand)


def test_whole_column_shortcuts_agree_with_points():
    """A cloud wholly inside, wholly outside and straddling a limit, incl. points exactly on it."""
    p = make("head_head_bc", x_limits_mm=[-100, 400])       # Z [100, 400] by default, pivot length 0
    c = np.array([[-100.0, 0, 0], [400.0, 0, 300], [0, 0, -50]])
    # angles 0, R = 0, G = 100: controlled point = c + place + (0, 0, 100)
    np.testing.assert_array_equal(feas(c, [0, 0], p, G=100, R=0)[:, 0], [True, True, False])
    np.testing.assert_array_equal(feas(c[:2], [0, 0], p, G=100, R=0)[:, 0], [True, True])
    assert not feas(c, [0, 0], p, G=100, R=0, place=(1000, 0, 0)).any()
    np.testing.assert_array_equal(feas(c[:2], [0, 0], p, G=100, R=0, place=(1e-7, 0, 1e-7))[:, 0], [True, True])
    np.testing.assert_array_equal(feas(c[:2], [0, 0], p, G=100, R=0, place=(0, 0, 1e-5))[:, 0], [True, False])
    np.testing.assert_array_equal(feas(c[:2], [0, 0], p, G=100, R=0, place=(-1e-5, 0, 0))[:, 0], [False, True])


def test_empty_and_all_infeasible_inputs():
    p = make()
    assert feas(np.zeros((0, 3)), [[0, 0], [10, 0]], p).shape == (0, 2)
    out = feas([[0, 0, 0]], [[np.nan, np.nan]], p)
    assert out.shape == (1, 1) and not out.any()
    assert np.isnan(pos([[0, 0, 0]], [[np.nan, np.nan]], p)).all()


def test_input_errors():
    p = make()
    kw = dict(placement_mm=(0, 0, 0), tool_radius_mm=3, gauge_length_mm=100)
    with pytest.raises(ParameterError, match="does not match its rotary angles"):
        travel_feasible([[0, 0, 0]], [[1, 0, 0]], [[0, 0]], p, **kw)
    with pytest.raises(ParameterError, match="candidates"):
        travel_feasible([[0, 0, 0]], [[0, 0, 1]], [[0, 0]], p, candidates=np.ones((2, 1), bool), **kw)
    with pytest.raises(ParameterError, match="gauge length"):
        travel_feasible([[0, 0, 0]], [[0, 0, 1]], [[0, 0]], p, placement_mm=(0, 0, 0), tool_radius_mm=5,
                        gauge_length_mm=4)
    with pytest.raises(ParameterError, match="placement_mm"):
        machine_positions([[0, 0, 0]], [[0, 0]], p, placement_mm=(0, 0), tool_radius_mm=3, gauge_length_mm=100)
    with pytest.raises(ParameterError, match="centres"):
        machine_positions([[0, 0, np.nan]], [[0, 0]], p, **kw)
    with pytest.raises(ParameterError, match="rotary angles"):
        machine_position_affine([[0, 0, 0]], p, **kw)
    with pytest.raises(ParameterError, match="machine profile is required"):
        machine_positions([[0, 0, 0]], [[0, 0]], None, **kw)


def test_default_placement():
    pts = np.array([[10.0, -20, 5], [30, 40, 25], [20, 0, 15]])
    np.testing.assert_allclose(default_placement(pts), [-20, -10, DEFAULT_FIXTURE_HEIGHT_MM - 5])
    np.testing.assert_allclose(default_placement(pts, fixture_height_mm=0), [-20, -10, -5])
    with pytest.raises(ParameterError):
        default_placement(np.zeros((0, 3)))
    with pytest.raises(ParameterError):
        default_placement(pts, fixture_height_mm=-1)


def test_affine_form():
    p = load_profile("compact_trunnion_bc")
    rng = np.random.default_rng(3)
    ang = np.c_[rng.uniform(-35, 120, 6), rng.uniform(-180, 180, 6)]
    A, b = machine_position_affine(ang, p, placement_mm=(1, 2, 50), tool_radius_mm=3, gauge_length_mm=100)
    assert A.shape == (6, 3, 3) and b.shape == (6, 3)
    np.testing.assert_allclose(np.einsum("mij,mik->mjk", A, A), np.eye(3)[None].repeat(6, 0), atol=1e-12)
    c = rng.uniform(-50, 50, (4, 3))
    np.testing.assert_allclose(pos(c, ang, p, place=(1, 2, 50)), np.einsum("mij,nj->nmi", A, c) + b, atol=1e-12)
