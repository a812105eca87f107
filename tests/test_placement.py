"""Placement when infeasible (fixtures.placement, planning/placement/): the candidate poses against the analytic
stable poses of a box, a tetrahedron and a prism; a slot block scanned upside down (its slot opening on the
table) that no set-ups cover as scanned and that "auto" turns the right way up; the reported rigid motion
against the placed cloud; determinism; the as-scanned message that names the placement."""

import json
import math

import jsonschema
import numpy as np
import pytest
from types import SimpleNamespace

from planning.errors import ParameterError
from planning.inputs.cloud import Cloud
from planning.inputs.samples import slot
from planning.orientations import load_profile
from planning.pipeline import STAGES, run_plan
from planning.placement import apply_pose, candidate_poses, full_yaw, stable_faces, stable_poses
from planning.placement.poses import YAWS_DEG, hull_centroid, principal_poses
from planning.setups import coverage_upper_bound, select_setups
from schemas.params import parse_config
from schemas.plan import plan_json_schema


def _box_corners(a, b, c):
    return np.array([[x, y, z] for x in (0, a) for y in (0, b) for z in (0, c)], dtype=float)


def _normals_of(faces):
    return np.array([f.normal for f in faces])


def _has(normals, n, tol=1e-9):
    return bool(np.any(np.linalg.norm(normals - np.asarray(n, float), axis=1) < tol))


# -- stable poses against the analytic ones ------------------------------------------------------------------------

def test_box_rests_on_each_of_its_six_faces_with_the_analytic_tipping_angles():
    a, b, c = 40.0, 30.0, 20.0
    faces = stable_faces(_box_corners(a, b, c))
    assert len(faces) == 6
    N = _normals_of(faces)
    for n in np.vstack([np.eye(3), -np.eye(3)]):
        assert _has(N, n)
    half = {0: a / 2, 1: b / 2, 2: c / 2}
    for f in faces:
        ax = int(np.argmax(np.abs(f.normal)))
        height = half[ax]
        margin = min(v for k, v in half.items() if k != ax)
        assert f.stability_deg == pytest.approx(math.degrees(math.atan2(margin, height)), abs=1e-9)
        assert f.n_facets == 2                        # qhull's two triangles per face, merged
    # most stable first: on the big 40 x 30 face (margin 15, height 10)
    assert _has(faces[0].normal[None], [0, 0, -1]) or _has(faces[0].normal[None], [0, 0, 1])
    assert [f.stability_deg for f in faces] == sorted((f.stability_deg for f in faces), reverse=True)


def test_a_noisy_dense_box_scan_still_gives_six_faces():
    s = slot(slot_width_mm=1e-3, slot_depth_mm=1e-3, density_per_mm2=0.5, noise_mm=0.02, seed=3, include_bottom=True)
    faces = stable_faces(s.points)
    assert len(faces) == 6
    N = _normals_of(faces)
    for n in np.vstack([np.eye(3), -np.eye(3)]):
        assert _has(N, n, tol=0.01)


def test_regular_tetrahedron_rests_on_its_four_faces():
    v = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float) * 10.0
    faces = stable_faces(v)
    assert len(faces) == 4
    N = _normals_of(faces)
    for p in v:                                       # the face opposite a vertex faces away from it
        assert _has(N, -p / np.linalg.norm(p))
    # tan(tip) = inradius of a face / inradius of the tetrahedron = sqrt(2)
    for f in faces:
        assert f.stability_deg == pytest.approx(math.degrees(math.atan(math.sqrt(2.0))), abs=1e-9)
    assert np.allclose(hull_centroid(v), 0.0, atol=1e-12)


def test_triangular_prism_rests_on_its_three_sides_and_two_ends():
    a, L = 20.0, 60.0
    tri = np.array([[0.0, 0.0], [a, 0.0], [a / 2, a * math.sqrt(3) / 2]])
    pts = np.array([[x, y, z] for x, y in tri for z in (0.0, L)])
    faces = stable_faces(pts)
    assert len(faces) == 5
    r_in = a / (2 * math.sqrt(3))
    ends = [f for f in faces if abs(abs(f.normal[2]) - 1) < 1e-9]
    sides = [f for f in faces if abs(f.normal[2]) < 1e-9]
    assert len(ends) == 2 and len(sides) == 3
    for f in ends:
        assert f.stability_deg == pytest.approx(math.degrees(math.atan2(r_in, L / 2)), abs=1e-9)
    for f in sides:
        assert f.stability_deg == pytest.approx(math.degrees(math.atan2(min(L / 2, a / 2), r_in)), abs=1e-9)
    assert faces[0] in sides                          # the sides are steadier than the ends


def test_a_face_the_centroid_does_not_fall_on_is_not_a_resting_pose():
    # a flat, leaning tetrahedron: its base (z = 0) lies far from under its centroid
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 1]], dtype=float)
    faces = stable_faces(v)
    assert 0 < len(faces) < 4
    assert not _has(_normals_of(faces), [0, 0, -1])


