"""The simulated range scan (planning/inputs/samples/rangescan.py): scan lines at the pitches asked,
first hits on the exact surfaces, holes at grazing incidence, noise, outliers, registration errors."""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from planning.errors import ParameterError
from planning.inputs.cloud import read_cloud
from planning.inputs.samples import (
    RANGE_SHAPES,
    SAMPLES,
    femur_implicit,
    femur_like,
    make_sample,
    range_scan,
    shape_distance,
)
from scanmill.cli import EXIT_ERROR, EXIT_OK, main

SHAPES = ["femur_like", "half_sphere", "slot", "filleted_box"]


@pytest.fixture(scope="module")
def scans():
    """The default scans (about 40,000 points each), generated once."""
    return {shape: range_scan(shape, seed=3) for shape in SHAPES}


@pytest.fixture(scope="module")
def clean():
    """Exact hits only: no noise, no outliers, no registration error (about 8,000 points each)."""
    return {shape: range_scan(shape, n_points=8000, noise_mm=0.0, outlier_share=0.0, registration_mm=0.0,
                              registration_deg=0.0, seed=5) for shape in SHAPES}


def _registration_bound(s):
    """The most a registration error moves a point of sample ``s`` (mm)."""
    m = s.meta
    reach = np.linalg.norm(s.points - np.asarray(m["registration_centre_mm"]), axis=1).max()
    return m["registration_mm"] + math.radians(m["registration_deg"]) * reach


def test_deterministic_for_a_seed():
    a, b = range_scan("half_sphere", n_points=5000, seed=7), range_scan("half_sphere", n_points=5000, seed=7)
    assert np.array_equal(a.points, b.points) and np.array_equal(a.normals, b.normals)
    for key in ("view", "line", "column", "outlier_index", "registration_rotvec_deg"):
        assert np.array_equal(a.meta[key], b.meta[key]), key
    c = range_scan("half_sphere", n_points=5000, seed=8)
    assert not (c.points.shape == a.points.shape and np.array_equal(c.points, a.points))


@pytest.mark.parametrize("shape", SHAPES)
def test_point_count_is_about_the_target(scans, shape):
    s = scans[shape]
    assert s.points.shape == s.normals.shape and s.points.shape[1] == 3
    assert abs(s.points.shape[0] - 40_000) <= 0.2 * 40_000
    assert s.meta["n_points_target"] == 40_000
    assert s.name == RANGE_SHAPES[shape]
    for key in ("view", "line", "column", "incidence_deg"):
        assert s.meta[key].shape == (s.points.shape[0],), key


@pytest.mark.parametrize("shape", SHAPES)
def test_spacing_along_and_across_the_lines(scans, shape):
    """Median distance between neighbours in a line (consecutive samples) and from a line to the
    next line of the same view, where the surface faces the view (incidence under 30 deg: on a
    surface at incidence theta the spacing stretches up to 1 / cos theta): the pitches asked."""
    s = scans[shape]
    m, p = s.meta, s.points
    line, col = m["line"], m["column"]
    facing = m["incidence_deg"] < 30.0
    assert facing.mean() > 0.1
    assert np.all(np.diff(line) >= 0)                       # grouped by line, in order along it
    same = (line[1:] == line[:-1]) & (col[1:] == col[:-1] + 1) & facing[1:] & facing[:-1]
    along = np.median(np.linalg.norm(p[1:] - p[:-1], axis=1)[same])
    gaps = []
    start = np.searchsorted(line, np.unique(line))
    bounds = dict(zip(np.unique(line), zip(start, np.append(start[1:], line.size))))
    for ln in list(bounds)[::5]:
        nxt = bounds.get(ln + 1)
        if nxt is None or m["view"][bounds[ln][0]] != m["view"][nxt[0]]:
            continue
        a = np.arange(*bounds[ln])
        a = a[facing[a]]
        if a.size:
            gaps.append(cKDTree(p[nxt[0]:nxt[1]]).query(p[a])[0])
    across = np.median(np.concatenate(gaps))
    # in the view's image plane the steps along a line are the pitch, along the line direction
    step = (p[1:] - p[:-1])[same]
    vw = m["view"][1:][same]
    assert np.median(np.einsum("ij,ij->i", step, m["line_directions"][vw])) == pytest.approx(m["along_mm"], rel=0.02)
    assert np.median(np.abs(np.einsum("ij,ij->i", step, m["across_directions"][vw]))) < 0.05 * m["along_mm"]
    assert along == pytest.approx(m["along_mm"], rel=0.25)
    assert across == pytest.approx(m["across_mm"], rel=0.25)
    assert across / along == pytest.approx(2.0, rel=0.25)


