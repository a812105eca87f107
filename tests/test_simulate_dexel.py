"""Tri-dexel stock and material removal (issue 15, planning.simulate.dexel / stock / mesh).

Known-answer volumes against the stated resolution bound (dexel module docstring:
|V_k - V| <= r/2 * integral over the surface of (|n_u| + |n_v|) dA for family k with grid axes u, v),
the analytic swept intervals against brute force, collisions, the signed deviation and the mesh.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from planning.geometry.fixtures import BoxFixture, CylinderFixture, TableFixture
from planning.simulate import dexel_kernels as K
from planning.simulate.dexel import TriDexel, collide, cut, signed_deviation, simulate_moves, tool_pieces
from planning.simulate.mesh import closed_edges, mesh_volume, stock_mesh
from planning.simulate.motion import FEED, RAPID, ToolShape
from planning.simulate.stock import box_mesh, fixture_model, obstacle_model, riser, stock_cylinder

R_RES = 0.5
FLAT5 = ToolShape(number=2, kind="flat", radius_mm=5.0, corner_radius_mm=0.0, flute_length_mm=20.0)
BALL3 = ToolShape(number=1, kind="ball", radius_mm=3.0, corner_radius_mm=3.0, flute_length_mm=12.0)


def _box_bound(r, w):
    """Per family k the bound r/2 * sum over faces of (|n_u| + |n_v|) dA for an axis-aligned box
    of sides w: the faces normal to u and v, i.e. r * w_k * (w_u + w_v)."""
    return np.array([r * w[k] * (w[(k + 1) % 3] + w[(k + 2) % 3]) for k in range(3)])


# ------------------------------------------------------------------------------------------------ volumes

def test_box_volume_each_family_within_its_bound():
    lo, hi = np.array([0.13, 0.27, 0.31]), np.array([20.2, 30.1, 10.05])
    w = hi - lo
    b = TriDexel.box(lo, hi, R_RES)
    v = b.volumes_mm3()
    err = np.abs(v - np.prod(w))
    assert np.all(err <= _box_bound(R_RES, w) + 1e-9), (v, np.prod(w))
    # faces on cell boundaries: exact
    b2 = TriDexel.box([0, 0, 0], [20, 30, 10], R_RES, domain_lo=[-1, -1, -1], domain_hi=[21, 31, 11])
    np.testing.assert_allclose(b2.volumes_mm3(), 6000.0, rtol=0, atol=1e-9)


def test_cylinder_volume_oblique_axis():
    a = np.array([0.3, -0.5, 0.8])
    R, h = 6.0, 25.0
    c = TriDexel.cylinder([1.0, 2.0, 3.0], a, R, h, R_RES)
    v = c.volumes_mm3()
    exact = math.pi * R * R * h
    area = 2 * math.pi * R * h + 2 * math.pi * R * R
    assert np.all(np.abs(v - exact) <= R_RES / math.sqrt(2) * area)   # |n_u| + |n_v| <= sqrt 2
    assert abs(v.mean() - exact) < 0.01 * exact                     # second order in practice
    assert np.ptp(v) < 0.01 * exact                                  # the families agree


def test_stock_cylinder_about_z_contains_the_box():
    m = stock_cylinder([0, 0, 0], [30, 40, 10], "z", margin_mm=1.0, resolution_mm=R_RES)
    R, h = 25.0 + 1.0, 12.0
    assert abs(m.volume_mm3() - math.pi * R * R * h) < 0.01 * math.pi * R * R * h


def test_mesh_volumes_box_and_tetrahedron():
    rot = np.array([[math.cos(0.4), -math.sin(0.4), 0], [math.sin(0.4), math.cos(0.4), 0], [0, 0, 1.0]])
    V, F = box_mesh([0.1, 0.2, 0.3], [12.1, 8.2, 6.3], rot)
    m = TriDexel.from_mesh(V, F, R_RES)
    exact = 12 * 8 * 6
    area = 2 * (12 * 8 + 12 * 6 + 8 * 6)
    v = m.volumes_mm3()
    assert np.all(np.abs(v - exact) <= R_RES / math.sqrt(2) * area)
    assert abs(v.mean() - exact) < 0.02 * exact
    # a tetrahedron
    V = np.array([[0.1, 0.2, 0.3], [10.3, 0.1, 0.2], [0.4, 9.1, 0.1], [0.2, 0.3, 8.7]])
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    exact = abs(np.linalg.det(V[1:] - V[0])) / 6
    v = TriDexel.from_mesh(V, F, 0.25).volumes_mm3()
    assert np.all(np.abs(v - exact) < 0.05 * exact)


def test_mesh_rays_through_edges_and_vertices_are_counted_once():
    # box corners exactly on ray coordinates (domain lo 0, r 0.5: rays at 0.25 + 0.5 k): every ray
    # that grazes an edge or a vertex must still see an even number of crossings
    V, F = box_mesh([2.25, 3.25, 1.25], [7.75, 6.25, 4.75])
    m = TriDexel.from_mesh(V, F, R_RES, domain_lo=[0, 0, 0], domain_hi=[10, 10, 10])
    v = m.volumes_mm3()
    # on the boundary: counted by the tie rule on exactly one side of each pair of faces
    assert np.all(np.abs(v - 5.5 * 3.0 * 3.5) <= _box_bound(R_RES, np.array([5.5, 3.0, 3.5])))


def test_mesh_ray_through_a_fan_apex_is_counted_once():
    # a pyramid whose apex lies exactly on a Z ray (0.25 + 0.5 k): four faces meet there
    V = np.array([[1.1, 1.3, 0.2], [9.3, 1.2, 0.4], [9.1, 9.4, 0.3], [1.2, 9.2, 0.1], [5.25, 5.25, 8.0]])
    F = np.array([[0, 2, 1], [0, 3, 2], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    m = TriDexel.from_mesh(V, F, R_RES, domain_lo=[0, 0, -1], domain_hi=[10, 10, 10])
    i = j = int(round((5.25 - 0.25) / R_RES))
    iv = m.ray_intervals(2, i, j)
    assert len(iv) == 1 and abs(iv[0, 1] - 8.0) < 1e-9


def test_open_mesh_is_refused():
    V, F = box_mesh([0, 0, 0], [5, 5, 5])
    with pytest.raises(ValueError, match="not closed"):
        TriDexel.from_mesh(V, F[:-1], R_RES)


def test_union_and_fixture_models():
    lo, hi = np.array([-5.0, -5.0, -5.0]), np.array([25.0, 25.0, 25.0])
    a = fixture_model(BoxFixture((0, 0, 0), (10, 10, 10)), lo, hi, R_RES)
    b = fixture_model(BoxFixture((5, 5, 5), (15, 15, 15)), lo, hi, R_RES)
    u = a.union(b)
    np.testing.assert_allclose(u.volumes_mm3(), 2000 - 125, atol=1e-9)
    table = fixture_model(TableFixture(z_mm=-2.0), lo, hi, R_RES)
    np.testing.assert_allclose(table.volumes_mm3(), 30 * 30 * 3, atol=1e-9)
    ri = riser([0, 0, 0], [20, 20, 10], 8.0, -5.0)
    assert isinstance(ri, CylinderFixture) and ri.height_mm == 5.0
    obs = obstacle_model([BoxFixture((0, 0, 0), (10, 10, 10)), ri, None], lo, hi, R_RES)
    assert abs(obs.volume_mm3() - (1000 + math.pi * 16 * 5)) < 0.03 * 1000


# ------------------------------------------------------------------------------------------------ swept intervals

def _brute_inside(kind, o, e, P, d, a, z0, z1, R, S):
    """Points o + s e (s in S) inside the piece at some sampled t in [0, 1]."""
    ts = np.linspace(0.0, 1.0, 241)
    q = (o[None, None] + S[None, :, None] * e) - P - ts[:, None, None] * d       # (t, s, 3)
    if kind == K.CYL:
        h = q @ a
        rad2 = (q * q).sum(-1) - h * h
        ins = (h >= z0) & (h <= z1) & (rad2 <= R * R)
    else:
        c = q - z0 * a
        ins = (c * c).sum(-1) <= R * R
    return ins.any(0)


def _analytic(kind, o, e, P, d, a, z0, z1, R):
    f = int(np.argmax(np.abs(e)))
    da = d @ a
    if kind == K.CYL:
        w = o - P
        h0 = w @ a
        u = w - h0 * a
        A = e - (e @ a) * a
        B = -(d - da * a)
        args = (A @ A, A @ B, B @ B, u @ A, u @ B, u @ u - R * R, R)
        general = K.swept_interval(*args, True, h0, e @ a, -da, z0, z1)
        fast = K.cyl_interval(*args, h0, e @ a, -da, z0, z1, *K.cyl_pre(A @ A, A @ B, B @ B, e @ a, -da))
        assert general[0] == fast[0]
        if general[0]:
            assert abs(general[1] - fast[1]) < 1e-7 and abs(general[2] - fast[2]) < 1e-7
        return fast
    w = o - (P + z0 * a)
    general = K.swept_interval(1.0, -(e @ d), d @ d, w @ e, -(w @ d), w @ w - R * R, R, False, 0, 0, 0, 0, 0)
    capsule = K.capsule_interval(w[f], w @ w, d[f], w @ d, d @ d, R * R)
    assert general[0] == capsule[0]
    if general[0]:
        assert abs(general[1] - capsule[1]) < 1e-7 and abs(general[2] - capsule[2]) < 1e-7
    return capsule


@pytest.mark.parametrize("seed", [0, 1])
def test_swept_intervals_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    S = np.linspace(-30.0, 30.0, 2401)
    ds = S[1] - S[0]
    checked = 0
    for trial in range(60):
        kind = K.CYL if trial % 3 else K.SPH
        a = rng.normal(size=3)
        if trial % 5 == 0:
            a = np.eye(3)[rng.integers(3)] * rng.choice([-1.0, 1.0])     # axis along a ray family
        a /= np.linalg.norm(a)
        d = rng.normal(size=3) * rng.uniform(0.0, 8.0)
        if trial % 7 == 0:
            d = np.eye(3)[rng.integers(3)] * rng.uniform(-8, 8)         # move along a ray family
        if trial % 11 == 0:
            d = a * rng.uniform(-8, 8)                                   # plunge along the axis
        if trial % 13 == 0:
            d = np.zeros(3)
        P = rng.normal(size=3) * 2
        R = rng.uniform(0.5, 4.0)
        z0 = rng.uniform(0.0, 3.0)
        z1 = z0 + rng.uniform(0.2, 10.0)
        f = int(rng.integers(3))
        e = np.eye(3)[f]
        o = P + rng.uniform(0, z1) * a + rng.uniform(0, 1) * d + rng.normal(size=3) * R * 0.8   # aimed
        o[f] = 0.0
        ins = _brute_inside(kind, o, e, P, d, a, z0, z1, R, S)
        ok, s0, s1 = _analytic(kind, o, e, P, d, a, z0, z1, R)
        if not ins.any():
            assert not ok or s1 - s0 < 0.1, (trial, s0, s1)
            continue
        b0, b1 = S[ins][0], S[ins][-1]
        assert ok, (trial, b0, b1)
        slack = ds + 3 * np.linalg.norm(d) / 240 + 1e-6      # sampling of s and of t
        assert s0 <= b0 + ds and s1 >= b1 - ds, (trial, (s0, s1), (b0, b1))
        assert s0 >= b0 - slack and s1 <= b1 + slack, (trial, (s0, s1), (b0, b1))
        checked += 1
    assert checked > 30


def test_bull_nose_stack_contains_the_torus_within_its_tolerance():
    shape = ToolShape(3, "bull", 5.0, 1.5, 20.0)
    kind, z0, z1, r, _ = tool_pieces(shape, 0.05)
    R, rc = 5.0, 1.5
    zs = np.linspace(0, rc, 400)
    prof = R - rc + np.sqrt(np.maximum(0, rc * rc - (rc - zs) ** 2))
    for z, p in zip(zs, prof):
        inside = [(r[i]) for i in range(len(kind)) if z0[i] - 1e-12 <= z <= z1[i] + 1e-12]
        assert max(inside) >= p - 1e-9                                   # contains the torus
        assert min(inside) <= p + 0.05 * 2 + 1e-9 or z in (0.0, rc)     # overcut bounded


# ------------------------------------------------------------------------------------------------ cutting

def _stock(lo=(0, 0, 0), hi=(60, 40, 20)):
    return TriDexel.box(lo, hi, R_RES, domain_lo=np.array(lo) - 1, domain_hi=np.array(hi) + 1)


def test_flat_pocket_volume_is_the_minkowski_area_times_depth():
    st = _stock()
    R, D, top = 5.0, 3.0, 20.0
    x0, x1, y0, y1 = 15.0, 45.0, 12.0, 28.0
    pts = []
    for k, y in enumerate(np.arange(y0, y1 + 1e-9, 4.0)):                # stepover 4 <= 2R
        pts += [(x0, y), (x1, y)] if k % 2 == 0 else [(x1, y), (x0, y)]
    pts += [(x0, y1), (x0, y0), (x1, y0), (x1, y1), (x0, y1)]             # the perimeter pass
    p = np.array([[x, y, top - D] for x, y in pts])
    removed = cut(st, p[:-1], p[1:], np.tile([0, 0, 1.0], (len(p) - 1, 1)), FLAT5)
    W, H = x1 - x0, y1 - y0
    exact = ((W + 2 * R) * (H + 2 * R) - (4 - math.pi) * R * R) * D
    # bounds of the removed solid: walls (perimeter) and, for X and Y rays, floor and top (on cell
    # boundaries here, so they add nothing in fact)
    walls_xy = D * (2 * W + 2 * H + 8 * R)                  # integral of |n_x| + |n_y| over the walls
    bound_z = R_RES / 2 * walls_xy
    v0 = _stock().volumes_mm3() - st.volumes_mm3()
    assert abs(v0[2] - exact) <= bound_z
    area = (W + 2 * R) * (H + 2 * R)
    for k in (0, 1):
        assert abs(v0[k] - exact) <= R_RES / 2 * (walls_xy + 2 * area)
    assert abs(removed.sum() - v0.mean()) < 1e-6
    assert abs(removed.sum() - exact) < 0.01 * exact


def _segment_area(R, depth):
    if depth <= R:
        return R * R * math.acos((R - depth) / R) - (R - depth) * math.sqrt(2 * R * depth - depth * depth)
    return math.pi * R * R / 2 + 2 * R * (depth - R)


@pytest.mark.parametrize("depth", [2.0, 4.5])
def test_ball_groove_cross_section_and_profile(depth):
    st = _stock()
    R, top, yc = 3.0, 20.0, 20.25                                      # yc on a Z ray (rays at .25 + .5 k)
    s = np.array([[-5.0, yc, top - depth]])
    e = np.array([[65.0, yc, top - depth]])
    removed = cut(st, s, e, [[0, 0, 1.0]], BALL3)
    exact = _segment_area(R, depth) * 60.0
    arc = 2 * R * (1 - (R - depth) / R) if depth <= R else 2 * R + 2 * (depth - R)   # integral of |n_y| ds
    bound_z = R_RES / 2 * (60.0 * arc + 2 * _segment_area(R, depth))
    v = _stock().volumes_mm3() - st.volumes_mm3()
    assert abs(v[2] - exact) <= bound_z
    assert abs(removed.sum() - exact) < 0.02 * exact
    # the Z rays are exact along their lines: the groove's bottom under each ray
    u, vv = st.ray_coordinates(2)
    i = int(np.argmin(np.abs(u - 30.25)))
    for j in np.flatnonzero(np.abs(vv - yc) < R):
        dy = vv[j] - yc
        zc = top - depth + R
        bottom = zc - math.sqrt(R * R - dy * dy) if depth <= R or abs(dy) < R else top
        iv = st.ray_intervals(2, i, j)
        assert abs(iv[-1, 1] - min(top, bottom)) < 1e-9
    # the depth profile read back with signed_deviation: points on the groove, and 0.3 mm off it
    phi = np.linspace(-0.6, 0.6, 9) * (math.acos((R - depth) / R) if depth <= R else 1.5)
    # (points off the surface by +-0.3 mm: material left, positive; gouge, negative)
    centre = np.array([31.1, yc, top - depth + R])
    nrm = np.stack([np.zeros_like(phi), -np.sin(phi), np.cos(phi)], 1)   # towards the centre (out of the part)
    on = centre - R * nrm
    kappa = 1 / R

    def tol(p, off):
        # the stated bound: interpolation r^2 kappa / (4 c^2), c the normal's component along the
        # ray family at the ray's crossing, plus the reading along the ray off the normal:
        # off^2 kappa tan^2 / 2
        c = np.sqrt(1 - ((p[:, 1] - yc) / R) ** 2)
        return R_RES ** 2 * kappa / (4 * c ** 2) + off ** 2 * kappa * (1 - c ** 2) / c ** 2 / 2 + 1e-9

    for off in (0.0, 0.3, -0.3):
        p = on - off * nrm                                                # off > 0: below the surface
        dev = signed_deviation(st, p, nrm)
        assert np.all(np.abs(dev - off) <= tol(p, off)), (off, dev)


def test_oblique_flat_move_sweeps_its_analytic_volume():
    st = TriDexel.box([-40, -40, -40], [40, 40, 40], R_RES)
    a = np.array([0.5, 0.0, math.sqrt(0.75)])                             # 30 deg tilt
    dvec = np.array([math.sqrt(0.75), 0.3, -0.5])
    dvec -= (dvec @ a) * a                                                # perpendicular to the axis
    dvec *= 20.0 / np.linalg.norm(dvec)
    R, h = 4.0, 12.0
    tool = ToolShape(2, "flat", R, 0.0, h)
    s = -dvec / 2 - a * h / 2
    removed = cut(st, [s], [s + dvec], [a], tool)
    exact = h * (math.pi * R * R + 2 * R * 20.0)
    area = 2 * math.pi * R * R + 2 * 20.0 * h + 2 * math.pi * R * h
    assert abs(removed[0] - exact) <= R_RES / math.sqrt(2) * area
    assert abs(removed[0] - exact) < 0.01 * exact


def test_many_splits_grow_the_rays_without_losing_material():
    st = _stock()
    n = 21
    x = 2.0 + 2.7 * np.arange(n)                                         # 0.3 mm deep, 2.6 wide, 2.7 apart
    s = np.stack([x, np.full(n, -5.0), np.full(n, 19.7)], 1)
    e = np.stack([x, np.full(n, 45.0), np.full(n, 19.7)], 1)
    pool0 = st.pool.shape[0]
    removed = cut(st, s, e, np.tile([0, 0, 1.0], (n, 1)), BALL3)
    assert st.pool.shape[0] > pool0                                       # the pool was repacked
    u, v = st.ray_coordinates(0)
    j = int(np.argmin(np.abs(v - 19.75)))
    i = int(np.argmin(np.abs(u - 20.25)))
    iv = st.ray_intervals(0, i, j)
    assert len(iv) == n + 1                                               # every groove splits the X ray
    one = [cut(_stock(), s[k:k + 1], e[k:k + 1], [[0, 0, 1.0]], BALL3)[0] for k in range(n)]
    np.testing.assert_allclose(removed, one, rtol=1e-9)                   # disjoint grooves: additive
    assert np.all(np.diff(iv, axis=0)[:, 0] > 0)


# ------------------------------------------------------------------------------------------------ collisions

def test_rapid_through_the_block_reports_its_depth():
    st = _stock()
    tool = ToolShape(1, "ball", 3.0, 3.0, 12.0, ((12.0, 40.0, 3.0), (40.0, math.inf, 10.0)))
    y = 20.25                                                             # on a Z ray
    s = np.array([[-10.0, y, 18.0], [-10.0, y, 20.5], [-10.0, y, 20.5]])
    e = np.array([[70.0, y, 18.0], [70.0, y, 20.5], [70.0, y, 20.5]])
    kind = np.array([RAPID, RAPID, FEED])
    v0 = st.volume_mm3()
    run = simulate_moves(st, s, e, np.tile([0, 0, 1.0], (3, 1)), tool, kind)
    assert abs(run.rapid_depth_mm[0] - 2.0) < 1e-6                      # tip 2 mm below the top
    assert run.rapid_depth_mm[1] == 0.0 and run.holder_depth_mm[2] == 0.0
    assert run.removed_mm3[0] == 0.0 and st.volume_mm3() == v0           # rapids cut nothing
    grown = simulate_moves(st, s[1:2], e[1:2], [[0, 0, 1.0]], tool, [RAPID], rapid_clearance_mm=1.0)
    assert grown.rapid_depth_mm[0] > 0.4                                  # within the clearance
    # the whole tool, as collide sees it (not the holder alone)
    assert collide(st, s[:1], e[:1], [[0, 0, 1.0]], tool, which="tool")[0] == pytest.approx(2.0, abs=1e-6)
    assert collide(st, s[:1], e[:1], [[0, 0, 1.0]], tool, which="holder")[0] == 0.0


@pytest.mark.parametrize("gap,hit", [(-0.3, True), (-0.05, True), (0.2, False)])
def test_holder_against_a_wall(gap, hit):
    lo, hi = np.array([-20.0, -20.0, -5.0]), np.array([60.0, 60.0, 80.0])
    wall = obstacle_model([BoxFixture((30, 0, 0), (40, 40, 60))], lo, hi, R_RES)
    holder_r = 10.0
    tool = ToolShape(1, "ball", 3.0, 3.0, 12.0, ((20.0, 70.0, holder_r),))
    x = 30.0 - holder_r - gap                                             # holder edge at 30 + (-gap)
    s = np.array([[x, 5.0, 10.0]])
    e = np.array([[x, 35.0, 10.0]])
    d = collide(wall, s, e, [[0, 0, 1.0]], tool, which="holder")
    assert (d[0] > 0) == hit, d
    assert collide(wall, s, e, [[0, 0, 1.0]], ToolShape(1, "ball", 3.0, 3.0, 12.0), which="tool")[0] == 0.0


def test_holder_collision_on_a_feed_move_is_reported():
    st = _stock()
    tool = ToolShape(1, "ball", 3.0, 3.0, 5.0, ((5.0, 30.0, 3.0),))      # short flutes, shank above
    run = simulate_moves(st, [[-10.0, 20.25, 12.0]], [[70.0, 20.25, 12.0]], [[0, 0, 1.0]], tool, [FEED])
    assert run.removed_mm3[0] > 0
    assert abs(run.holder_depth_mm[0] - 3.0) < 1e-6                      # the shank from 17 to 20


def test_shank_leading_a_retract_collides_but_trailing_a_plunge_does_not():
    tool = ToolShape(1, "ball", 3.0, 3.0, 5.0, ((5.0, 30.0, 3.0),))      # shank as wide as the cutter
    ax = [[0, 0, 1.0]]
    # retract through material: the shank is in the block before the flutes get there
    st = _stock()
    up = simulate_moves(st, [[30.25, 20.25, 5.0]], [[30.25, 20.25, 15.0]], ax, tool, [FEED])
    assert up.holder_depth_mm[0] > 0
    # plunge into a block whose top is below the start: the flutes open the hole the shank follows
    st = TriDexel.box([0, 0, 0], [60, 40, 15], R_RES, domain_lo=[-1, -1, -1], domain_hi=[61, 41, 21])
    down = simulate_moves(st, [[30.25, 20.25, 18.0]], [[30.25, 20.25, 5.0]], ax, tool, [FEED])
    assert down.removed_mm3[0] > 0 and down.holder_depth_mm[0] == 0.0


# ------------------------------------------------------------------------------------------------ deviation

def test_signed_deviation_of_a_faced_plane():
    st = _stock()
    z = 17.3
    ys = np.arange(-6.0, 47.0, 4.0)
    p = []
    for k, y in enumerate(ys):
        p += [(-8.0, y, z), (68.0, y, z)] if k % 2 == 0 else [(68.0, y, z), (-8.0, y, z)]
    p = np.array(p)
    cut(st, p[:-1], p[1:], np.tile([0, 0, 1.0], (len(p) - 1, 1)), FLAT5)
    rng = np.random.default_rng(3)
    xy = rng.uniform([2, 2], [58, 38], (200, 2))
    for h, want in ((17.0, 0.3), (17.5, -0.2), (10.0, 1.0), (19.0, -1.0)):
        pts = np.column_stack([xy, np.full(200, h)])
        dev = signed_deviation(st, pts, np.tile([0, 0, 1.0], (200, 1)), max_mm=1.0)
        np.testing.assert_allclose(dev, want, atol=1e-9)
    assert np.isnan(signed_deviation(st, [[5, 5, 5]], [[0, 0, 0]])[0])


@pytest.mark.parametrize("normal", [(0.3, 0.1, 1.0), (1.0, 0.2, 0.4)])
def test_signed_deviation_is_exact_for_a_tilted_plane(normal):
    n = np.array(normal) / np.linalg.norm(normal)
    # the solid below the plane n.x = 5 inside a box, as a closed mesh (the box cut by the plane)
    big = 30.0
    t1 = np.cross(n, [0, 1.0, 0] if abs(n[1]) < 0.9 else [1.0, 0, 0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    c = 5 * n
    top = [c + big * (sx * t1 + sy * t2) for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    bot = [q - 20 * n for q in top]
    V = np.array(top + bot)
    F = np.array([[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6], [0, 4, 5], [0, 5, 1], [1, 5, 6], [1, 6, 2],
                  [2, 6, 7], [2, 7, 3], [3, 7, 4], [3, 4, 0]])
    m = TriDexel.from_mesh(V, F, R_RES)
    rng = np.random.default_rng(1)
    q = c + rng.uniform(-8, 8, (100, 1)) * t1 + rng.uniform(-8, 8, (100, 1)) * t2
    for off in (0.0, 0.25, -0.4):
        dev = signed_deviation(m, q + off * n, np.tile(n, (100, 1)), max_mm=2.0)
        np.testing.assert_allclose(dev, -off, atol=1e-9)


# ------------------------------------------------------------------------------------------------ mesh

@pytest.mark.parametrize("method", ["marching_cubes", "cuberille"])
def test_stock_mesh_is_closed_with_the_right_volume(method):
    if method == "marching_cubes":
        pytest.importorskip("skimage")
    lo, hi = np.array([0.13, 0.27, 0.31]), np.array([20.2, 30.1, 10.05])
    b = TriDexel.box(lo, hi, R_RES)
    V, F = stock_mesh(b, method=method)
    assert V.dtype == np.float32 and F.dtype == np.int32
    assert closed_edges(F)
    exact = float(np.prod(hi - lo))
    area = 2 * float((hi - lo)[0] * (hi - lo)[1] + (hi - lo)[1] * (hi - lo)[2] + (hi - lo)[0] * (hi - lo)[2])
    vol = mesh_volume(V, F)
    assert vol > 0 and abs(vol - exact) <= R_RES * area / 2
    if method == "marching_cubes":
        assert abs(vol - exact) < 0.005 * exact                           # vertices snapped to the rays
    # after a cut: still closed, and the volume follows the model's
    cut(b, [[-5, 15, 8.0]], [[25, 15, 8.0]], [[0, 0, 1.0]], BALL3)
    V, F = stock_mesh(b, method=method)
    assert closed_edges(F) if method == "marching_cubes" else True
    assert abs(mesh_volume(V, F) - b.volume_mm3()) < 0.02 * exact


def test_progress_of_simulate_moves_and_collide_ends_at_one_and_changes_nothing():
    """issue 17: the optional ``progress(fraction, message)``: fractions rising to 1.0, results
    identical to a run without it (chunks of 50 moves here, so it is called more than once)."""
    from planning.simulate import dexel as D

    x = np.linspace(-8, 8, 201)
    s = np.stack([x[:-1], np.zeros(200), np.full(200, 4.0)], 1)
    e = np.stack([x[1:], np.zeros(200), np.full(200, 4.0)], 1)
    a = np.tile([0.0, 0.0, 1.0], (200, 1))
    kind = np.full(200, FEED)
    calls = []
    one, two = TriDexel.box([-10, -10, 0], [10, 10, 5], 0.5), TriDexel.box([-10, -10, 0], [10, 10, 5], 0.5)
    old = D.CHUNK
    try:
        D.CHUNK = 50
        r1 = simulate_moves(one, s, e, a, BALL3, kind, progress=lambda f, m: calls.append(f))
        r2 = simulate_moves(two, s, e, a, BALL3, kind)
    finally:
        D.CHUNK = old
    assert np.array_equal(r1.removed_mm3, r2.removed_mm3) and np.array_equal(r1.holder_depth_mm, r2.holder_depth_mm)
    assert calls and calls[-1] == 1.0 and all(b >= a_ for a_, b in zip(calls, calls[1:]))
    calls.clear()
    d1 = collide(one, s, e, a, BALL3, "tool", progress=lambda f, m: calls.append(f))
    assert np.array_equal(d1, collide(one, s, e, a, BALL3, "tool")) and calls[-1] == 1.0


# ------------------------------------------------------------------------------------------------ column rise

@pytest.mark.parametrize("shape", [
    ToolShape(number=2, kind="flat", radius_mm=4.0, corner_radius_mm=0.0, flute_length_mm=25.0,
              pieces=((25.0, math.inf, 4.0),)),
    ToolShape(number=1, kind="ball", radius_mm=3.0, corner_radius_mm=0.0, flute_length_mm=12.0,
              pieces=((12.0, 40.0, 2.5), (40.0, math.inf, 10.0))),
    ToolShape(number=3, kind="bull", radius_mm=5.0, corner_radius_mm=1.5, flute_length_mm=20.0,
              pieces=((20.0, math.inf, 5.0),)),
], ids=["flat", "ball_necked_holder", "bull"])
def test_column_rise_is_where_the_swept_test_clears_within_its_tolerance(shape):
    """dexel.column_rise against collide (the swept test, exact for a move's own sweep): on a grooved
    box and a tilted axis, for tips in the material, beside it and in the air, the tool moved from the
    height found up to the top meets nothing, and moved from 0.03 mm more than the tolerance below it
    meets the material; -inf exactly where the whole column is clear."""
    from planning.simulate.dexel import column_rise

    rng = np.random.default_rng(7)
    lo, hi = np.array([-20.0, -20.0, -10.0]), np.array([20.0, 20.0, 10.0])
    stock = TriDexel.box(lo, hi, R_RES, domain_lo=lo - 12.0, domain_hi=hi + 12.0)
    ax = np.array([0.2, 0.3, 0.93])
    ax /= np.linalg.norm(ax)
    groove = np.array([[-30.0, -2.0, 7.0], [30.0, -2.0, 7.0], [30.0, 6.0, 4.0]])
    cut(stock, groove[:-1], groove[1:], np.tile(ax, (2, 1)), shape)
    tips = rng.uniform(lo - 8.0, hi + 8.0, (300, 3))
    length = 45.0 - tips @ ax
    axes = np.tile(ax, (tips.shape[0], 1))
    tol = 0.02
    s = column_rise(stock, tips, ax, length, shape, grow_mm=0.5, tol_mm=tol)
    whole = collide(stock, tips, tips + length[:, None] * ax, axes, shape, which="tool", grow_mm=0.5)
    met = np.isfinite(s)
    assert 50 < met.sum() < 290                      # both kinds of column occur
    # -inf: the whole column clear; else the contact lies on it
    assert np.all(whole[~met] == 0.0)
    assert np.all((s[met] >= -tol - 1e-9) & (s[met] <= length[met] + 1e-9))
    up = np.flatnonzero(met & (s < length - 0.1))
    start = tips[up] + (np.maximum(s[up], 0.0) + 1e-6)[:, None] * ax
    end = tips[up] + length[up, None] * ax
    assert np.all(collide(stock, start, end, axes[up], shape, which="tool", grow_mm=0.5) == 0.0)
    low = up[s[up] > tol + 0.03]
    start = tips[low] + (s[low] - tol - 0.03)[:, None] * ax
    end = tips[low] + length[low, None] * ax
    assert np.all(collide(stock, start, end, axes[low], shape, which="tool", grow_mm=0.5) > 0.0)
    assert low.size > 30
    # the serial and the parallel kernels agree
    one = np.array([column_rise(stock, tips[k:k + 1], ax, length[k], shape, grow_mm=0.5, tol_mm=tol)[0]
                    for k in range(0, 300, 37)])
    np.testing.assert_array_equal(one, s[::37])
    # the row segments passed over by their material bounds change nothing: every ray read gives the same
    np.testing.assert_array_equal(column_rise(_every_ray_read(stock), tips, ax, length, shape, grow_mm=0.5,
                                              tol_mm=tol), s)


def _every_ray_read(stock: TriDexel) -> TriDexel:
    """A copy of ``stock`` whose row segments' material bounds say every segment may hold material
    anywhere: the kernels that pass segments over by those bounds then read every ray."""
    out = stock.copy()
    out.seg_lo[:] = -np.inf
    out.seg_hi[:] = np.inf
    return out


@pytest.mark.parametrize("shape", [
    ToolShape(number=2, kind="flat", radius_mm=4.0, corner_radius_mm=0.0, flute_length_mm=25.0,
              pieces=((25.0, math.inf, 4.0),)),
    ToolShape(number=1, kind="ball", radius_mm=3.0, corner_radius_mm=0.0, flute_length_mm=12.0,
              pieces=((12.0, 40.0, 2.5), (40.0, math.inf, 10.0))),
], ids=["flat", "ball_necked_holder"])
def test_column_rise_of_a_rapid_across_is_where_the_swept_rapids_clear(shape):
    """dexel.column_rise with a sweep (a rapid across the axis at every height) against collide: on a
    grooved box and a tilted axis, for rapids from random starts to random ends, the rapid at the
    height found and at heights above it meets nothing, 0.05 mm below it meets the material."""
    from planning.simulate.dexel import column_rise

    rng = np.random.default_rng(11)
    lo, hi = np.array([-20.0, -20.0, -10.0]), np.array([20.0, 20.0, 10.0])
    stock = TriDexel.box(lo, hi, R_RES, domain_lo=lo - 12.0, domain_hi=hi + 12.0)
    ax = np.array([-0.25, 0.2, 0.95])
    ax /= np.linalg.norm(ax)
    groove = np.array([[-30.0, 3.0, 6.0], [30.0, 3.0, 6.0], [30.0, -8.0, 3.0]])
    cut(stock, groove[:-1], groove[1:], np.tile(ax, (2, 1)), shape)
    a = rng.uniform(lo - 6.0, hi + 6.0, (200, 3))
    b = rng.uniform(lo - 6.0, hi + 6.0, (200, 3))
    d = (b - a) - np.outer((b - a) @ ax, ax)           # across the axis
    length = 45.0 - a @ ax
    tol = 0.02
    s = column_rise(stock, a, ax, length, shape, grow_mm=0.5, tol_mm=tol, sweep=d)
    met = np.isfinite(s) & (s >= 0.0)
    assert 40 < met.sum() < 195
    axes = np.tile(ax, (a.shape[0], 1))

    def hits(h):
        st = a + h[:, None] * ax
        return collide(stock, st, st + d, axes[: len(h)], shape, which="tool", grow_mm=0.5) > 0

    # clear at the height found and at every 0.7 mm above it up to the top
    h = np.where(met, np.maximum(s, 0.0) + 1e-6, 0.0)
    for k in range(0, 80):
        hk = np.minimum(h + 0.7 * k, length)
        assert not hits(hk).any(), k
    # met 0.05 mm below it
    low = np.flatnonzero(met & (s > tol + 0.05) & (s < length - 0.1))
    assert low.size > 20
    st = a[low] + (s[low] - tol - 0.03)[:, None] * ax
    assert np.all(collide(stock, st, st + d[low], axes[low], shape, which="tool", grow_mm=0.5) > 0)
    # a rapid never met: -inf, and the rapid at its start height clears
    never = ~np.isfinite(s)
    assert not hits(np.zeros(a.shape[0]))[never].any()
    # the row segments passed over by their material bounds change nothing
    np.testing.assert_array_equal(column_rise(_every_ray_read(stock), a, ax, length, shape, grow_mm=0.5, tol_mm=tol,
                                              sweep=d), s)
