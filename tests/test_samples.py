"""Reference samples (planning/inputs/samples/): the paper's half sphere, the femur-like scan, slot, post-wall."""

import math

import numpy as np
import pytest

from planning.errors import ParameterError
from planning.inputs.samples import (
    FEMUR_DIMENSIONS_MM,
    SAMPLES,
    Sample,
    femur_implicit,
    femur_like,
    half_sphere,
    make_sample,
    post_wall,
    slot,
    slot_floor_max_tilt_deg,
)
from planning.inputs.samples import femur as S


def _unit(n):
    return np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# half sphere (Makki 2010 §3.2)


def test_half_sphere_is_the_papers_case():
    s = half_sphere()
    assert isinstance(s, Sample) and s.name == "half_sphere"
    assert s.points.shape == (2537, 3) and s.points.dtype == np.float64
    r = s.meta["radius_mm"]
    assert r == 50.0
    assert np.max(np.abs(np.linalg.norm(s.points, axis=1) - r)) < 1e-9
    assert s.points[:, 2].min() > 0.0
    assert _unit(s.normals)
    assert np.allclose(s.normals, s.points / r, atol=1e-12)          # exact radial, outward
    assert s.meta["ring_counts"].sum() == 2537


def test_half_sphere_density_is_not_uniform():
    """Points per mm^2 in the cap within 20 deg of the pole vs the band within 20 deg of the equator."""
    s = half_sphere()
    r = s.meta["radius_mm"]
    polar = np.degrees(np.arccos(s.points[:, 2] / r))
    cap_area = 2 * math.pi * r * r * (1 - math.cos(math.radians(20)))
    band_area = 2 * math.pi * r * r * math.sin(math.radians(20))
    ratio = ((polar < 20).sum() / cap_area) / ((polar > 70).sum() / band_area)
    assert 4.5 < ratio < 7.0                   # uniform in polar angle: about 5.7x denser at the pole


def test_half_sphere_deterministic_and_parametrised():
    a, b = half_sphere(), half_sphere()
    assert np.array_equal(a.points, b.points) and np.array_equal(a.normals, b.normals)
    c = half_sphere(seed=1)
    assert c.points.shape == a.points.shape and not np.array_equal(c.points, a.points)
    d = half_sphere(n_points=1000, radius_mm=20.0)
    assert d.points.shape == (1000, 3)
    assert np.allclose(np.linalg.norm(d.points, axis=1), 20.0, atol=1e-9)


@pytest.mark.parametrize("kwargs", [{"n_points": 0}, {"n_points": 2.5}, {"radius_mm": -1.0},
                                    {"radius_mm": float("nan")}, {"seed": -1}, {"n_points": True}])
def test_half_sphere_rejects_bad_arguments(kwargs):
    with pytest.raises(ParameterError) as e:
        half_sphere(**kwargs)
    assert next(iter(kwargs)) in str(e.value)


# ---------------------------------------------------------------------------------------------
# femur-like scan


@pytest.fixture(scope="module")
def femur():
    return femur_like(n_points=50_000, seed=0)


@pytest.fixture(scope="module")
def femur_clean():
    return femur_like(n_points=20_000, seed=4, noise_mm=0.0)


def test_femur_count_shapes_and_normals(femur):
    assert femur.name == "femur_like"
    assert femur.points.shape == (50_000, 3) and femur.normals.shape == (50_000, 3)
    assert femur.points.dtype == np.float64 and np.isfinite(femur.points).all()
    assert _unit(femur.normals)
    assert femur.meta["scanner_index"].shape == (50_000,)


def test_femur_exact_points_lie_on_the_implicit_surface_with_its_normals(femur_clean):
    f, g = femur_implicit(femur_clean.points)
    assert np.max(np.abs(f)) < 1e-9
    assert np.allclose(g / np.linalg.norm(g, axis=1, keepdims=True), femur_clean.normals, atol=1e-9)


