"""Point-based ball drop (planning.toolpath.balldrop): exact against brute force, analytic answers, and
OpenCAMLib's BatchDropCutter on a triangle mesh of the same surface."""

from __future__ import annotations

import numpy as np
import pytest

from planning.toolpath.balldrop import ball_drop, brute_force_ball_drop
from planning.errors import ParameterError


@pytest.mark.parametrize("seed", range(4))
def test_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-20, -20, -3], [20, 20, 3], size=(3000, 3))
    xy = rng.uniform(-25, 25, size=(400, 2))
    R = [0.5, 2.0, 3.0, 6.0][seed]
    fast = ball_drop(pts, xy, R)
    ref = brute_force_ball_drop(pts, xy, R)
    assert np.array_equal(fast.z_mm, ref.z_mm)
    assert np.array_equal(fast.contact, ref.contact)
    assert np.isinf(ref.z_mm).any() and np.isfinite(ref.z_mm).any()   # lines off the cloud too
    for cell in (0.1, 1.0, 7.0):
        assert np.array_equal(ball_drop(pts, xy, R, cell_mm=cell).z_mm, ref.z_mm)


def test_plane_and_sphere_known_answers():
    # a dense plane z = 2: the centre sits R above it (the nearest point is within the spacing)
    g = np.arange(-10, 10.001, 0.05)
    X, Y = np.meshgrid(g, g)
    plane = np.stack([X.ravel(), Y.ravel(), np.full(X.size, 2.0)], 1)
    R = 3.0
    z = ball_drop(plane, [[0.013, -0.021], [4.0, 4.0]], R).z_mm
    assert np.all(z <= 2.0 + R + 1e-12) and np.all(z >= 2.0 + R - 0.05 ** 2 / R)
    # a single point: the ball centre is on the sphere of radius R about it
    p = np.array([[1.0, 2.0, 3.0]])
    assert ball_drop(p, [[1.0, 2.0]], R).z_mm[0] == pytest.approx(6.0)
    assert ball_drop(p, [[1.0 + 1.8, 2.0 + 2.4]], R).z_mm[0] == pytest.approx(3.0)   # rho = 3: on the equator
    assert ball_drop(p, [[1.0 + 3.01, 2.0]], R).z_mm[0] == -np.inf


def test_bad_input():
    with pytest.raises(ParameterError):
        ball_drop(np.zeros((3, 2)), [[0, 0]], 1.0)
    with pytest.raises(ParameterError):
        ball_drop(np.zeros((3, 3)), [[0, 0]], 0.0)
    with pytest.raises(ParameterError):
        ball_drop(np.zeros((3, 3)), [[np.nan, 0]], 1.0)


def _mesh(spacing=1.0, half=20.0):
    g = np.arange(-half, half + 1e-9, spacing)
    X, Y = np.meshgrid(g, g, indexing="ij")
    Z = 5.0 * np.sin(X / 10.0) * np.cos(Y / 15.0)
    V = np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1)
    n = g.size
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    b, c, d = a + n, a + n + 1, a + 1
    T = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return V, T


def _sample_triangles(V, T, k):
    """Barycentric grid with k subdivisions on every triangle (vertices and edges included)."""
    u, v = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
    keep = u + v <= k
    u, v = u[keep] / k, v[keep] / k
    A, B, C = V[T[:, 0]], V[T[:, 1]], V[T[:, 2]]
    P = A[:, None] + u[None, :, None] * (B - A)[:, None] + v[None, :, None] * (C - A)[:, None]
    return P.reshape(-1, 3)


def test_agrees_with_opencamlib_on_the_same_mesh():
    import opencamlib as ocl       # test dependency (pyproject [test])
    V, T = _mesh(spacing=1.0)
    R = 3.0
    surf = ocl.STLSurf()
    for t in T:
        surf.addTriangle(ocl.Triangle(*(ocl.Point(*map(float, V[q])) for q in t)))
    cutter = ocl.BallCutter(2 * R, 30.0)
    bdc = ocl.BatchDropCutter()
    bdc.setSTL(surf)
    bdc.setCutter(cutter)
    rng = np.random.default_rng(5)
    xy = rng.uniform(-15, 15, size=(300, 2))
    for x, y in xy:
        bdc.appendPoint(ocl.CLPoint(float(x), float(y), -100.0))
    bdc.run()
    z_ocl = np.array([p.z for p in bdc.getCLPoints()]) + R     # OCL gives the tip: centre = tip + R
    k = 10
    pts = _sample_triangles(V, T, k)
    z = ball_drop(pts, xy, R).z_mm
    # Sampling error bound: every mesh point is within delta of a sample (delta = longest edge / k).
    # Along a facet, f(q) = q_z + sqrt(R^2 - rho^2) peaks at the contact with zero first variation;
    # its second derivative is at most 1 / (R cos^3 a), a the contact angle, tan a <= the mesh's
    # largest slope g. So 0 <= z_ocl - z <= delta^2 / (2 R cos^3 a) (+ OCL's own 1e-6 tolerance).
    g = np.max(np.hypot(np.gradient(V[:, 2].reshape(41, 41), 1.0, axis=0),
                        np.gradient(V[:, 2].reshape(41, 41), 1.0, axis=1))) * 1.1
    cos_a = 1.0 / np.sqrt(1 + g * g)
    delta = np.sqrt(2.0) * 1.0 / k
    bound = delta ** 2 / (2 * R * cos_a ** 3)
    diff = z_ocl - z
    assert np.all(diff >= -1e-6), diff.min()
    assert np.all(diff <= bound + 1e-6), (diff.max(), bound)


def test_serial_kernels_have_their_own_cache_entries():
    # numba's cache keys an entry by module, qualified name, line and signature, not by flags: a
    # serial copy of a parallel kernel under the same name would load whichever compiled first
    from planning.toolpath import balldrop, safety, verify

    for par, ser in ((balldrop._drop, balldrop._drop_serial), (verify._prep, verify._prep_serial),
                     (verify._clearance, verify._clearance_serial), (safety._finished, safety._finished_serial)):
        assert par.targetoptions.get("parallel") and not ser.targetoptions.get("parallel")
        assert ser.targetoptions.get("nogil") and ser.py_func.__qualname__ != par.py_func.__qualname__
        assert ser.py_func.__code__ is par.py_func.__code__          # the same code