def test_other_pitches_are_kept():
    s = range_scan("slot", n_points=5000, along_mm=0.5, across_mm=0.5, noise_mm=0.0, registration_mm=0.0,
                   registration_deg=0.0, outlier_share=0.0)
    top = s.meta["labels"] == s.meta["label_names"].index("top")
    view0 = (s.meta["view"] == 0) & top                     # seen from straight above: the grid itself
    d = cKDTree(s.points[view0]).query(s.points[view0], k=2)[0][:, 1]
    assert np.median(d) == pytest.approx(0.5, rel=0.02)


@pytest.mark.parametrize("shape", SHAPES)
def test_exact_hits_lie_on_the_surface_with_its_normals(clean, shape):
    s = clean[shape]
    d, n = shape_distance(shape, s.points, s.meta["scale"])
    assert np.abs(d).max() < 1e-6
    assert np.allclose(np.linalg.norm(s.normals, axis=1), 1.0, atol=1e-9)
    if shape != "slot":      # at the slot's edges the nearest box face is either one
        assert np.einsum("ij,ij->i", n, s.normals).min() > 1.0 - 1e-6
    if shape == "femur_like":
        f, g = femur_implicit(s.points / s.meta["scale"])
        assert np.abs(f).max() * s.meta["scale"] < 1e-6
        assert np.allclose(g / np.linalg.norm(g, axis=1)[:, None], s.normals, atol=1e-6)
    if shape == "half_sphere":
        assert np.allclose(s.normals, s.points / s.meta["radius_mm"], atol=1e-9)
        assert s.points[:, 2].min() >= 0.0
    # outward: every normal faces the view that recorded it, at the incidence in meta
    cos = np.einsum("ij,ij->i", s.normals, s.meta["view_directions"][s.meta["view"]])
    assert cos.min() > 0.0
    assert np.allclose(np.degrees(np.arccos(np.clip(cos, -1, 1))), s.meta["incidence_deg"], atol=1e-6)


@pytest.mark.parametrize("shape", ["femur_like", "filleted_box"])
def test_marched_hits_are_the_first_along_the_ray(clean, shape):
    """Nothing of the part lies between a hit and its scanner: points every 0.2 mm from 0.05 mm
    above the hit out of the bounding box, on 300 rays, are all outside (ray marching skips no wall)."""
    s = clean[shape]
    rows = np.random.default_rng(0).choice(s.points.shape[0], 300, replace=False)
    v = s.meta["view_directions"][s.meta["view"][rows]]
    extent = float(np.ptp(s.points, axis=0).max()) + 1.0
    t = np.arange(0.05, extent, 0.2)
    probe = s.points[rows][:, None, :] + t[None, :, None] * v[:, None, :]
    d, _ = shape_distance(shape, probe.reshape(-1, 3), s.meta["scale"])
    assert d.min() > 0.0


def test_slot_faces_and_their_normals(clean):
    s = clean["slot"]
    names, lab, n, p = s.meta["label_names"], s.meta["labels"], s.normals, s.points
    for name, normal in (("top", (0, 0, 1)), ("slot_floor", (0, 0, 1))):
        rows = lab == names.index(name)
        assert rows.sum() > 100, name
        assert np.allclose(n[rows], normal)
    assert np.allclose(p[lab == names.index("top"), 2], s.meta["top_z_mm"])
    assert np.allclose(p[lab == names.index("slot_floor"), 2], s.meta["floor_z_mm"])
    wall = lab == names.index("slot_wall")
    assert wall.sum() > 100
    assert np.allclose(np.abs(p[wall, 0]), s.meta["slot_width_mm"] / 2)
    assert np.allclose(n[wall, 0], -np.sign(p[wall, 0]))    # the walls face into the slot
    assert not np.any(lab == names.index("bottom"))         # the table side is never seen