def test_femur_noise_is_along_the_views_with_the_requested_sigma(femur):
    sigma = femur.meta["noise_mm"]
    assert sigma == 0.03
    f, g = femur_implicit(femur.points)
    dist = f / np.linalg.norm(g, axis=1)                  # first-order signed distance, mm
    assert np.mean(np.abs(dist) < 3 * sigma) > 0.99
    # noise moves a point by eps along its view v: distance = eps (n . v)
    v = femur.meta["scanner_directions"][femur.meta["scanner_index"]]
    cos = np.sum(femur.normals * v, axis=1)
    eps = dist / cos
    assert abs(np.std(eps) / sigma - 1.0) < 0.05
    assert abs(np.mean(eps)) < 0.1 * sigma


def test_femur_points_come_from_eight_views_that_face_them(femur):
    dirs = femur.meta["scanner_directions"]
    assert dirs.shape == (8, 3) and _unit(dirs)
    views = femur.meta["scanner_index"]
    counts = np.bincount(views, minlength=8)
    assert (counts > 0.03 * len(views)).all()             # every view contributes
    assert counts.max() < 0.3 * len(views)
    assert np.all(np.sum(femur.normals * dirs[views], axis=1) > 0.2)
    # overlapping views: many surface regions are recorded by several views
    cells = np.floor(femur.points / 5.0).astype(np.int64)
    key = (cells[:, 0] * 1000 + cells[:, 1]) * 1000 + cells[:, 2]
    n_views_per_cell = np.unique(np.stack([key, views]), axis=1)[0]
    _, per_cell = np.unique(n_views_per_cell, return_counts=True)
    assert np.mean(per_cell >= 2) > 0.5


def test_femur_recorded_points_are_not_hidden_from_their_view(femur_clean):
    """Exact check by marching along the ray to the scanner: the part must not be in the way."""
    rng = np.random.default_rng(0)
    k = rng.choice(len(femur_clean.points), 300, replace=False)
    p = femur_clean.points[k]
    v = femur_clean.meta["scanner_directions"][femur_clean.meta["scanner_index"][k]]
    t = np.arange(0.3, 420.0, 0.3)
    q = p[:, None, :] + t[None, :, None] * v[:, None, :]
    f, _ = femur_implicit(q.reshape(-1, 3))
    blocked = (f.reshape(len(p), -1) < 0).any(axis=1)
    assert blocked.mean() < 0.02


def test_femur_frame_and_size(femur):
    dims = np.array(FEMUR_DIMENSIONS_MM)
    assert 380 < dims[0] < 420 and dims[0] > 3 * dims[1:].max()   # ~400 mm along X
    assert femur.meta["dimensions_mm"] == FEMUR_DIMENSIONS_MM
    lo, hi = femur.points.min(axis=0), femur.points.max(axis=0)
    assert np.all(np.abs((hi - lo) - dims) < 3.0)
    assert np.all(np.abs((lo + hi)[:2] / 2) < 2.0)        # centred in x, y
    assert abs(lo[2]) < 1.0                               # lying on the table


def test_femur_frame_constants_match_a_dense_exact_sample():
    x, _, _ = S._femur_surface(np.random.default_rng(7), 4.0)
    x = x + S._FEMUR_OFFSET
    lo, hi = x.min(axis=0), x.max(axis=0)
    half = np.array(FEMUR_DIMENSIONS_MM) / 2
    assert np.allclose(lo, [-half[0], -half[1], 0.0], atol=0.1)
    assert np.allclose(hi, [half[0], half[1], 2 * half[2]], atol=0.1)
    assert abs(len(x) / 4.0 / S._FEMUR_AREA_MM2 - 1) < 0.02     # documented area


