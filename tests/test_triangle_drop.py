"""Ball drop on a triangle mesh and the segment-triangle clearance (planning.geometry.triangles,
planning.toolpath.verify.move_clearance with triangles): against the numpy brute force, against OpenCAMLib's drop
cutter on the same triangles, analytic facet / edge / vertex contacts, and clearances against an
exact reference that shares no code with the kernel (the minimum of the distance over every face
of the segment x triangle polytope, Karush-Kuhn-Tucker style)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from planning.errors import ParameterError
from planning.geometry import triangles as tri
from planning.geometry.triangles import (
    TriangleDropSurface,
    brute_force_triangle_drop,
    triangle_clearance,
    triangle_drop,
)
from planning.toolpath.verify import ARC_CHORD_MM, BinnedCloud, move_clearance
from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    FEED,
    PLANE_AXES,
    PLANE_XY,
    PLANE_YZ,
    PLANE_ZX,
    Toolpath,
    arc_sweep_rad,
    lines,
)

# ----------------------------------------------------------------------------- meshes

def _random_mesh(seed, T=150):
    """A soup of random triangles of varied size and slope, either winding: some vertical (a
    vertical edge, so the normal's z is exactly 0), some overhanging others, some sharing vertices
    and edges with their neighbours (a strip), one degenerate."""
    rng = np.random.default_rng(seed)
    c = rng.uniform(-10, 10, (T, 1, 3))
    s = np.exp(rng.uniform(np.log(0.1), np.log(8.0), (T, 1, 1)))
    P = c + s * rng.normal(size=(T, 3, 3))
    nv = T // 10                                 # vertical: B straight above A
    P[:nv, 1, :2] = P[:nv, 0, :2]
    P[nv:2 * nv, :, 0] = P[nv:2 * nv, :1, 0]     # in a plane x = const
    P[2 * nv, 2] = P[2 * nv, 0] + 0.5 * (P[2 * nv, 1] - P[2 * nv, 0])   # collinear (zero area)
    V = P.reshape(-1, 3)
    F = np.arange(3 * T).reshape(T, 3)
    # a strip sharing vertices: a small height field, half of its rows wound the other way
    g = np.arange(-4.0, 4.01, 1.0)
    X, Y = np.meshgrid(g, g, indexing="ij")
    Z = rng.uniform(-2, 2, X.shape)
    n = g.size
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    Fs = np.concatenate([np.stack([a, a + n, a + n + 1], 1), np.stack([a, a + n + 1, a + 1], 1)])
    Fs[::2] = Fs[::2, ::-1]
    V = np.concatenate([V, np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1)])
    F = np.concatenate([F, Fs + 3 * T])
    return V, F


def _lines(V, F, rng, K=400):
    """Random lines, and lines through vertices, edge midpoints, at exactly R from a vertex, off the mesh."""
    xy = [rng.uniform(-16, 16, (K, 2))]
    vv = rng.choice(V.shape[0], 40, replace=False)
    xy.append(V[vv, :2])
    f = F[rng.choice(F.shape[0], 40, replace=False)]
    xy.append(0.5 * (V[f[:, 0], :2] + V[f[:, 1], :2]))
    xy.append(V[vv[:10], :2] + np.array([2.0, 0.0]))       # rho = R = 2 exactly (a tangent line)
    xy.append(np.array([[100.0, 100.0], [-100.0, 3.0]]))
    return np.concatenate(xy)


def _ocl_drop(V, F, xy, R):
    import opencamlib as ocl  # test dependency (pyproject [test])
    surf = ocl.STLSurf()
    for t in F:
        surf.addTriangle(ocl.Triangle(*(ocl.Point(*map(float, V[q])) for q in t)))
    cutter = ocl.BallCutter(2 * R, 100.0)    # keep a reference: OCL holds a bare pointer to it
    bdc = ocl.BatchDropCutter()
    bdc.setSTL(surf)
    bdc.setCutter(cutter)
    low = float(V[:, 2].min()) - 1000.0
    for x, y in xy:
        bdc.appendPoint(ocl.CLPoint(float(x), float(y), low))
    bdc.run()
    z = np.array([p.z for p in bdc.getCLPoints()])
    return np.where(z <= low, -np.inf, z + R)       # OCL gives the tip: centre = tip + R


# ----------------------------------------------------------------------------- drop

@pytest.mark.parametrize("seed", range(4))
def test_drop_matches_brute_force_and_opencamlib(seed):
    V, F = _random_mesh(seed)
    rng = np.random.default_rng(100 + seed)
    xy = _lines(V, F, rng)
    R = 2.0
    got = TriangleDropSurface(V, F, R).drop(xy)
    ref = brute_force_triangle_drop(V, F, xy, R)
    fin = np.isfinite(ref.z_mm)
    assert np.array_equal(np.isfinite(got.z_mm), fin)
    assert np.isinf(ref.z_mm).any() and fin.sum() > 300
    assert np.abs(got.z_mm[fin] - ref.z_mm[fin]).max() <= 1e-9
    assert np.all(got.contact[~fin] == -1) and np.all(got.contact[fin] >= 0)
    # the contact triangle alone gives the height
    own = np.array([brute_force_triangle_drop(V, F[[t]], xy[[k]], R).z_mm[0]
                    for k, t in enumerate(got.contact) if t >= 0])
    assert np.abs(own - got.z_mm[fin]).max() <= 1e-9
    z_ocl = _ocl_drop(V, F, xy, R)
    assert np.array_equal(np.isfinite(z_ocl), fin)
    assert np.abs(z_ocl[fin] - got.z_mm[fin]).max() <= 1e-6


def test_cell_size_and_kernels_do_not_change_the_answer():
    V, F = _random_mesh(7)
    rng = np.random.default_rng(7)
    xy = rng.uniform(-15, 15, (3000, 2))                  # >= the parallel threshold
    R = 1.5
    ref = TriangleDropSurface(V, F, R).drop(xy)
    for cell in (0.05, 0.7, 4.0, 50.0):
        d = TriangleDropSurface(V, F, R, cell_mm=cell).drop(xy)
        assert np.array_equal(d.z_mm, ref.z_mm) and np.array_equal(d.contact, ref.contact)
    serial = np.concatenate([TriangleDropSurface(V, F, R).drop(xy[i:i + 500]).z_mm for i in range(0, 3000, 500)])
    assert np.array_equal(serial, ref.z_mm)
    assert np.array_equal(triangle_drop(V, F, xy, R).z_mm, ref.z_mm)


def test_facet_contact_horizontal_triangle():
    V = np.array([[0.0, 0.0, 2.0], [10.0, 0.0, 2.0], [0.0, 10.0, 2.0]])
    for F in ([[0, 1, 2]], [[0, 2, 1]]):                  # both windings
        d = triangle_drop(V, F, [[2.0, 3.0], [5.0, 4.999], [11.0, 0.0], [14.0, 0.0]], 3.0)
        assert d.z_mm[0] == 5.0 and d.z_mm[1] == 5.0       # facet: plane + R
        assert d.z_mm[2] == pytest.approx(2.0 + math.sqrt(9.0 - 1.0), abs=1e-12)   # the vertex (10,0)
        assert d.z_mm[3] == -np.inf and d.contact[3] == -1
        assert np.array_equal(d.contact[:3], [0, 0, 0])


def test_facet_contact_inclined_plane():
    # z = 0.5 x: the centre sits R / cos(a) above the plane on the vertical line
    V = np.array([[-20.0, -20.0, -10.0], [20.0, -20.0, 10.0], [20.0, 20.0, 10.0], [-20.0, 20.0, -10.0]])
    F = [[0, 1, 2], [0, 2, 3]]
    R = 2.0
    xy = np.array([[0.3, 1.7], [-4.0, 5.0]])
    z = triangle_drop(V, F, xy, R).z_mm
    assert np.allclose(z, 0.5 * xy[:, 0] + R * math.sqrt(1 + 0.25), atol=1e-12)


@pytest.mark.parametrize("d", [0.0, 0.4, 0.9])
def test_edge_contact_on_a_ridge(d):
    # a roof with a horizontal ridge along x at z = 4, sides falling 2 in 1 (a = atan 2): a ball
    # centred within R sin(a) of the ridge line rests on the ridge edge, z = 4 + sqrt(R^2 - d^2)
    R = 1.5
    V = np.array([[-10, 0, 4], [10, 0, 4], [-10, 2, 0], [10, 2, 0], [-10, -2, 0], [10, -2, 0]], float)
    F = [[0, 1, 3], [0, 3, 2], [1, 0, 4], [1, 4, 5]]
    assert d < R * math.sin(math.atan(2.0))
    got = triangle_drop(V, F, [[1.234, d]], R)
    assert got.z_mm[0] == pytest.approx(4.0 + math.sqrt(R * R - d * d), abs=1e-12)
    ref = brute_force_triangle_drop(V, F, [[1.234, d]], R)
    assert got.z_mm[0] == pytest.approx(ref.z_mm[0], abs=1e-12)


@pytest.mark.parametrize("x,d", [(3.0, 0.0), (6.0, 0.8), (1.0, -1.2)])
def test_edge_contact_on_an_inclined_edge(x, d):
    # a vertical knife in the plane y = 0 (no facet contact) with its top edge z = 0.5 x, 0 <= x <= 10:
    # in the edge's plane the ball's section has radius r' = sqrt(R^2 - d^2) and rests on the line
    # z = m x at centre height m x + r' sqrt(1 + m^2)
    R, m = 2.0, 0.5
    V = np.array([[0, 0, 0], [10, 0, 5], [10, 0, -10]], float)
    got = triangle_drop(V, [[0, 1, 2]], [[x, d]], R).z_mm[0]
    rp = math.sqrt(R * R - d * d)
    assert got == pytest.approx(m * x + rp * math.sqrt(1 + m * m), abs=1e-12)


def test_vertex_contact_on_a_spike():
    # a steep pyramid: the ball rests on its apex, z = 10 + sqrt(R^2 - rho^2)
    ang = np.array([0.0, 2.1, 4.2])
    V = np.concatenate([[[0.0, 0.0, 10.0]], np.stack([np.cos(ang), np.sin(ang), np.zeros(3)], 1)])
    F = [[0, 1, 2], [0, 2, 3], [0, 3, 1]]
    R = 2.0
    xy = np.array([[0.0, 0.0], [1.2, 0.9], [-0.3, 1.9]])
    d = triangle_drop(V, F, xy, R)
    rho2 = (xy ** 2).sum(1)
    assert np.allclose(d.z_mm, 10.0 + np.sqrt(R * R - rho2), atol=1e-12)
    assert np.all(d.contact == 0)         # the apex is on every facet: the lowest index


def test_downward_facing_and_vertical_triangles_count():
    R = 1.0
    # an overhang (a triangle wound downwards above the line) and a vertical wall: both are touched
    V = np.array([[-3, -3, 5], [3, 0, 5], [-3, 3, 5], [0.5, -3, 0], [0.5, 3, 0], [0.5, 0, 8]], float)
    d = triangle_drop(V, [[0, 2, 1]], [[0.0, 0.0]], R)
    assert d.z_mm[0] == 6.0
    w = triangle_drop(V, [[3, 4, 5]], [[0.0, 0.0], [0.5, 0.0], [1.6, 0.0]], R)
    assert w.z_mm[0] == pytest.approx(8.0 + math.sqrt(R * R - 0.25), abs=1e-12)   # the top vertex
    assert w.z_mm[1] == 9.0
    assert w.z_mm[2] == -np.inf


def test_bad_input():
    V = np.zeros((3, 3))
    with pytest.raises(ParameterError):
        TriangleDropSurface(V, [[0, 1, 3]], 1.0)
    with pytest.raises(ParameterError):
        TriangleDropSurface(V, [[0, 1, 2]], 0.0)
    with pytest.raises(ParameterError):
        TriangleDropSurface(np.zeros((3, 2)), [[0, 1, 2]], 1.0)
    with pytest.raises(ParameterError):
        TriangleDropSurface(V, [[0.0, 1.0, 2.0]], 1.0)
    with pytest.raises(ParameterError):
        TriangleDropSurface(V, [[0, 1, 2]], 1.0).drop([[np.nan, 0.0]])
    empty = TriangleDropSurface(np.zeros((0, 3)), np.zeros((0, 3), np.int64), 1.0)
    assert empty.drop([[0.0, 0.0]]).z_mm[0] == -np.inf
    assert empty.clearance([[0.0, 0, 0]], [[1.0, 0, 0]])[0] == 1.0


def test_serial_kernels_have_their_own_cache_entries():
    for par, ser in ((tri._drop, tri._drop_serial), (tri._clearance, tri._clearance_serial)):
        assert par.targetoptions.get("parallel") and not ser.targetoptions.get("parallel")
        assert ser.targetoptions.get("nogil") and ser.py_func.__qualname__ != par.py_func.__qualname__
        assert ser.py_func.__code__ is par.py_func.__code__


# ----------------------------------------------------------------------------- clearance

def _kkt_faces():
    """Per face of the polytope {(l, u, v): 0 <= l <= 1, u, v >= 0, u + v <= 1} (active constraints
    G x + h = 0): a particular point and a null-space basis of its affine hull."""
    G = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, 0, 1], [0, -1, -1]], float)
    h = np.array([0, 1, 0, 0, 1], float)
    out = []
    for k in range(4):
        for act in itertools.combinations(range(5), k):
            if {0, 1} <= set(act) or {2, 3, 4} <= set(act):
                continue
            A, b = G[list(act)], -h[list(act)]
            if k:
                xp = np.linalg.lstsq(A, b, rcond=None)[0]
                _, sv, vt = np.linalg.svd(A)
                N = vt[int((sv > 1e-12).sum()):].T
            else:
                xp, N = np.zeros(3), np.eye(3)
            out.append((xp, N))
    return G, h, out


def _kkt_seg_tri(S, E, A, B, C):
    """Exact distance between the segments S E and the triangles A B C (rows paired): the convex
    quadratic |S + l (E - S) - A - u (B - A) - v (C - A)|^2 minimised on the affine hull of every
    face of the polytope, kept where feasible; the least is the minimum (the minimiser lies in the
    relative interior of some face)."""
    G, h, faces = _kkt_faces()
    D = np.stack([E - S, A - B, A - C], 2)             # (P,3,3): difference = (S - A) + D x
    r0 = S - A
    best = np.full(S.shape[0], np.inf)
    for xp, N in faces:
        if N.shape[1]:
            M = D @ N
            y = (np.linalg.pinv(M) @ (-(r0 + D @ xp))[:, :, None])[:, :, 0]
            x = xp + y @ N.T
        else:
            x = np.broadcast_to(xp, (S.shape[0], 3))
        ok = np.all(x @ G.T + h >= -1e-12, axis=1)
        d = np.linalg.norm(r0 + np.einsum("pij,pj->pi", D, x), axis=1)
        best = np.where(ok, np.minimum(best, d), best)
    return best


def _ref_clearance(V, F, S, E, cap):
    K, T = S.shape[0], F.shape[0]
    k, t = np.repeat(np.arange(K), T), np.tile(np.arange(T), K)
    d = _kkt_seg_tri(S[k], E[k], V[F[t, 0]], V[F[t, 1]], V[F[t, 2]]).reshape(K, T)
    return np.minimum(d.min(axis=1), cap)


def test_reference_on_analytic_cases():
    V = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0]])
    A, B, C = V[[0]], V[[1]], V[[2]]
    S = np.array([[1.0, 1, 2], [12, -3, 4], [1, 1, -1], [-2, 5, 1], [1, 1, 0.5]])
    E = np.array([[3.0, 2, 2], [12, -3, 4], [1, 1, 1], [-2, 5, 3], [8, 8, 0.5]])
    got = _kkt_seg_tri(S, E, *(np.repeat(X, 5, 0) for X in (A, B, C)))
    want = [2.0, math.sqrt(4 + 9 + 16), 0.0, math.sqrt(4 + 1), 0.5]
    assert np.allclose(got, want, atol=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_clearance_matches_exact_reference(seed):
    rng = np.random.default_rng(seed)
    V, F = _random_mesh(seed, T=30)
    F = F[:60]
    R = 1.5
    surf = TriangleDropSurface(V, F, R)
    K = 80
    S = rng.uniform(-9, 9, (K, 3))
    E = S + rng.normal(size=(K, 3)) * np.exp(rng.uniform(-4, 2, (K, 1)))
    E[:5] = S[:5]                                        # zero-length moves
    # moves through a triangle's interior point
    t = rng.choice(F.shape[0], 10)
    w = rng.dirichlet([1, 1, 1], 10)
    P = np.einsum("ki,kij->kj", w, V[F[t]])
    off = rng.normal(size=(10, 3))
    S[5:15], E[5:15] = P - off * rng.uniform(0.1, 1, (10, 1)), P + off * rng.uniform(0.1, 1, (10, 1))
    for cap in (R, 4 * R, np.inf):
        got = surf.clearance(S, E, cap)
        ref = _ref_clearance(V, F, S, E, cap)
        assert np.abs(got - ref).max() <= 1e-9, (cap, np.abs(got - ref).max())
    assert np.all(surf.clearance(S[5:15], E[5:15]) == 0.0)
    assert np.array_equal(triangle_clearance(S, E, surf), surf.clearance(S, E))
    big = np.repeat(S, 30, 0), np.repeat(E, 30, 0)        # the parallel kernel
    assert np.array_equal(surf.clearance(*big), np.repeat(surf.clearance(S, E), 30))


def test_clearance_axis_aligned():
    V = np.array([[0.0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]])
    F = [[0, 1, 2], [0, 2, 3]]
    R = 3.0
    surf = TriangleDropSurface(V, F, R)
    S = np.array([[1.0, 1, 2], [5, 5, 1], [12, 5, 1], [-1, -1, 2], [2, 2, -1], [15, 5, 0]])
    E = np.array([[9.0, 9, 2], [5, 5, -1], [12, 8, 1], [-1, -1, 5], [20, 2, -1], [20, 5, 0]])
    want = [2.0, 0.0, math.sqrt(5), math.sqrt(6), 1.0, R]
    assert np.allclose(surf.clearance(S, E), want, atol=1e-12)


def _mesh_move_clearance(tp, surf, cutoff_mm=None):
    """verify.move_clearance against the triangles alone (a cloud without points)."""
    binned = BinnedCloud(np.zeros((0, 3)), 1.0)
    binned.triangles = surf
    return move_clearance(tp, binned, surf.R, cutoff_mm=cutoff_mm)


def test_path_clearance_to_triangles_straight_and_arcs():
    V, F = _random_mesh(3, T=40)
    R = 1.0
    surf = TriangleDropSurface(V, F, R)
    rng = np.random.default_rng(3)
    pts = rng.uniform(-6, 6, (30, 3))
    tp = lines(pts, np.zeros(30, np.int8))
    tp.kind[5] = 0                                       # a rapid: not measured by default
    c = _mesh_move_clearance(tp, surf)
    assert np.isnan(c[0]) and np.isnan(c[5])
    m = np.flatnonzero(np.isfinite(c))
    assert np.array_equal(c[m], surf.clearance(pts[m - 1], pts[m]))
    # arcs (planar, helical, more than half a turn, full circle) are bounded below by their chord
    for plane, ccw, sweep, rise in ((PLANE_XY, True, 1.0, 0.0), (PLANE_ZX, False, 4.0, 0.0),
                                    (PLANE_YZ, True, 2.5, 0.7), (PLANE_XY, False, 2 * math.pi, 0.0)):
        a, b, n = PLANE_AXES[plane]
        cen = rng.uniform(-3, 3, 3)
        r, t0 = rng.uniform(0.5, 3), rng.uniform(0, 6)
        s = cen.copy()
        s[a], s[b] = cen[a] + r * math.cos(t0), cen[b] + r * math.sin(t0)
        e = cen.copy()
        t1 = t0 + (sweep if ccw else -sweep)
        e[a], e[b], e[n] = cen[a] + r * math.cos(t1), cen[b] + r * math.sin(t1), cen[n] + rise
        if sweep == 2 * math.pi:
            e = s.copy()
        tp = Toolpath(xyz_mm=np.stack([s, e]), kind=np.array([FEED, ARC_CCW if ccw else ARC_CW], np.int8),
                      centre_mm=np.stack([np.full(3, np.nan), cen]), plane=np.array([0, plane], np.int8),
                      use=np.zeros(2, np.int8))
        t_0, sw, _ = arc_sweep_rad(s, e, cen, plane, ccw)
        assert sw == pytest.approx(sweep if ccw else -sweep)
        got = _mesh_move_clearance(tp, surf, cutoff_mm=np.inf)[1]
        # the arc's true clearance is at most that of any of its points (end points included)
        tt = np.linspace(0, 1, 2001)
        q = np.empty((tt.size, 3))
        q[:, a] = cen[a] + r * np.cos(t_0 + sw * tt)
        q[:, b] = cen[b] + r * np.sin(t_0 + sw * tt)
        q[:, n] = s[n] + (e[n] - s[n]) * tt
        upper = surf.clearance(q, q, np.inf).min()
        assert 0.0 <= got <= upper + 1e-12
        # and not far below it: the chords' allowance, and 0.01 for the sampling of the arc points
        assert got >= upper - 2 * ARC_CHORD_MM - 0.01