@pytest.mark.parametrize("shape", SHAPES)
def test_noisy_points_lie_on_the_surface_within_noise_except_the_outliers(scans, shape):
    s = scans[shape]
    m = s.meta
    d, _ = shape_distance(shape, s.points, m["scale"])
    inlier = np.ones(d.size, bool)
    inlier[m["outlier_index"]] = False
    assert m["outliers"] == m["outlier_index"].size == round(m["outlier_share"] * d.size) > 0
    tol = 5.0 * m["noise_mm"] + _registration_bound(s)
    assert np.abs(d[inlier]).max() < tol
    assert np.std(d[inlier]) > 0.3 * m["noise_mm"]          # the noise is there
    assert np.median(np.abs(d[~inlier])) > 1.0              # outliers: several mm along the ray


def test_noise_and_outliers_move_along_the_rays():
    """Same seed with and without noise and outliers, no registration error: each point moved along
    its view direction only; the outliers by 0.5-1.5 x outlier_mm, the others by about noise_mm."""
    kw = {"n_points": 6000, "registration_mm": 0.0, "registration_deg": 0.0, "seed": 11}
    a = range_scan("filleted_box", noise_mm=0.0, outlier_share=0.0, **kw)
    b = range_scan("filleted_box", noise_mm=0.05, outlier_share=0.01, outlier_mm=4.0, **kw)
    assert np.array_equal(a.meta["line"], b.meta["line"]) and np.array_equal(a.meta["column"], b.meta["column"])
    v = b.meta["view_directions"][b.meta["view"]]
    delta = b.points - a.points
    along = np.einsum("ij,ij->i", delta, v)
    assert np.allclose(delta, along[:, None] * v, atol=1e-9)
    out = np.zeros(along.size, bool)
    out[b.meta["outlier_index"]] = True
    assert np.all((np.abs(along[out]) > 0.5 * 4.0 - 0.3) & (np.abs(along[out]) < 1.5 * 4.0 + 0.3))
    assert np.std(along[~out]) == pytest.approx(0.05, rel=0.1)


def test_registration_error_is_one_rigid_motion_per_view():
    kw = {"n_points": 6000, "noise_mm": 0.0, "outlier_share": 0.0, "seed": 2}
    a = range_scan("half_sphere", registration_mm=0.0, registration_deg=0.0, **kw)
    b = range_scan("half_sphere", registration_mm=0.05, registration_deg=0.02, **kw)
    m = b.meta
    assert np.allclose(np.linalg.norm(m["registration_translation_mm"], axis=1), 0.05)
    assert np.allclose(np.linalg.norm(m["registration_rotvec_deg"], axis=1), 0.02)
    c = np.asarray(m["registration_centre_mm"])
    moved = np.linalg.norm(b.points - a.points, axis=1)
    assert moved.min() > 0.0 and moved.max() <= _registration_bound(b) + 1e-9
    for j in range(m["n_views"]):
        rows = m["view"] == j
        x, y = a.points[rows] - c, b.points[rows] - c
        xm, ym = x.mean(axis=0), y.mean(axis=0)
        u, _, vt = np.linalg.svd((x - xm).T @ (y - ym))   # the best rigid motion of the view (Kabsch)
        r = (u @ vt).T
        if np.linalg.det(r) < 0:
            vt[-1] *= -1
            r = (u @ vt).T
        angle = math.degrees(math.acos(np.clip((np.trace(r) - 1) / 2, -1, 1)))
        assert angle == pytest.approx(0.02, rel=1e-3)
        assert np.allclose(x @ r.T + (ym - xm @ r.T), y, atol=1e-9)
        assert np.allclose(ym - xm @ r.T, m["registration_translation_mm"][j], atol=1e-9)


def test_grazing_rays_are_lost(scans):
    """Holes where the surface turns away: far fewer points seen at over 70 deg incidence than in
    the uniform femur sample, none beyond the end of the dropout ramp; without the dropout many."""
    s = scans["femur_like"]
    inc = s.meta["incidence_deg"]
    assert inc.max() < s.meta["dropout_deg"][1]
    u = femur_like(n_points=20_000, seed=1)
    cos = np.einsum("ij,ij->i", u.normals, u.meta["scanner_directions"][u.meta["scanner_index"]])
    uniform = float(np.mean(np.degrees(np.arccos(cos)) > 70.0))
    ranged = float(np.mean(inc > 70.0))
    assert uniform > 0.08
    assert ranged < 0.25 * uniform
    everything = range_scan("femur_like", n_points=5000, dropout_deg=(90.0, 90.0), seed=3)
    some = range_scan("femur_like", n_points=5000, seed=3)
    assert np.mean(everything.meta["incidence_deg"] > 70.0) > 3.0 * np.mean(some.meta["incidence_deg"] > 70.0)
    assert some.meta["hits"] > some.points.shape[0]