def test_femur_implicit_gradient_and_sign():
    rng = np.random.default_rng(3)
    p = rng.uniform(-1, 1, (400, 3)) * [210, 60, 40] + [0, 0, 34]
    _, g = femur_implicit(p)
    h = 1e-5
    num = np.column_stack([(femur_implicit(p + e)[0] - femur_implicit(p - e)[0]) / (2 * h)
                           for e in np.eye(3) * h])
    assert np.allclose(num, g, atol=1e-6)
    centre_of_head = S._HEAD_CENTRE + S._FEMUR_OFFSET
    assert femur_implicit(centre_of_head[None])[0][0] < -15      # inside
    assert femur_implicit(np.array([[0.0, 0.0, 200.0]]))[0][0] > 100


def test_femur_deterministic_and_seeded():
    a, b = femur_like(n_points=20_000, seed=1), femur_like(n_points=20_000, seed=1)
    assert np.array_equal(a.points, b.points) and np.array_equal(a.normals, b.normals)
    assert np.array_equal(a.meta["scanner_index"], b.meta["scanner_index"])
    c = femur_like(n_points=20_000, seed=2)
    assert not np.array_equal(a.points, c.points)


def test_femur_other_view_counts():
    s = femur_like(n_points=5_000, seed=0, n_scanner_directions=3)
    d = s.meta["scanner_directions"]
    assert d.shape == (3, 3) and np.allclose(d[:, 0], 0.0)        # around the long axis only
    assert s.points.shape == (5_000, 3) and set(np.unique(s.meta["scanner_index"])) == {0, 1, 2}


@pytest.mark.parametrize("kwargs", [{"n_points": 10}, {"noise_mm": -0.1}, {"noise_mm": "x"},
                                    {"n_scanner_directions": 0}, {"seed": 1.5}])
def test_femur_rejects_bad_arguments(kwargs):
    with pytest.raises(ParameterError) as e:
        femur_like(**kwargs)
    assert next(iter(kwargs)) in str(e.value)


# ---------------------------------------------------------------------------------------------
# slot and post beside a wall


def _check_boundary(points, normals, inside, eps=1e-6):
    """Every point is on the solid's boundary, its normal pointing out of the solid."""
    assert _unit(normals)
    assert inside(points - eps * normals).all()
    assert not inside(points + eps * normals).any()


def _slot_inside(s):
    X, Y, Z = s.meta["size_mm"]
    w, zf, L = s.meta["slot_width_mm"], s.meta["floor_z_mm"], s.meta["slot_length_mm"]

    def inside(p):
        block = (np.abs(p[:, 0]) < X / 2) & (np.abs(p[:, 1]) < Y / 2) & (p[:, 2] > 0) & (p[:, 2] < Z)
        cut = (np.abs(p[:, 0]) < w / 2) & (p[:, 2] > zf) & (np.abs(p[:, 1]) < L / 2)
        return block & ~cut
    return inside


def _by_label(s, name):
    return s.meta["labels"] == s.meta["label_names"].index(name)


@pytest.mark.parametrize("length", [None, 40.0])
def test_slot_faces_normals_and_meta(length):
    s = slot(slot_length_mm=length)
    m = s.meta
    assert m["kind"] == ("through_slot" if length is None else "pocket")
    assert (m["slot_width_mm"], m["slot_depth_mm"], m["top_z_mm"]) == (12.0, 15.0, 30.0)
    assert m["floor_z_mm"] == m["top_z_mm"] - m["slot_depth_mm"] == 15.0
    _check_boundary(s.points, s.normals, _slot_inside(s))
    floor = s.points[_by_label(s, "slot_floor")]
    assert len(floor) > 0 and np.all(floor[:, 2] == 15.0) and np.all(np.abs(floor[:, 0]) <= 6.0)
    assert np.all(np.abs(floor[:, 1]) <= m["slot_length_mm"] / 2)
    walls = s.points[_by_label(s, "slot_wall")]
    assert np.allclose(np.abs(walls[:, 0]), 6.0) and walls[:, 2].min() >= 15.0 and walls[:, 2].max() <= 30.0
    top = s.points[_by_label(s, "top")]
    assert np.all(top[:, 2] == 30.0)
    assert np.all(s.normals[_by_label(s, "slot_floor")] == [0, 0, 1])
    assert (len(s.points[_by_label(s, "pocket_end_wall")]) > 0) == (length is not None)
    assert not _by_label(s, "bottom").any()
    assert abs(len(s.points) / m["area_mm2"] - 1.0) < 0.01       # 1 point/mm^2 by default


