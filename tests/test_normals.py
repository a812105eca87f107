"""Sphere throwing (planning/normals/throwing.py): accuracy on analytic surfaces, exactness against a brute-force
drop, result contract, determinism and parameter errors.

Accuracy surfaces (tests/surfaces.py): 45 points/mm^2, Gaussian noise sigma 0.02 mm along the line of
sight of the scanner view that recorded each point, sphere diameter 7 mm, default grid spacing. Points
within 4 mm (> r = 3.5 mm) of the boundary of a finite patch are excluded from the error statistics and
the orientation check, because there the ball touches the patch's edge rather than its surface (an edge
effect, not what these tests are about); the whole sphere has no boundary and is checked everywhere.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

import surfaces as S
from planning.errors import InputError, ParameterError
from planning.normals.throwing import (DEFAULT_DIRECTIONS, NormalsResult, default_grid_spacing_mm, point_spacing_mm,
                              sphere_throwing, throw_lines)

Z = [(0.0, 0.0, 1.0)]


def _stats(surface: S.Surface, res: NormalsResult):
    m = surface.interior[res.sample_index]
    idx = res.sample_index[m]
    err = S.angular_error_deg(res.normals[m], surface.normals[idx])
    return err, idx


CASES = {
    "plane": (lambda: S.plane(), Z),
    "plane_tilted_30": (lambda: S.plane(tilt_deg=30.0), Z),
    "wave": (lambda: S.wave(), Z),
    "saddle": (lambda: S.saddle(), Z),
    "hemisphere_R40": (lambda: S.sphere(40.0), DEFAULT_DIRECTIONS),
    "closed_cylinder_R25": (lambda: S.cylinder(25.0), DEFAULT_DIRECTIONS),
}


@pytest.mark.parametrize("name", list(CASES))
def test_accuracy_on_analytic_surfaces(name):
    make, dirs = CASES[name]
    surface = make()
    res = sphere_throwing(surface.points, sphere_diameter_mm=7.0, directions=dirs)
    err, idx = _stats(surface, res)
    assert idx.size > 0.05 * np.count_nonzero(surface.interior)     # the paper keeps ~10 %
    assert np.median(err) < 2.0, f"{name}: median {np.median(err):.2f} deg"
    assert np.percentile(err, 95) < 5.0, f"{name}: p95 {np.percentile(err, 95):.2f} deg"
    # outward: every interior touched point's normal is on the material's outer side
    dots = np.einsum("ij,ij->i", res.normals[surface.interior[res.sample_index]], surface.normals[idx])
    assert dots.min() > 0.0


def test_outward_everywhere_on_a_closed_sphere():
    surface = S.sphere(20.0, z_min_mm=-20.0, seed=11)
    res = sphere_throwing(surface.points)
    dots = np.einsum("ij,ij->i", res.normals, surface.normals[res.sample_index])
    assert res.sample_index.size > 0.05 * surface.points.shape[0]
    assert dots.min() > 0.0
    err = S.angular_error_deg(res.normals, surface.normals[res.sample_index])
    assert np.median(err) < 2.0


def test_oblique_direction_matches_axis_direction():
    """A tilted plane thrown along its own normal behaves like a level plane thrown along +Z."""
    surface = S.plane(tilt_deg=30.0, seed=12)
    n = np.array([-math.sin(math.radians(30.0)), 0.0, math.cos(math.radians(30.0))])
    res = sphere_throwing(surface.points, directions=[n * 3.0])
    err, _ = _stats(surface, res)
    assert np.median(err) < 2.0 and np.percentile(err, 95) < 5.0


def test_result_contract():
    surface = S.wave(size_mm=16.0, seed=13)
    res = sphere_throwing(surface.points, directions=DEFAULT_DIRECTIONS)
    n = res.sample_index.size
    assert res.sample_index.dtype == np.int64 and res.sample_index.shape == (n,)
    assert np.all(np.diff(res.sample_index) > 0)                       # sorted, unique
    assert res.sample_index.min() >= 0 and res.sample_index.max() < surface.points.shape[0]
    assert res.normals.dtype == np.float64 and res.normals.shape == (n, 3)
    assert np.allclose(np.linalg.norm(res.normals, axis=1), 1.0, atol=1e-12)
    assert res.touches.dtype == np.int32 and res.touches.shape == (n,) and res.touches.min() >= 1
    assert res.grid_spacing_mm == default_grid_spacing_mm(surface.points, 7.0)
    assert res.sphere_diameter_mm == 7.0
    explicit = sphere_throwing(surface.points, grid_spacing_mm=0.3)
    assert explicit.grid_spacing_mm == 0.3


def test_deterministic():
    surface = S.saddle(size_mm=16.0, seed=14)
    a = sphere_throwing(surface.points)
    b = sphere_throwing(surface.points.copy())
    for field in ("sample_index", "normals", "touches"):
        assert np.array_equal(getattr(a, field), getattr(b, field))
    assert a.grid_spacing_mm == b.grid_spacing_mm


def test_direction_length_and_touch_counts():
    surface = S.plane(size_mm=14.0, seed=15)
    a = sphere_throwing(surface.points, directions=[(0, 0, 1)])
    b = sphere_throwing(surface.points, directions=[(0, 0, 2.5)])
    assert np.array_equal(a.sample_index, b.sample_index) and np.array_equal(a.normals, b.normals)
    # the same direction twice: every point touched twice as often, same normals
    c = sphere_throwing(surface.points, directions=[(0, 0, 1), (0, 0, 1)])
    assert np.array_equal(c.sample_index, a.sample_index)
    assert np.array_equal(c.touches, 2 * a.touches)
    assert np.allclose(c.normals, a.normals, atol=1e-12)
    lines = throw_lines(surface.points, (0, 0, 1))
    assert a.touches.sum() == lines.contact_index.size


def test_progress_callback():
    surface = S.plane(size_mm=12.0, seed=16)
    calls = []
    sphere_throwing(surface.points, progress=lambda f, msg: calls.append((f, msg)))
    assert len(calls) == len(DEFAULT_DIRECTIONS)
    fractions = [f for f, _ in calls]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    assert all(isinstance(m, str) and "direction" in m for _, m in calls)


def test_single_point():
    res = sphere_throwing(np.array([[1.0, 2.0, 3.0]]), grid_spacing_mm=0.5, directions=Z)
    assert res.sample_index.tolist() == [0]
    assert res.normals[0] @ np.array([0, 0, 1.0]) > 0.99      # lines all around it: the mean is +Z


# ------------------------------------------------------------------------------------------------
# brute force

def _brute_force(points, lines, subset=None, chunk=512):
    """For every grid line of ``lines``' frame with a point within r: the maximum over ALL points of
    ``subset`` (default: every point) of h + sqrt(r^2 - rho^2) for rho < r, by the explicit formula.
    Returns {(i, j): (point index, height, second-best height)}."""
    r = lines.sphere_diameter_mm / 2.0
    g = lines.grid_spacing_mm
    q = points - lines.origin
    idx = np.arange(points.shape[0]) if subset is None else np.asarray(subset)
    u, v, h = q[idx] @ lines.e_u, q[idx] @ lines.e_v, q[idx] @ lines.direction
    i0, i1 = math.floor((u.min() - r) / g), math.ceil((u.max() + r) / g)
    j0, j1 = math.floor((v.min() - r) / g), math.ceil((v.max() + r) / g)
    ii, jj = np.meshgrid(np.arange(i0, i1 + 1), np.arange(j0, j1 + 1), indexing="ij")
    ii, jj = ii.ravel(), jj.ravel()
    out = {}
    for s in range(0, ii.size, chunk):
        X, Y = ii[s:s + chunk, None] * g, jj[s:s + chunk, None] * g
        rho2 = (u[None, :] - X) ** 2 + (v[None, :] - Y) ** 2
        with np.errstate(invalid="ignore"):
            val = np.where(rho2 < r * r, h[None, :] + np.sqrt(r * r - rho2), -np.inf)
        order = np.argsort(-val, axis=1, kind="stable")[:, :2]
        top = np.take_along_axis(val, order, axis=1)
        for k in np.flatnonzero(np.isfinite(top[:, 0])):
            second = top[k, 1] if order.shape[1] > 1 else -np.inf
            out[(int(ii[s + k]), int(jj[s + k]))] = (int(idx[order[k, 0]]), float(top[k, 0]), float(second))
    return out


def _fast_lines(lines):
    height = (lines.centres - lines.origin) @ lines.direction
    return {(int(i), int(j)): (int(p), float(hh), k)
            for k, ((i, j), p, hh) in enumerate(zip(lines.line_ij, lines.contact_index, height))}


TINY = [("+Z", (0.0, 0.0, 1.0)), ("-X", (-1.0, 0.0, 0.0)), ("oblique", (0.3, -0.2, 1.0))]


@pytest.mark.parametrize("label,direction", TINY)
def test_exact_on_the_candidate_subset(label, direction):
    """The fast search is exact on its candidate subset (the top point of each 2g cell): same lines,
    same touched point on every line, same ball height (float32 search: near-ties within 1e-4 mm may
    go either way; none occur with these seeds), and no candidate strictly inside any ball."""
    surface = S.wave(size_mm=12.0, seed=21)
    pts = surface.points
    lines = throw_lines(pts, direction, sphere_diameter_mm=7.0, grid_spacing_mm=0.25)
    ref = _brute_force(pts, lines, subset=lines.candidate_index)
    fast = _fast_lines(lines)
    assert set(fast) == set(ref)
    for key, (p_ref, h_ref, second) in ref.items():
        p_fast, h_fast, _ = fast[key]
        if p_fast != p_ref:
            assert h_ref - second < 1e-4, f"{label} line {key}: {p_fast} instead of {p_ref}"
        assert abs(h_fast - h_ref) < 1e-4
    r = lines.sphere_diameter_mm / 2.0
    assert np.allclose(np.linalg.norm(lines.centres - pts[lines.contact_index], axis=1), r, atol=1e-9)
    assert np.all(lines.normals @ lines.direction >= 0.0)      # the ball comes from +direction
    dist, _ = cKDTree(pts[lines.candidate_index]).query(lines.centres)
    assert dist.min() > r - 1e-4


@pytest.mark.parametrize("label,direction", TINY[:2])
def test_against_brute_force_on_all_points(label, direction):
    """Against the exact drop on ALL points the fast method is approximate (non-top points of a cell
    are never touched). Stated tolerances, measured with margin on this noisy patch (45 points/mm^2,
    sigma 0.02 mm, D 7, g 0.25): the ball is never higher than the exact one; it sinks into the full
    cloud by a median <= 0.03 mm and a 90th percentile <= 0.3 mm; the per-line normals differ by a
    median <= 5 deg; at least 30 % of the lines touch exactly the same point; at most 5 % of the
    exact lines (at the rim of the cloud, where only non-top points lie within r) get no contact.
    Measured: +Z (face-on) sink median 0.008 / p90 0.09 mm, normals median 2.9 deg, 40 % same,
    0.8 % missing; -X (edge-on) sink median 0 / p90 0.23 mm, normals median 0 deg, 64 % same,
    3.3 % missing."""
    surface = S.wave(size_mm=12.0, seed=22)
    pts = surface.points
    lines = throw_lines(pts, direction, sphere_diameter_mm=7.0, grid_spacing_mm=0.25)
    ref = _brute_force(pts, lines)
    fast = _fast_lines(lines)
    assert set(fast) <= set(ref)
    assert len(ref) - len(fast) <= 0.05 * len(ref)
    g, r = lines.grid_spacing_mm, lines.sphere_diameter_mm / 2.0
    sink, angle, same = [], [], []
    for key, (p_fast, h_fast, k) in fast.items():
        p_ref, h_ref, _ = ref[key]
        assert h_fast <= h_ref + 1e-9
        sink.append(h_ref - h_fast)
        same.append(p_fast == p_ref)
        centre = lines.origin + key[0] * g * lines.e_u + key[1] * g * lines.e_v + h_ref * lines.direction
        n_ref = (centre - pts[p_ref]) / r
        angle.append(math.degrees(math.acos(min(1.0, float(n_ref @ lines.normals[k])))))
        if p_fast == p_ref:
            assert abs(h_fast - h_ref) < 1e-4
    sink, angle = np.array(sink), np.array(angle)
    assert np.median(sink) <= 0.03 and np.percentile(sink, 90) <= 0.3
    assert np.median(angle) <= 5.0
    assert np.mean(same) >= 0.3


# ------------------------------------------------------------------------------------------------
# default grid spacing

def test_point_spacing_and_default_grid():
    surface = S.plane(size_mm=40.0, density=45.0, sigma_mm=0.0, seed=31)
    s = point_spacing_mm(surface.points)
    assert abs(s - 1.0 / math.sqrt(45.0)) < 0.1 / math.sqrt(45.0)
    g = default_grid_spacing_mm(surface.points, 7.0)
    assert g == float(f"{1.5 * s:.3g}")
    assert 0.2 <= g <= 0.25
    # bounds: a sparse cloud gets r/4, a very dense one r/32
    sparse = S.plane(size_mm=100.0, density=0.05, sigma_mm=0.0, seed=32)
    assert default_grid_spacing_mm(sparse.points, 7.0) == float(f"{3.5 / 4:.3g}")
    dense = S.plane(size_mm=3.0, density=4000.0, sigma_mm=0.0, seed=33)
    assert default_grid_spacing_mm(dense.points, 7.0) == float(f"{3.5 / 32:.3g}")
    assert default_grid_spacing_mm(np.zeros((3, 3)), 7.0) == float(f"{3.5 / 4:.3g}")   # too few points


# ------------------------------------------------------------------------------------------------
# errors

PTS = np.random.default_rng(0).uniform(0.0, 10.0, (200, 3))


@pytest.mark.parametrize("kwargs,match", [
    ({"sphere_diameter_mm": 0.0}, "sphere_diameter_mm = 0: must be a finite number of mm > 0"),
    ({"sphere_diameter_mm": -7.0}, "sphere_diameter_mm = -7"),
    ({"sphere_diameter_mm": float("nan")}, "sphere_diameter_mm = nan"),
    ({"sphere_diameter_mm": "big"}, "sphere_diameter_mm = 'big'"),
    ({"grid_spacing_mm": 0.0}, "grid_spacing_mm = 0: must be a finite number of mm > 0"),
    ({"grid_spacing_mm": -0.1}, "grid_spacing_mm = -0.1"),
    ({"grid_spacing_mm": float("inf")}, "grid_spacing_mm = inf"),
    ({"grid_spacing_mm": 0.001}, r"too fine for sphere_diameter_mm = 7: it must be at least"),
    ({"directions": []}, "directions is empty"),
    ({"directions": [(0, 0, 1), (0, 0, 0)]}, r"directions\[1\] = \[0.0, 0.0, 0.0\] is the zero vector"),
    ({"directions": [(0, 1)]}, r"3-vectors"),
    ({"directions": [(0, float("nan"), 1)]}, "finite"),
])
def test_parameter_errors(kwargs, match):
    with pytest.raises(ParameterError, match=match) as info:
        sphere_throwing(PTS, **kwargs)
    assert info.value.code == "invalid_parameter"
    assert info.value.details.get("parameter") in {"sphere_diameter_mm", "grid_spacing_mm", "directions"}


def test_grid_too_fine_for_the_extent():
    pts = np.array([[0.0, 0.0, 0.0], [5000.0, 5000.0, 0.0]])
    with pytest.raises(ParameterError, match="too fine for this cloud"):
        sphere_throwing(pts, sphere_diameter_mm=7.0, grid_spacing_mm=0.1, directions=Z)


@pytest.mark.parametrize("points,match", [
    (np.zeros((0, 3)), "empty"),
    (np.zeros((5, 2)), r"\(N, 3\)"),
    (np.array([[0.0, 0.0, np.nan], [1.0, 1.0, 1.0]]), "NaN"),
    ([["a", "b", "c"]], "numbers"),
])
def test_input_errors(points, match):
    with pytest.raises(InputError, match=match):
        sphere_throwing(points)