@pytest.mark.parametrize("shape", SHAPES)
def test_every_view_contributes(scans, shape):
    m = scans[shape].meta
    assert m["n_views"] == m["view_directions"].shape[0] == (8 if shape == "femur_like" else 5)
    counts = np.bincount(m["view"], minlength=m["n_views"])
    assert np.array_equal(counts, m["points_per_view"])
    assert counts.min() > 0.02 * counts.sum()
    assert np.all(np.diff(m["view"]) >= 0)
    # a line belongs to one view, line ids of different views never mix
    first = {}
    for ln, v in zip(m["line"][::97], m["view"][::97]):
        assert first.setdefault(int(ln), int(v)) == v
    # the scan lines run along the line direction, across the view direction
    assert np.allclose(np.einsum("ij,ij->i", m["line_directions"], m["view_directions"]), 0.0, atol=1e-12)


def test_scale_and_count():
    s = range_scan("half_sphere", scale=0.2, seed=1)
    assert s.meta["scale"] == 0.2 and s.meta["radius_mm"] == pytest.approx(10.0)
    inlier = np.ones(s.points.shape[0], bool)
    inlier[s.meta["outlier_index"]] = False
    assert np.abs(np.linalg.norm(s.points[inlier], axis=1) - 10.0).max() < 0.2
    t = range_scan("half_sphere", scale=0.4, seed=1)
    assert t.points.shape[0] / s.points.shape[0] == pytest.approx(4.0, rel=0.1)     # grows as scale^2
    small = range_scan("filleted_box", n_points=3000, seed=1)
    assert abs(small.points.shape[0] - 3000) < 0.2 * 3000
    assert small.meta["size_mm"][0] == pytest.approx(60.0 * small.meta["scale"])


def test_registry_and_make_sample():
    for name in RANGE_SHAPES.values():
        assert name in SAMPLES
    assert "range_scan" in SAMPLES
    a = make_sample("range_slot", n_points=4000, seed=4)
    b = range_scan("slot", n_points=4000, seed=4)
    assert a.name == "range_slot" and np.array_equal(a.points, b.points)
    with pytest.raises(ParameterError) as e:
        make_sample("range_femur", shape="slot")
    assert "shape" in str(e.value)


@pytest.mark.parametrize("kwargs", [{"shape": "cube"}, {"n_points": 10}, {"along_mm": 0.0}, {"across_mm": -1.0},
                                    {"dropout_deg": (80.0, 60.0)}, {"dropout_deg": 70.0},
                                    {"outlier_share": 0.9}, {"n_points": 5000, "scale": 0.5}, {"scale": 0.0},
                                    {"n_views": 0}, {"seed": -1}])
def test_rejects_bad_arguments(kwargs):
    with pytest.raises(ParameterError):
        range_scan(**kwargs)


def test_cli_writes_a_range_scan_ply(tmp_path, capsys):
    path = tmp_path / "rs.ply"
    code = main(["sample", "slot", "--scanner", "range", "--points", "5000", "--along-mm", "0.4",
                 "--across-mm", "0.8", "--seed", "1", "--out", str(path)])
    assert code == EXIT_OK
    assert "range_slot" in capsys.readouterr().out
    cloud = read_cloud(path)
    s = range_scan("slot", n_points=5000, along_mm=0.4, across_mm=0.8, seed=1)
    assert np.array_equal(cloud.points, s.points)
    assert np.allclose(cloud.normals, s.normals)
    assert main(["sample", "range_half_sphere", "--points", "2000", "--out", str(tmp_path / "h.ply")]) == EXIT_OK
    assert read_cloud(tmp_path / "h.ply").points.shape[0] == pytest.approx(2000, rel=0.2)
    assert main(["sample", "post_wall", "--scanner", "range", "--out", str(tmp_path / "p.ply")]) == EXIT_ERROR
    assert "post_wall" in capsys.readouterr().err
    assert main(["sample", "slot", "--along-mm", "0.4", "--out", str(tmp_path / "q.ply")]) == EXIT_ERROR
    assert not (tmp_path / "p.ply").exists() and not (tmp_path / "q.ply").exists()