def test_flat_cloud_has_no_hull_poses_but_still_principal_ones():
    rng = np.random.default_rng(0)
    pts = np.column_stack((rng.random(100), rng.random(100), np.zeros(100)))
    assert stable_faces(pts) == [] and stable_poses(pts) == []
    assert len(principal_poses(pts)) == 6


# -- the candidate poses -----------------------------------------------------------------------------------------

def test_candidates_are_rigid_and_stand_on_the_table():
    pts = _box_corners(40, 30, 20) @ np.array([[0.8, -0.6, 0], [0.6, 0.8, 0], [0, 0, 1]]).T + [5, -7, 3]
    poses = candidate_poses(pts)
    assert poses[0].kind == "as_scanned" and np.array_equal(poses[0].rotation, np.eye(3))
    assert np.array_equal(poses[0].translation_mm, np.zeros(3))
    assert len(poses) == 6 and [p.kind for p in poses[1:]] == ["hull_face"] * 5   # the principal axes repeat them
    ups = np.array([p.up for p in poses])
    for i in range(len(ups)):                         # no two candidates share an up direction
        assert np.all(ups[i + 1:] @ ups[i] < math.cos(math.radians(5.0)))
    for p in poses:
        R = p.rotation
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.linalg.det(R) == pytest.approx(1.0)
        assert np.allclose(R[2], p.up)
        q = apply_pose(pts, p)
        if p.kind != "as_scanned":
            lo, hi = q.min(axis=0), q.max(axis=0)
            assert lo[2] == pytest.approx(0.0, abs=1e-9)
            assert (lo[:2] + hi[:2]) == pytest.approx([0.0, 0.0], abs=1e-9)
            assert p.part_height_mm == pytest.approx(hi[2] - lo[2])
    faces = [p for p in poses if p.kind == "hull_face"]
    assert len(faces) == 5                            # the box's bottom is the scan's own: as scanned
    # the longest horizontal side lies along X
    q = apply_pose(pts, faces[0])
    ext = q.max(axis=0) - q.min(axis=0)
    assert ext[0] >= ext[1] - 1e-9


def test_yaw_is_tried_only_where_the_rotary_axis_is_limited():
    assert full_yaw(load_profile("compact_trunnion_bc")) and full_yaw(load_profile("fork_head_ac"))
    limited = SimpleNamespace(rotary_continuous=False, rotary_min_deg=-90.0, rotary_max_deg=90.0)
    assert not full_yaw(limited)
    pts = _box_corners(40, 30, 20)
    one, four = candidate_poses(pts), candidate_poses(pts, full_yaw=False)
    assert len(four) == len(YAWS_DEG) * len(one)
    assert [p.yaw_deg for p in four[:4]] == list(YAWS_DEG)
    assert all(np.allclose(p.up, four[0].up) for p in four[:4])


def test_auto_rejects_a_fixed_placement():
    with pytest.raises(ParameterError, match="placement_mm"):
        parse_config({"fixtures": {"placement": "auto", "placement_mm": [0, 0, 50]}})
    assert parse_config({}).fixtures.placement == "as_scanned"


# -- the price bound every candidate is first held against -------------------------------------------------------

def test_coverage_upper_bound_bounds_the_best_and_proves_what_select_setups_proves():
    rng = np.random.default_rng(4)
    V = rng.random((3000, 40)) < 0.08
    for cov in (0.3, 0.6, 0.9):
        b = coverage_upper_bound(V, coverage=cov, max_setups=3)
        r = select_setups(V, coverage=cov, max_setups=3)
        best = r.covered if r.status == "infeasible" else None
        if best is not None:
            assert b.bound >= best
        if b.proven_infeasible:
            assert r.status == "infeasible"
        assert b.required == r.required_covered and b.greedy <= V.any(axis=1).sum()


# -- the pipeline: a slot block scanned with its slot on the table -----------------------------------------------

_FAST = {"normals": {"method": "input"}, "setups": {"coverage": 0.95, "max_setups": 3},
         "paths": {"finishing": {"enabled": False}, "roughing": {"enabled": False}}, "simulate": {"enabled": False}}


def _config(**fixtures):
    d = json.loads(json.dumps(_FAST))
    d["fixtures"] = fixtures
    return parse_config(d)


@pytest.fixture(scope="module")
def upside_down_slot():
    """The slot block (bottom not scanned, as on a table) turned upside down: the slot opens towards the
    table, so its floor and walls face down; turned about x, shifted so that it stands on z = 0."""
    s = slot(density_per_mm2=0.5, seed=1)
    flip = np.diag([1.0, -1.0, -1.0])
    return Cloud(points=s.points @ flip.T + [0.0, 0.0, 30.0], normals=s.normals @ flip.T, source_format="generated")


@pytest.fixture(scope="module")
def auto_plan(upside_down_slot):
    return run_plan(upside_down_slot, _config(placement="auto"), name="slot_upside_down")


@pytest.fixture(scope="module")
def scanned_plan(upside_down_slot):
    return run_plan(upside_down_slot, _config(), name="slot_upside_down")


