"""The density guard (issue 18 item 3): a cloud whose spacing exceeds 20 % of the tool radius is finished on
triangles through its points, and no finishing move comes closer than R - tol to the TRUE surface the
points were sampled from; on the points alone the ball sinks between them (what the guard prevents)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planning.errors import InputError
from planning.inputs import Cloud
from planning.pipeline import run_plan
from planning.toolpath.moves import densify
from planning.toolpath.surface import dip_mm, path_surface, point_spacing_mm
from schemas.params import parse_config

R = 3.0
TOL = 0.01
SPACING = 1.5
AMP, WAVE = 2.0, 20.0          # z = AMP sin(x / WAVE) cos(y / WAVE): curvature radius >= WAVE^2 / (2 AMP) = 100 mm


def f(x, y):
    return AMP * np.sin(x / WAVE) * np.cos(y / WAVE)


def grad(x, y):
    return (AMP / WAVE * np.cos(x / WAVE) * np.cos(y / WAVE), -AMP / WAVE * np.sin(x / WAVE) * np.sin(y / WAVE))


def sparse_surface(seed: int = 0, half: float = 30.0):
    """A jittered 1.5 mm grid on the analytic surface, with its exact upward normals."""
    rng = np.random.default_rng(seed)
    g = np.arange(-half, half + 1e-9, SPACING)
    X, Y = np.meshgrid(g, g, indexing="ij")
    X = X + rng.uniform(-0.25, 0.25, X.shape)
    Y = Y + rng.uniform(-0.25, 0.25, Y.shape)
    x, y = X.ravel(), Y.ravel()
    gx, gy = grad(x, y)
    n = np.stack([-gx, -gy, np.ones_like(x)], axis=1)
    return np.stack([x, y, f(x, y)], axis=1), n / np.linalg.norm(n, axis=1, keepdims=True)


def distance_to_true_surface(c: np.ndarray) -> np.ndarray:
    """Distance from each ball centre ``c`` (K,3) to the analytic surface: the nearest of a 0.25 mm grid of
    surface points within R of the centre's (x, y), refined by Newton steps on the squared distance
    (exact derivatives of f)."""
    off = np.arange(-R, R + 1e-9, 0.25)
    DX, DY = [a.ravel() for a in np.meshgrid(off, off, indexing="ij")]
    x = np.empty(c.shape[0])
    y = np.empty(c.shape[0])
    for k0 in range(0, c.shape[0], 4096):
        cc = c[k0:k0 + 4096]
        gx, gy = cc[:, 0, None] + DX, cc[:, 1, None] + DY
        d2 = (gx - cc[:, :1]) ** 2 + (gy - cc[:, 1:2]) ** 2 + (f(gx, gy) - cc[:, 2:3]) ** 2
        j = np.argmin(d2, axis=1)
        x[k0:k0 + 4096], y[k0:k0 + 4096] = gx[np.arange(j.size), j], gy[np.arange(j.size), j]
    for _ in range(12):
        z = f(x, y)
        fx, fy = grad(x, y)
        fxx = fyy = -z / WAVE ** 2
        fxy = -AMP / WAVE ** 2 * np.cos(x / WAVE) * np.sin(y / WAVE)
        e = z - c[:, 2]
        gx = (x - c[:, 0]) + e * fx
        gy = (y - c[:, 1]) + e * fy
        hxx, hyy, hxy = 1 + fx * fx + e * fxx, 1 + fy * fy + e * fyy, fx * fy + e * fxy
        det = hxx * hyy - hxy * hxy
        x, y = x - (hyy * gx - hxy * gy) / det, y - (hxx * gy - hxy * gx) / det
    return np.sqrt((x - c[:, 0]) ** 2 + (y - c[:, 1]) ** 2 + (f(x, y) - c[:, 2]) ** 2)


def chord_error_bound(points: np.ndarray, faces: np.ndarray) -> float:
    """How far a triangle through points of the surface can lie from it: linear interpolation on a
    triangle errs by at most M r^2 / 2 (Waldron 1998: r the radius of the smallest circle containing
    the triangle, its circumradius when acute, half its longest edge otherwise; M bounds the second
    derivative of f in any direction, here AMP / WAVE^2 since |f_xx| + |f_xy| <= AMP / WAVE^2)."""
    t = points[faces]
    a = np.linalg.norm(t[:, 1] - t[:, 2], axis=1)
    b = np.linalg.norm(t[:, 2] - t[:, 0], axis=1)
    cc = np.linalg.norm(t[:, 0] - t[:, 1], axis=1)
    area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    r = a * b * cc / (4 * np.maximum(area, 1e-12))
    e = np.sort(np.stack([a, b, cc], axis=1), axis=1)
    obtuse = e[:, 2] ** 2 >= e[:, 0] ** 2 + e[:, 1] ** 2
    r = np.where(obtuse, e[:, 2] / 2, r)
    return float(0.5 * AMP / WAVE ** 2 * r.max() ** 2)


def test_spacing_estimate_on_a_grid_and_at_random():
    g = np.arange(0, 60, 0.8)
    X, Y = np.meshgrid(g, g)
    grid = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=1)
    assert point_spacing_mm(grid) == pytest.approx(0.8, rel=0.05)
    rng = np.random.default_rng(1)
    n = 40_000
    rand = np.stack([rng.uniform(0, 100, n), rng.uniform(0, 100, n), np.zeros(n)], axis=1)
    assert point_spacing_mm(rand) == pytest.approx(math.sqrt(100 * 100 / n), rel=0.08)
    # points 0.1 mm apart on lines 2 mm apart: the mean spacing is 0.45 mm, but no neighbour of the 16 nearest
    # lies across the lines, so the spacing is at least their reach (a lower bound of the 2 mm)
    x = np.arange(0, 60, 0.1)
    lines = np.concatenate([np.stack([x, np.full_like(x, y), np.zeros_like(x)], axis=1) for y in np.arange(0, 60, 2.0)])
    assert point_spacing_mm(lines) >= 0.79
    assert point_spacing_mm(lines) > math.sqrt(60 * 60 / lines.shape[0])


def test_dip_formula():
    assert dip_mm(1.5, 3.0) == pytest.approx(3.0 - math.sqrt(9.0 - 1.125))
    assert dip_mm(10.0, 3.0) == 3.0


def test_auto_chooses_triangles_on_a_sparse_cloud_and_points_on_a_dense_one():
    pts, nrm = sparse_surface()
    s = path_surface(pts, radius_mm=R)
    assert s.kind == "reconstructed" and s.faces.shape[0] > pts.shape[0]        # ~2 triangles per point
    assert s.spacing_mm > 0.2 * R and s.unmeshed_share < 0.02
    assert "exceeds" in s.reason and f"{s.spacing_mm:.3f} mm" in s.reason
    dense = path_surface(pts, radius_mm=10.0)                    # 1.5 mm < 20 % of R 10
    assert dense.kind == "points" and dense.faces is None
    forced = path_surface(pts, radius_mm=R, mode="points")
    assert forced.kind == "points" and "sink" in forced.warning


def test_refused_with_the_density_message_when_no_surface_can_be_built():
    # a line scanner's cloud: points 0.1 mm apart along lines 4 mm apart. Its mean spacing is small, but
    # across the lines none of its 16 nearest neighbours lies: the spacing is at least their reach (0.8 mm),
    # over 20 % of R; no triangle of circumradius <= 1.6 spacings joins two lines, so the plan is refused
    x = np.arange(0, 60, 0.1)
    lines = [np.stack([x, np.full_like(x, y), 0.01 * x], axis=1) for y in np.arange(0, 60, 4.0)]
    pts = np.concatenate(lines)
    assert point_spacing_mm(pts) > 0.2 * R
    with pytest.raises(InputError) as e:
        path_surface(pts, radius_mm=R)
    msg = e.value.message
    assert e.value.code == "cloud_too_sparse"
    assert "spacing" in msg and "R 3" in msg and "paths.surface = points" in msg and "tool.diameter_mm" in msg


def _every(xyz: np.ndarray, step: float) -> np.ndarray:
    """Points along the polyline ``xyz`` at most ``step`` apart (its vertices included)."""
    seg = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    n = np.maximum(np.ceil(seg / step).astype(int), 1)
    k = np.repeat(np.arange(seg.size), n)
    t = (np.arange(k.size) - np.repeat(np.cumsum(n) - n, n)) / n[k]
    return np.concatenate([xyz[k] + (xyz[k + 1] - xyz[k]) * t[:, None], xyz[-1:]])


def _plan(surface_mode: str):
    pts, nrm = sparse_surface()
    config = parse_config({
        "tool": {"diameter_mm": 2 * R}, "normals": {"method": "input"}, "visibility": {"cone_deg": [0, 60]},
        "setups": {"coverage": 0.9, "max_setups": 1},
        "paths": {"surface": surface_mode, "roughing": {"enabled": False}, "carry_stock": False,
                  "finishing": {"tolerance_mm": TOL, "scallop_mm": 0.05}},
        "simulate": {"enabled": False}})
    out = run_plan(Cloud(points=pts, normals=nrm, source_format="test"), config, name="sparse")
    centres = []
    for ap in out.extra["area_paths"]:
        xyz, _ = densify(ap.finishing, 0.05)          # arcs sampled every 0.05 mm, then every segment
        centres.append(ap.frame.to_part(_every(xyz, 0.05)))
    c = np.concatenate(centres)
    # only where the ball is over the sampled patch (the passes reach R past its edge)
    inside = (np.abs(c[:, 0]) < 30 - R) & (np.abs(c[:, 1]) < 30 - R)
    return out, distance_to_true_surface(c[inside])


def test_sparse_cloud_plans_on_triangles_without_gouging_the_true_surface():
    out, d = _plan("auto")
    ps = out.result.paths_surface
    assert ps.kind == "reconstructed" and ps.spacing_mm > 0.2 * R
    assert d.size > 1000
    # the moves keep R - tol from the triangles; the triangles themselves lie within the interpolation
    # error of the true surface (a few thousandths of a mm here), which comes on top
    pts, nrm = sparse_surface()
    chord = chord_error_bound(pts, path_surface(pts, radius_mm=R).faces)
    assert 0 < chord < 0.02
    assert d.min() >= R - TOL - chord - 1e-6, (d.min(), chord)


def test_the_same_cloud_on_points_alone_sinks_between_them():
    out, d = _plan("points")
    assert out.result.paths_surface.kind == "points"
    assert any("sink" in w for w in out.result.warnings)
    assert d.min() < R - 0.05          # 0.25 mm into the true surface: the gouge the guard prevents