def test_slot_options_and_determinism():
    a, b = slot(), slot()
    assert np.array_equal(a.points, b.points)
    s = slot(size_mm=(50, 40, 20), slot_width_mm=8, slot_depth_mm=10, density_per_mm2=4.0,
             include_bottom=True, seed=3)
    _check_boundary(s.points, s.normals, _slot_inside(s))
    assert abs(len(s.points) / (4.0 * s.meta["area_mm2"]) - 1.0) < 0.01
    assert _by_label(s, "bottom").any()
    assert abs(len(slot(n_points=5000).points) / 5000 - 1) < 0.03
    noisy = slot(noise_mm=0.05)
    dev = np.sum((noisy.points - a.points) * a.normals, axis=1)
    assert abs(np.std(dev) / 0.05 - 1) < 0.05


def test_slot_floor_tilt_limit_is_where_the_shank_meets_the_edge():
    s = slot()
    m = s.meta
    assert slot_floor_max_tilt_deg(m["slot_width_mm"], m["slot_depth_mm"], 3.0) == pytest.approx(13.644, abs=1e-3)
    for w, h, R in [(12.0, 15.0, 3.0), (12.0, 15.0, 5.0), (20.0, 8.0, 3.0), (12.0, 2.0, 3.0), (30.0, 40.0, 1.0)]:
        a_max = slot_floor_max_tilt_deg(w, h, R)
        centre = np.array([0.0, R])                     # ball centre (x, z), floor at z = 0
        e = np.array([w / 2, h]) - centre               # the top edge the axis tilts towards

        def edge_to_shank(alpha_deg, e=e):
            a = np.array([math.sin(math.radians(alpha_deg)), math.cos(math.radians(alpha_deg))])
            t = max(e @ a, 0.0)                         # nearest point of the half-line from the centre
            return np.linalg.norm(e - t * a)
        assert edge_to_shank(a_max - 0.01) > R > edge_to_shank(a_max + 0.01), (w, h, R)
    assert math.isnan(slot_floor_max_tilt_deg(12.0, 15.0, 7.0))      # the ball does not fit
    assert slot_floor_max_tilt_deg(12.0, 15.0, 6.0) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("kwargs", [{"slot_width_mm": 80.0}, {"slot_depth_mm": 30.0},
                                    {"slot_length_mm": 60.0}, {"size_mm": (80, 60)},
                                    {"density_per_mm2": 0.0}, {"noise_mm": -1.0}])
def test_slot_rejects_bad_arguments(kwargs):
    with pytest.raises(ParameterError) as e:
        slot(**kwargs)
    assert next(iter(kwargs)) in str(e.value)


def _post_wall_inside(s):
    m = s.meta
    PX, PY, T = m["plate_size_mm"]
    R, top = m["post_radius_mm"], m["post_top_z_mm"]
    wx0, wx1, wtop = m["wall_face_x_mm"], m["wall_face_x_mm"] + m["wall_thickness_mm"], m["wall_top_z_mm"]

    def inside(p):
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        plate = (np.abs(x) < PX / 2) & (np.abs(y) < PY / 2) & (z > 0) & (z < T)
        post = (x * x + y * y < R * R) & (z >= T) & (z < top)
        wall = (x > wx0) & (x < wx1) & (np.abs(y) < PY / 2) & (z >= T) & (z < wtop)
        return plate | post | wall
    return inside


