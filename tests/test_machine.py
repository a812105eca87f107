"""Machine profiles, kinematics and machine visibility (planning/orientations/kinematics.py, Makki 2010 §2.2.2)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planning.errors import ParameterError
from planning.orientations.candidates import phi_theta_axes, uniform_axes
from planning.orientations.kinematics import (
    ANGLE_TOL_DEG,
    MachineProfile,
    RotarySolutions,
    available_profiles,
    choose_rotary,
    load_profile,
    machine_visibility,
    part_to_machine_rotation,
    part_to_tool_rotation,
    solve_rotary,
    tool_axis_from_angles,
)

KINEMATICS = ["table_table_ac", "table_table_bc", "head_head_ac", "head_head_bc"]
Z = np.array([0.0, 0.0, 1.0])


def make(kin="table_table_bc", tilt=(-180, 180), rotary=None, name="test"):
    """A profile; ``rotary=None`` means a continuous rotary axis."""
    d = dict(name=name, kinematics=kin, tilt_min_deg=tilt[0], tilt_max_deg=tilt[1],
             x_travel_mm=500, y_travel_mm=400, z_travel_mm=300)
    if rotary is None:
        d["rotary_continuous"] = True
    else:
        d.update(rotary_continuous=False, rotary_min_deg=rotary[0], rotary_max_deg=rotary[1])
    return MachineProfile(**d)


def sph(phi_deg, theta_deg):
    p, t = np.radians(phi_deg), np.radians(theta_deg)
    return np.stack([np.sin(p) * np.cos(t), np.sin(p) * np.sin(t), np.cos(p) + 0 * t], axis=-1)


def apply(R, v):
    return np.einsum("mij,mj->mi", R, v)


# ------------------------------------------------------------------------------------------ profiles


def test_bundled_profiles_load():
    names = available_profiles()
    assert {"compact_trunnion_bc", "compact_trunnion_ac", "fork_head_ac"} <= set(names)
    for n in names:
        p = load_profile(n)
        assert p.name == n
        assert p.description
    bc = load_profile("compact_trunnion_bc")
    assert bc.kinematics == "table_table_bc" and bc.axis_names == ("B", "C") and bc.is_table_table
    assert (bc.tilt_min_deg, bc.tilt_max_deg) == (-35, 120) and bc.rotary_continuous
    assert (bc.x_travel_mm, bc.y_travel_mm, bc.z_travel_mm) == (762, 508, 508)
    assert "modelled on" in bc.description
    ac = load_profile("compact_trunnion_ac")
    assert ac.axis_names == ("A", "C") and (ac.tilt_min_deg, ac.tilt_max_deg) == (-120, 30)
    fh = load_profile("fork_head_ac")
    assert fh.kinematics == "head_head_ac" and not fh.is_table_table
    assert (fh.rotary_min_deg, fh.rotary_max_deg) == (-360, 360) and not fh.rotary_continuous


def test_default_profile_matches_params_default():
    from schemas.params import MachineParams
    assert MachineParams().profile in available_profiles()


def test_unknown_profile_lists_available_names():
    with pytest.raises(ParameterError) as ei:
        load_profile("haas_umc_9000")
    msg = str(ei.value)
    assert "haas_umc_9000" in msg and "machine.profile" in msg
    for n in available_profiles():
        assert n in msg


def test_profile_from_path(tmp_path):
    data = make("head_head_bc", (-90, 90), (-200, 200), name="mine").model_dump()
    f = tmp_path / "mine.json"
    f.write_text(json.dumps(data))
    p = load_profile(str(f))
    assert p.kinematics == "head_head_bc" and p.rotary_max_deg == 200
    assert load_profile(f) == p
    assert load_profile(p) is p


def test_profile_file_errors(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ParameterError, match="not valid JSON"):
        load_profile(str(bad))
    d = make().model_dump()
    d["tilt_min_deg"], d["tilt_max_deg"] = 30, -30
    f = tmp_path / "p.json"
    f.write_text(json.dumps(d))
    with pytest.raises(ParameterError, match="tilt_min_deg"):
        load_profile(str(f))
    d = make().model_dump()
    d["spindle_rpm"] = 12000
    f.write_text(json.dumps(d))
    with pytest.raises(ParameterError, match="spindle_rpm: unknown field"):
        load_profile(str(f))
    f.write_text("[1, 2]")
    with pytest.raises(ParameterError, match="JSON object"):
        load_profile(str(f))


@pytest.mark.parametrize("change, match", [
    (dict(rotary_continuous=True, rotary_min_deg=-10, rotary_max_deg=10), "must be null"),
    (dict(rotary_continuous=False), "required"),
    (dict(rotary_continuous=False, rotary_min_deg=10, rotary_max_deg=-10), "rotary_min_deg"),
    (dict(tilt_max_deg=200), "tilt_max_deg"),
    (dict(kinematics="head_table_bc"), "kinematics"),
    (dict(x_travel_mm=0), "x_travel_mm"),
])
def test_profile_validation(change, match):
    d = dict(name="t", kinematics="table_table_bc", tilt_min_deg=-30, tilt_max_deg=90, rotary_continuous=True,
             x_travel_mm=1, y_travel_mm=1, z_travel_mm=1)
    d.update(change)
    with pytest.raises(Exception, match=match):
        MachineProfile(**d)


def test_profile_fields_documented():
    for name, f in MachineProfile.model_fields.items():
        assert f.description, name
    schema = MachineProfile.model_json_schema()
    assert schema["properties"]["tilt_min_deg"]["minimum"] == -180


# ------------------------------------------------------------------------- conventions (explicit)


@pytest.mark.parametrize("kin, angles, axis", [
    # table-table: t = R_z(-C) R_tilt(-tilt) Z
    ("table_table_bc", (90, 0), (-1, 0, 0)),
    ("table_table_bc", (90, 90), (0, 1, 0)),
    ("table_table_ac", (90, 0), (0, 1, 0)),
    ("table_table_ac", (90, 90), (1, 0, 0)),
    # head-head: t = R_z(C) R_tilt(tilt) Z
    ("head_head_bc", (90, 0), (1, 0, 0)),
    ("head_head_bc", (90, 90), (0, 1, 0)),
    ("head_head_ac", (90, 0), (0, -1, 0)),
    ("head_head_ac", (90, 90), (1, 0, 0)),
    ("head_head_ac", (0, 123), (0, 0, 1)),
    ("table_table_bc", (0, 0), (0, 0, 1)),
    ("table_table_bc", (180, 0), (0, 0, -1)),
])
def test_forward_kinematics_conventions(kin, angles, axis):
    t = tool_axis_from_angles(angles, make(kin))
    np.testing.assert_allclose(t[0], axis, atol=1e-15)


def test_table_rotation_is_tilt_after_rotary():
    p = make("table_table_bc")
    R = part_to_machine_rotation([30, 40], p)[0]
    b, c = math.radians(30), math.radians(40)
    Ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    Rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    np.testing.assert_allclose(R, Ry @ Rz, atol=1e-15)
    np.testing.assert_allclose(part_to_machine_rotation([[30, 40]] * 3, make("head_head_bc")), np.eye(3)[None].repeat(3, 0))


# ------------------------------------------------------------------------------------ round trips


@pytest.mark.parametrize("kin", KINEMATICS)
@pytest.mark.parametrize("axes_fn", [lambda: phi_theta_axes(10, 30).axes, lambda: uniform_axes(7).axes])
def test_round_trip_every_kinematics(kin, axes_fn):
    axes = axes_fn()
    p = make(kin)                                   # full tilt travel, continuous rotary
    vis = machine_visibility(axes, p)
    assert vis.feasible.all()
    np.testing.assert_allclose(tool_axis_from_angles(vis.angles_deg, p), axes, atol=1e-9)
    for j in range(2):                              # every solution, valid or not, is a solution
        a = vis.solutions.angles_deg[:, j]
        np.testing.assert_allclose(tool_axis_from_angles(a, p), axes, atol=1e-9)
        np.testing.assert_allclose(apply(part_to_tool_rotation(a, p), axes), np.tile(Z, (len(axes), 1)), atol=1e-9)
        if p.is_table_table:
            np.testing.assert_allclose(apply(part_to_machine_rotation(a, p), axes), np.tile(Z, (len(axes), 1)),
                                       atol=1e-9)
    # tilt = +-phi, and the rotary angle of a continuous axis in [-180, 180)
    phi = np.degrees(np.arccos(np.clip(axes[:, 2], -1, 1)))
    np.testing.assert_allclose(np.abs(vis.solutions.angles_deg[:, :, 0]), np.c_[phi, phi], atol=1e-6)
    r = vis.solutions.angles_deg[:, :, 1]
    assert np.all((r >= -180) & (r < 180))
    # both solutions except at +Z
    north = axes[:, 2] == 1
    np.testing.assert_array_equal(vis.n_solutions, np.where(north, 1, 2))
    # chosen: non-negative tilt when the full travel allows both
    assert np.all(vis.angles_deg[:, 0] >= 0)


@pytest.mark.parametrize("name", ["compact_trunnion_bc", "compact_trunnion_ac", "fork_head_ac"])
def test_round_trip_bundled_profiles(name):
    p = load_profile(name)
    c = phi_theta_axes(5, 15)
    vis = machine_visibility(c.axes, name)
    f = vis.feasible
    assert f.any() and vis.axis_names == p.axis_names
    np.testing.assert_allclose(tool_axis_from_angles(vis.angles_deg[f], p), c.axes[f], atol=1e-9)
    assert np.all(np.isnan(vis.angles_deg[~f]))
    t, r = vis.angles_deg[f, 0], vis.angles_deg[f, 1]
    assert np.all((t >= p.tilt_min_deg) & (t <= p.tilt_max_deg))
    if not p.rotary_continuous:
        assert np.all((r >= p.rotary_min_deg) & (r <= p.rotary_max_deg))


# ------------------------------------------------------------------------------- feasibility limits


def test_default_trunnion_reaches_phi_up_to_120_for_every_theta():
    c = phi_theta_axes(10, 30)
    vis = machine_visibility(c.axes, "compact_trunnion_bc")
    np.testing.assert_array_equal(vis.feasible, c.phi_deg <= 120)
    assert vis.feasible.sum() == 1 + 12 * 12
    # at phi 120 the tilt sits exactly on the limit
    at = c.phi_deg == 120
    np.testing.assert_array_equal(vis.angles_deg[at, 0], 120.0)
    # phi <= 35: both tilts in travel; 35 < phi <= 120: only the positive one
    n = vis.n_solutions
    assert np.all(n[(c.phi_deg > 0) & (c.phi_deg <= 30)] == 2)
    assert np.all(n[(c.phi_deg >= 40) & (c.phi_deg <= 120)] == 1)
    # the paper's best pair is machinable
    for phi, theta in ((50, 30), (110, 210)):
        j = np.flatnonzero((c.phi_deg == phi) & (c.theta_deg == theta))[0]
        assert vis.feasible[j]


def test_tilt_limit_exactly_and_just_beyond():
    p = make("table_table_bc", (-35, 120))
    eps = 1e-7
    axes = sph(np.array([120.0, 120.0 + eps, 35.0, 35.0 + eps]), np.array([77.0, 77.0, 200.0, 200.0]))
    s = solve_rotary(axes, p)
    np.testing.assert_array_equal(s.valid, [[True, False], [False, False], [True, True], [True, False]])
    assert s.angles_deg[0, 0, 0] == 120.0
    assert s.angles_deg[2, 1, 0] == -35.0
    # within ANGLE_TOL_DEG outside the limit is accepted and snapped
    q = make("table_table_bc", (-35, 120 - 0.5 * ANGLE_TOL_DEG))
    s2 = solve_rotary(sph(120.0, 0.0), q)
    assert s2.valid[0, 0] and s2.angles_deg[0, 0, 0] == q.tilt_max_deg


def test_negative_tilt_chosen_when_only_it_is_in_travel():
    p = load_profile("compact_trunnion_ac")            # A -120..+30
    axes = sph(np.array([20.0, 60.0, 120.0, 130.0]), np.array([45.0, 45.0, 45.0, 45.0]))
    vis = machine_visibility(axes, p)
    np.testing.assert_array_equal(vis.feasible, [True, True, True, False])
    np.testing.assert_allclose(vis.angles_deg[:3, 0], [20, -60, -120], atol=1e-9)
    np.testing.assert_allclose(tool_axis_from_angles(vis.angles_deg[:3], p), axes[:3], atol=1e-12)


def test_rotary_limits_with_wraps():
    # head_head_bc: C = theta for positive tilt, theta + 180 for negative tilt
    p = make("head_head_bc", (-90, 90), (200, 300))
    axes = sph(np.full(4, 45.0), np.array([250.0, -110.0 + 360.0, 90.0, 10.0]))
    s = solve_rotary(axes, p)
    # theta 250: C = 250 (a wrap of -110) with tilt +45; tilt -45 needs C = 70 -> out of travel
    assert s.valid[0, 0] and s.angles_deg[0, 0, 1] == pytest.approx(250.0)
    assert not s.valid[0, 1]
    # theta 90: tilt +45 needs C = 90 (out); tilt -45 needs C = 270 (a wrap of -90) -> valid
    assert not s.valid[2, 0] and s.valid[2, 1]
    assert s.angles_deg[2, 1, 1] == pytest.approx(270.0)
    # theta 10: C = 10 or 190 -> both out of [200, 300]
    assert not s.valid[3].any()
    ch, feas = choose_rotary(s, p)
    np.testing.assert_array_equal(feas, [True, True, True, False])
    np.testing.assert_allclose(ch[2], [-45, 270], atol=1e-9)
    np.testing.assert_allclose(tool_axis_from_angles(ch[:3], p), axes[:3], atol=1e-12)


def test_rotary_limit_exactly_and_just_beyond():
    p = make("head_head_bc", (0, 90), (0, 90))
    axes = sph(np.array([30.0, 30.0, 30.0, 30.0]), np.array([90.0, 90.0 + 1e-6, 0.0, 360.0 - 1e-6]))
    vis = machine_visibility(axes, p)
    np.testing.assert_array_equal(vis.feasible, [True, False, True, False])
    assert vis.angles_deg[0, 1] == 90.0
    assert vis.angles_deg[2, 1] == 0.0


def test_wide_rotary_travel_prefers_wrap_nearest_zero():
    p = load_profile("fork_head_ac")                  # C -360..+360
    c = phi_theta_axes(10, 30)
    s = solve_rotary(c.axes, p)
    r = s.angles_deg[:, :, 1]
    assert np.all(s.valid[c.phi_deg <= 110, 0])
    assert np.all((r >= -180) & (r <= 180))


def test_rotary_travel_not_containing_zero_uses_nearest_limit_at_pole():
    p = make("table_table_bc", (-30, 110), (30, 90))
    s = solve_rotary([0, 0, 1], p)
    np.testing.assert_array_equal(s.angles_deg[0, 0], [0, 30])
    np.testing.assert_array_equal(s.valid[0], [True, False])


def test_poles():
    p = make("table_table_bc")
    s = solve_rotary(np.array([[0, 0, 1.0], [0, 0, -1.0], [1e-14, 0, 1.0]]), p)
    np.testing.assert_array_equal(s.angles_deg[0], [[0, 0], [0, 0]])
    np.testing.assert_array_equal(s.n_solutions, [1, 2, 1])
    np.testing.assert_array_equal(s.angles_deg[1], [[180, 0], [-180, 0]])
    vis = machine_visibility([[0, 0, 1.0], [0, 0, -1.0]], "compact_trunnion_bc")
    np.testing.assert_array_equal(vis.feasible, [True, False])
    np.testing.assert_array_equal(vis.angles_deg[0], [0, 0])
    # tilt travel not containing 0: +Z infeasible
    q = make("head_head_ac", (10, 90))
    assert not machine_visibility([0, 0, 1.0], q).feasible[0]


def test_choose_rule():
    sols = RotarySolutions(
        angles_deg=np.array([[[30, 10], [-30, -170]], [[30, 10], [-30, -170]], [[0, 0], [0, 0]],
                             [[40, 170], [40, 20]]], dtype=float),
        valid=np.array([[True, True], [False, True], [False, False], [True, True]]))
    ch, feas = choose_rotary(sols)
    np.testing.assert_array_equal(feas, [True, True, False, True])
    np.testing.assert_array_equal(ch[0], [30, 10])
    np.testing.assert_array_equal(ch[1], [-30, -170])
    assert np.isnan(ch[2]).all()
    np.testing.assert_array_equal(ch[3], [40, 20])    # same tilt: rotary closest to 0


# ----------------------------------------------------------------------------- property-based tests

unit_vectors = st.one_of(
    st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1))
    .filter(lambda v: sum(c * c for c in v) > 1e-6)
    .map(lambda v: tuple(np.array(v) / np.linalg.norm(v))),
    st.sampled_from([(0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (1.0, 0.0, 0.0), (0.0, -1.0, 0.0)]),
    st.tuples(st.floats(0, 180), st.floats(0, 360)).map(lambda pt: tuple(sph(*pt))),
)


def _reference_feasible(axis, p) -> bool:
    """Independent scalar check: some (tilt, rotary + 360 k) of the full-travel solutions is in travel."""
    full = make(p.kinematics)
    s = solve_rotary(axis, full)
    for tilt, rot in s.angles_deg[0]:
        if not (p.tilt_min_deg - 1e-9 <= tilt <= p.tilt_max_deg + 1e-9):
            continue
        if p.rotary_continuous:
            return True
        if math.hypot(axis[0], axis[1]) <= 1e-12:
            # pole: the rotary angle is free, any angle in travel will do
            return True
        for k in range(-4, 5):
            if p.rotary_min_deg - 1e-9 <= rot + 360 * k <= p.rotary_max_deg + 1e-9:
                return True
    return False


@settings(max_examples=200, deadline=None)
@given(axis=unit_vectors, kin=st.sampled_from(KINEMATICS))
def test_property_all_solutions_are_solutions(axis, kin):
    axis = np.array(axis)
    p = make(kin)
    s = solve_rotary(axis, p)
    for j in range(2):
        a = s.angles_deg[:, j]
        np.testing.assert_allclose(tool_axis_from_angles(a, p)[0], axis, atol=1e-9)
        np.testing.assert_allclose(part_to_tool_rotation(a, p)[0] @ axis, Z, atol=1e-9)
        if p.is_table_table:
            np.testing.assert_allclose(part_to_machine_rotation(a, p)[0] @ axis, Z, atol=1e-9)
    assert s.valid[0, 0]


@settings(max_examples=300, deadline=None)
@given(axis=unit_vectors, kin=st.sampled_from(KINEMATICS),
       tilt=st.tuples(st.floats(-180, 180), st.floats(-180, 180)).filter(lambda t: t[0] < t[1]),
       rotary=st.one_of(st.none(), st.tuples(st.floats(-720, 720), st.floats(-720, 720)).filter(lambda r: r[0] < r[1])))
def test_property_limited_travel(axis, kin, tilt, rotary):
    axis = np.array(axis)
    p = make(kin, tilt, rotary)
    vis = machine_visibility(axis, p)
    s = vis.solutions
    for j in range(2):
        if s.valid[0, j]:
            t, r = s.angles_deg[0, j]
            assert p.tilt_min_deg <= t <= p.tilt_max_deg
            if rotary is not None:
                assert rotary[0] <= r <= rotary[1]
            np.testing.assert_allclose(tool_axis_from_angles([t, r], p)[0], axis, atol=1e-9)
    assert vis.feasible[0] == _reference_feasible(axis, p)
    if vis.feasible[0]:
        np.testing.assert_allclose(tool_axis_from_angles(vis.angles_deg, p)[0], axis, atol=1e-9)
    else:
        assert np.isnan(vis.angles_deg).all()


# ---------------------------------------------------------------------------------------- errors


def test_input_validation():
    p = make()
    with pytest.raises(ParameterError, match="unit vectors"):
        solve_rotary([[0, 0, 2.0]], p)
    with pytest.raises(ParameterError, match=r"\(m, 3\)"):
        solve_rotary([[0, 1.0]], p)
    with pytest.raises(ParameterError, match="NaN"):
        machine_visibility([[0, 0, np.nan]], p)
    with pytest.raises(ParameterError, match=r"\(m, 2\)"):
        tool_axis_from_angles([[1, 2, 3]], p)
    with pytest.raises(ParameterError, match="NaN"):
        part_to_machine_rotation([[np.inf, 0]], p)
    with pytest.raises(ParameterError, match="available profiles"):
        machine_visibility([[0, 0, 1.0]], "no_such_machine")
    # nearly-unit axes are accepted and normalised
    s = solve_rotary([[0, 0, 1 + 1e-9]], p)
    assert s.valid[0, 0]


def test_empty_input():
    vis = machine_visibility(np.zeros((0, 3)), "compact_trunnion_bc")
    assert vis.feasible.shape == (0,) and vis.angles_deg.shape == (0, 2) and vis.n_solutions.shape == (0,)


@pytest.mark.parametrize("name", ["compact_trunnion_bc", "compact_trunnion_ac"])
def test_the_written_out_table_rotation_is_the_matrix_product(name):
    """part_to_machine_rotation writes R_tilt R_z(rotary) out by columns (the 5-axis posts ask it for
    every posted point): the same numbers as the product of the two rotations, and the machine model's
    pivot shift is (I - R_tilt) P."""
    from planning.orientations.kinematics import (
        _rot,
        _tilt_axis,
        part_to_machine_rotation,
    )
    from planning.simulate.kinematics import MachineModel

    rng = np.random.default_rng(5)
    a = np.c_[rng.uniform(-40, 120, 5000), rng.uniform(-4000, 4000, 5000)]
    a[:20, 1] = 0.0
    a[20:40, 0] = 0.0
    m = MachineModel(name, np.array([1.0, 2.0, 3.0]))
    Rt = _rot(_tilt_axis(m.profile), np.radians(a[:, 0]))
    assert np.array_equal(part_to_machine_rotation(a, m.profile), Rt @ _rot("z", np.radians(a[:, 1])))
    M, shift = m._rotation(a)
    assert np.array_equal(M, Rt @ _rot("z", np.radians(a[:, 1])))
    assert np.allclose(shift, m.pivot - Rt @ m.pivot, rtol=0, atol=1e-12)