def test_upside_down_slot_is_infeasible_as_scanned_and_feasible_with_auto(scanned_plan, auto_plan):
    assert scanned_plan.result.status == "infeasible"
    r = auto_plan.result
    assert r.status == "planned" and r.coverage >= 0.95 and r.selection.k <= 3
    p = r.placement
    assert p.mode == "auto" and p.kind == "hull_face" and p.candidate is not None
    # turned the right way up: the scan's -z, where the slot opens, points up
    assert np.allclose(np.array(p.rotation)[2], [0, 0, -1], atol=2e-3)   # the rim points are jittered
    win = p.candidates[p.candidate]
    assert win.stage == "confirmed" and win.feasible is True and win.k == r.selection.k
    scanned = next(c for c in p.candidates if c.kind == "as_scanned")
    assert scanned.feasible is False
    assert [t.stage for t in r.timings][:2] == ["normals", "placement"]
    assert set(t.stage for t in r.timings) <= set(STAGES)
    assert r.artifacts.placed_ply == "placed.ply"


def test_the_reported_rotation_applied_to_the_scan_is_the_placed_cloud(upside_down_slot, auto_plan):
    p = auto_plan.result.placement
    R, t = np.array(p.rotation), np.array(p.translation_mm)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.linalg.det(R) == pytest.approx(1.0)
    placed = upside_down_slot.points @ R.T + t
    assert np.allclose(placed, auto_plan.points, atol=1e-9)
    assert auto_plan.points.min(axis=0)[2] == pytest.approx(0.0, abs=1e-9)
    # normals turned the same way (exact: the file's normals of the sampled points)
    a = auto_plan.arrays
    assert np.allclose(a["normals"], upside_down_slot.normals[a["sample_index"]] @ R.T, atol=1e-12)
    # and the plan's frame is the placed one: every chosen axis sees its points from above the table
    assert auto_plan.result.visibility.placement_mm[2] == pytest.approx(50.0)


def test_plan_json_with_placement_validates_and_placed_ply_is_written(auto_plan, tmp_path):
    from planning.report.plan_files import plan_json_text, write_plan
    from planning.inputs import read_cloud

    doc = json.loads(plan_json_text(auto_plan))
    jsonschema.validate(doc, plan_json_schema())
    assert doc["parameters"]["fixtures"]["placement"] == "auto"
    assert len(doc["placement"]["candidates"]) == doc["placement"]["n_candidates"] >= 2
    paths = write_plan(auto_plan, tmp_path)
    back = read_cloud(paths["placed_ply"])
    assert np.allclose(back.points, auto_plan.points, atol=1e-4)


def test_placement_is_deterministic(upside_down_slot, auto_plan):
    again = run_plan(upside_down_slot, _config(placement="auto"), name="slot_upside_down")

    def strip(p):
        d = p.model_dump()
        d.pop("seconds")
        for c in d["candidates"]:
            c.pop("seconds")
        return d

    assert strip(again.result.placement) == strip(auto_plan.result.placement)
    assert np.array_equal(again.points, auto_plan.points)
    assert np.array_equal(again.arrays["selected"], auto_plan.arrays["selected"])


def test_the_infeasible_as_scanned_message_names_the_placement(scanned_plan):
    r = scanned_plan.result
    assert "fixtures.placement = auto reaches it" in r.message
    assert "resting on hull face" in r.message and "down" in r.message
    p = r.placement
    assert p.mode == "as_scanned" and p.kind == "as_scanned" and np.allclose(p.rotation, np.eye(3))
    assert p.candidates and all(c.kind != "as_scanned" for c in p.candidates)
    assert any(c.feasible for c in p.candidates)
    assert r.artifacts.placed_ply is None
    assert "placement" in [t.stage for t in r.timings]


def test_a_feasible_as_scanned_plan_searches_nothing():
    s = slot(density_per_mm2=0.5, seed=1)
    out = run_plan(Cloud(points=s.points, normals=s.normals, source_format="generated"), _config())
    r = out.result
    assert r.status == "planned" and "placement" not in [t.stage for t in r.timings]
    assert r.placement.mode == "as_scanned" and r.placement.candidates == []


def test_a_costly_search_is_only_suggested(upside_down_slot, monkeypatch):
    from planning.placement import stage

    monkeypatch.setattr(stage, "HINT_MAX_WORK", 0.0)
    r = run_plan(upside_down_slot, _config(), name="slot_upside_down").result
    assert r.status == "infeasible" and r.message.endswith("try fixtures.placement = auto to search other "
                                                           "placements of the part")
    assert "placement" not in [t.stage for t in r.timings] and r.placement.candidates == []


def test_auto_without_a_winner_plans_as_scanned_and_says_why(upside_down_slot):
    d = json.loads(json.dumps(_FAST))
    d["setups"]["max_setups"] = 1
    d["fixtures"] = {"placement": "auto"}
    r = run_plan(upside_down_slot, parse_config(d)).result
    assert r.status == "infeasible" and r.placement.mode == "auto" and r.placement.candidate is None
    assert r.placement.kind == "as_scanned" and np.allclose(r.placement.rotation, np.eye(3))
    assert all(c.feasible is False for c in r.placement.candidates)
    assert "no tested placement reaches 95 % with 1 set-up (" in r.message
    assert any("planned as scanned" in w for w in r.warnings)