def test_post_wall_faces_normals_and_meta():
    s = post_wall()
    m = s.meta
    assert (m["post_radius_mm"], m["post_height_mm"], m["gap_mm"], m["wall_height_mm"]) == (5.0, 30.0, 8.0, 40.0)
    assert m["wall_face_x_mm"] == m["post_radius_mm"] + m["gap_mm"]
    assert m["post_top_z_mm"] == m["plate_top_z_mm"] + 30.0 and m["wall_top_z_mm"] == m["plate_top_z_mm"] + 40.0
    _check_boundary(s.points, s.normals, _post_wall_inside(s))
    side = _by_label(s, "post_side")
    rxy = np.linalg.norm(s.points[side, :2], axis=1)
    assert np.allclose(rxy, 5.0, atol=1e-9)
    assert np.allclose(s.normals[side, :2], s.points[side, :2] / 5.0, atol=1e-12)
    front = s.points[_by_label(s, "wall_front")]
    assert np.all(front[:, 0] == 13.0) and np.all(s.normals[_by_label(s, "wall_front")] == [-1, 0, 0])
    gap = front[:, 0].min() - s.points[side, 0].max()
    assert gap == pytest.approx(m["gap_mm"], abs=0.05)
    assert abs(len(s.points) / m["area_mm2"] - 1.0) < 0.01
    assert np.array_equal(s.points, post_wall().points)


def test_post_wall_rejects_a_wall_off_the_plate():
    with pytest.raises(ParameterError) as e:
        post_wall(gap_mm=40.0)
    assert "plate_size_mm" in str(e.value)
    with pytest.raises(ParameterError):
        post_wall(post_radius_mm=0.0)


# ---------------------------------------------------------------------------------------------
# registry


def test_make_sample_by_name():
    assert set(SAMPLES) == {"half_sphere", "femur_like", "slot", "post_wall", "filleted_box", "draft_slot",
                            "range_scan", "range_femur", "range_half_sphere", "range_slot", "range_filleted_box"}
    assert np.array_equal(make_sample("half_sphere").points, half_sphere().points)
    assert make_sample("slot", n_points=2000, seed=1).name == "slot"
    assert make_sample("post_wall", n_points=2000).points.shape[0] == pytest.approx(2000, rel=0.03)
    assert make_sample("draft_slot", n_points=3000).points.shape[0] == pytest.approx(3000, rel=0.03)


def test_make_sample_rejects_unknown_names_and_arguments():
    with pytest.raises(ParameterError) as e:
        make_sample("cube")
    for name in SAMPLES:
        assert name in str(e.value)
    with pytest.raises(ParameterError) as e:
        make_sample("half_sphere", noise_mm=0.1)
    assert "noise_mm" in str(e.value)


def test_samples_are_frozen():
    s = half_sphere()
    with pytest.raises(AttributeError):
        s.name = "x"


def test_the_draft_slot_s_walls_lean_out_at_the_angle_asked_and_the_normals_are_exact():
    from planning.inputs.samples import draft_slot

    s = draft_slot(density_per_mm2=2.0, seed=4, wall_deg=70.0)
    lab = s.meta["labels"]
    wall = lab == s.meta["label_names"].index("slot_wall")
    p, n = s.points[wall], s.normals[wall]
    # every wall point lies on its plane: through the floor edge, leaning out at 70 degrees
    a = np.radians(70.0)
    left = p[:, 0] < 0
    x_edge = 0.5 * s.meta["floor_width_mm"] + (p[:, 2] - s.meta["floor_z_mm"]) / np.tan(a)
    assert np.allclose(np.abs(p[:, 0]), x_edge, atol=1e-9)
    assert np.allclose(n[left], [np.sin(a), 0, np.cos(a)]) and np.allclose(n[~left], [-np.sin(a), 0, np.cos(a)])
    assert s.points[:, 2].min() >= 0 and s.points[:, 2].max() <= 30.0 + 1e-9
    top_only = draft_slot(density_per_mm2=2.0, seed=4, include_sides=False)
    assert "side" not in {top_only.meta["label_names"][k] for k in np.unique(top_only.meta["labels"])}
