"""Gouge verification (planning.toolpath.verify): exact move clearances against brute force
(every point against every move; arcs both sampled very finely and by an analytic distance),
analytic cases for segments and arcs, and the cut-off."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from planning.errors import ParameterError
from planning.toolpath.moves import (ARC_CCW, ARC_CW, FEED, PLANE_AXES, PLANE_XY, PLANE_YZ, PLANE_ZX, RAPID,
                                     USE_CUT, USE_RAPID, Toolpath, arc_sweep_rad, lines)
from planning.toolpath.verify import BinnedCloud, clearance_report, move_clearance


# ----------------------------------------------------------------------------- references

def _seg_ref(pts, a, b):
    d = b - a
    L2 = d @ d
    u = np.clip((pts - a) @ d / L2, 0.0, 1.0) if L2 > 0 else np.zeros(len(pts))
    return np.sqrt(((pts - (a + u[:, None] * d)) ** 2).sum(1))


def _arc_samples(s, e, c, plane, ccw, n):
    """n + 1 points on the arc / helix from s to e (start radius, normal coordinate linear)."""
    a, b, k = PLANE_AXES[plane]
    t0, sw, r = arc_sweep_rad(s, e, c, plane, ccw)
    t = np.linspace(0.0, 1.0, n + 1)
    q = np.empty((n + 1, 3))
    q[:, a] = c[a] + r * np.cos(t0 + sw * t)
    q[:, b] = c[b] + r * np.sin(t0 + sw * t)
    q[:, k] = s[k] + (e[k] - s[k]) * t
    return q


def _sampled_ref(pts, s, e, c, plane, ccw, n=200_000):
    """Distance from each point to a fine sampling of the arc (an upper bound of the exact one,
    within half a sample step)."""
    return cKDTree(_arc_samples(s, e, c, plane, ccw, n)).query(pts)[0]


def _planar_arc_ref(pts, s, e, c, plane, ccw):
    """Analytic distance to a planar arc: the nearest point of the full circle if it lies on the
    arc (its angle from the start, in the turning direction, within the sweep), else the nearer
    end."""
    a, b, k = PLANE_AXES[plane]
    t0, sw, r = arc_sweep_rad(s, e, c, plane, ccw)
    u, v = pts[:, a] - c[a], pts[:, b] - c[b]
    rho = np.hypot(u, v)
    ang = np.arctan2(v, u)
    rel = np.mod(ang - t0, 2 * np.pi) if sw > 0 else np.mod(t0 - ang, 2 * np.pi)
    on_arc = (rel <= abs(sw)) | (rho == 0)
    h = pts[:, k] - s[k]
    ends = np.stack([c + 0.0, c + 0.0])
    ends[0, a], ends[0, b] = c[a] + r * np.cos(t0), c[b] + r * np.sin(t0)
    ends[1, a], ends[1, b] = c[a] + r * np.cos(t0 + sw), c[b] + r * np.sin(t0 + sw)
    ends[:, k] = s[k]
    d_end = np.sqrt(((pts[:, None, :] - ends[None]) ** 2).sum(-1)).min(1)
    return np.where(on_arc, np.hypot(rho - r, h), d_end)


def _arc_path(rng, n, plane, helix):
    """A chain of n random arcs in ``plane`` (each end equidistant from its centre)."""
    a, b, k = PLANE_AXES[plane]
    xyz = np.zeros((n + 1, 3))
    cen = np.full((n + 1, 3), np.nan)
    kind = np.full(n + 1, RAPID, np.int8)
    xyz[0] = rng.uniform(-3, 3, 3)
    for i in range(1, n + 1):
        s = xyz[i - 1]
        c = s.copy()
        c[a] += rng.uniform(-4, 4)
        c[b] += rng.uniform(-4, 4)
        r = math.hypot(s[a] - c[a], s[b] - c[b])
        th = rng.uniform(-math.pi, math.pi)
        e = c.copy()
        e[a], e[b] = c[a] + r * math.cos(th), c[b] + r * math.sin(th)
        e[k] = s[k] + (rng.uniform(-2, 2) if helix else 0.0)
        xyz[i], cen[i] = e, c
        kind[i] = ARC_CCW if rng.random() < 0.5 else ARC_CW
    pl = np.where(kind == RAPID, 0, plane).astype(np.int8)
    return Toolpath(xyz, kind, cen, pl, np.full(n + 1, USE_CUT, np.int8))


# ----------------------------------------------------------------------------- brute force

@pytest.mark.parametrize("seed", range(3))
def test_segments_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-10, -10, -3], [10, 10, 3], size=(1500, 3))
    cl = rng.uniform([-12, -12, -2], [12, 12, 5], size=(60, 3))
    cl[40:50, 2] += 6.0                                      # some moves high above the cloud
    cl[10] = cl[9]                                           # a zero-length move
    tp = lines(cl, np.full(60, USE_CUT, np.int8))
    ref = np.array([np.nan] + [_seg_ref(pts, cl[i - 1], cl[i]).min() for i in range(1, 60)])
    exact = move_clearance(tp, pts, 2.0, cutoff_mm=np.inf)
    assert np.isnan(exact[0])
    np.testing.assert_allclose(exact[1:], ref[1:], rtol=0, atol=1e-12)
    for R, cell in ((2.0, None), (2.0, 0.13), (3.0, 7.0), (0.7, None)):
        got = move_clearance(tp, pts, R, cell_mm=cell)
        np.testing.assert_allclose(got[1:], np.minimum(ref[1:], R), rtol=0, atol=1e-12)
    assert (ref[1:] > 2.0).any() and (ref[1:] < 2.0).any()   # both sides of the cut-off


@pytest.mark.parametrize("plane", [PLANE_XY, PLANE_ZX, PLANE_YZ])
def test_planar_arcs_match_analytic_and_sampled(plane):
    rng = np.random.default_rng(plane)
    tp = _arc_path(rng, 12, plane, helix=False)
    pts = rng.uniform(-9, 9, size=(400, 3))
    pts[:5] = tp.centre_mm[1:6]                              # points at arc centres
    got = move_clearance(tp, pts, 1.0, cutoff_mm=np.inf)
    for i in range(1, tp.n_moves):
        s, e, c = tp.xyz_mm[i - 1], tp.xyz_mm[i], tp.centre_mm[i]
        ccw = tp.kind[i] == ARC_CCW
        ana = _planar_arc_ref(pts, s, e, c, plane, ccw).min()
        smp = _sampled_ref(pts, s, e, c, plane, ccw, 50_000).min()
        assert got[i] == pytest.approx(ana, abs=1e-9)
        assert got[i] <= smp + 1e-9 and smp - got[i] < 2e-3    # sampling is a close upper bound
    # the cut-off caps, never raises
    R = 1.5
    np.testing.assert_allclose(move_clearance(tp, pts, R)[1:], np.minimum(got[1:], R), atol=1e-12)


def test_helical_arcs_match_fine_sampling():
    rng = np.random.default_rng(7)
    for plane in (PLANE_ZX, PLANE_XY):
        tp = _arc_path(rng, 8, plane, helix=True)
        pts = rng.uniform(-8, 8, size=(150, 3))
        got = move_clearance(tp, pts, 1.0, cutoff_mm=np.inf)
        for i in range(1, tp.n_moves):
            s, e, c = tp.xyz_mm[i - 1], tp.xyz_mm[i], tp.centre_mm[i]
            d = _sampled_ref(pts, s, e, c, plane, tp.kind[i] == ARC_CCW)
            # exact <= any sample; arcs here are < 60 mm long: 200k samples are < 3e-4 mm apart
            assert got[i] <= d.min() + 1e-12
            assert d.min() - got[i] < 2e-4


# ----------------------------------------------------------------------------- analytic cases

def _one(points, xyz, kind=None, centre=None, plane=None, **kw):
    xyz = np.asarray(xyz, float)
    n = len(xyz)
    k = np.full(n, FEED, np.int8) if kind is None else np.asarray(kind, np.int8)
    cen = np.full((n, 3), np.nan) if centre is None else np.asarray(centre, float)
    pl = np.zeros(n, np.int8) if plane is None else np.asarray(plane, np.int8)
    tp = Toolpath(xyz, k, cen, pl, np.full(n, USE_CUT, np.int8))
    return move_clearance(tp, np.asarray(points, float).reshape(-1, 3), 1.0, cutoff_mm=np.inf, **kw)


def test_segment_known_distances():
    a, b = [0.0, 0.0, 0.0], [10.0, 0.0, 0.0]
    assert _one([[4.0, 3.0, 4.0]], [a, b])[1] == pytest.approx(5.0)          # foot inside
    assert _one([[-3.0, 4.0, 0.0]], [a, b])[1] == pytest.approx(5.0)         # beyond the start
    assert _one([[13.0, 0.0, -4.0]], [a, b])[1] == pytest.approx(5.0)        # beyond the end
    assert _one([[7.0, 0.0, 0.0]], [a, b])[1] == 0.0                         # on it
    assert _one([[1.0, 2.0, 2.0]], [a, a])[1] == pytest.approx(3.0)          # zero length


def test_arc_known_distances():
    # G18 quarter arc about the origin, radius 5, from +Z (angle 0) to +X (angle 90 deg): CCW
    s, e, c = [0.0, 0.0, 5.0], [5.0, 0.0, 0.0], [0.0, 0.0, 0.0]

    def d(p, kind=ARC_CCW):
        return _one([p], [s, e], kind=[RAPID, kind], centre=[[np.nan] * 3, c], plane=[0, PLANE_ZX])[1]

    assert d([7 * 0.6, 0.0, 7 * 0.8]) == pytest.approx(2.0)                  # outside, radially
    assert d([0.6, 0.0, 0.8]) == pytest.approx(4.0)                          # inside, radially
    assert d([3.0, 2.0, 4.0]) == pytest.approx(2.0)                          # on the arc, off the plane
    assert d([0.0, 0.0, 0.0]) == pytest.approx(5.0)                          # at the centre
    assert d([0.0, 2.0, 0.0]) == pytest.approx(math.sqrt(29.0))              # above the centre
    assert d([1e-7, 0.0, 1e-7]) == pytest.approx(5.0 - math.sqrt(2e-14), abs=1e-12)   # near the centre
    assert d([-2.0, 0.0, 5.0]) == pytest.approx(2.0)                         # before the start, on its tangent
    assert d([5.0, 0.0, -3.0]) == pytest.approx(3.0)                         # past the end, on its tangent
    assert d(s) == 0.0 and d(e) == pytest.approx(0.0, abs=1e-12)             # the end points
    far = [-4.0 / math.sqrt(2), 0.0, -4.0 / math.sqrt(2)]                    # opposite side, radius 4
    to_end = math.dist(far, e)
    assert d(far) == pytest.approx(to_end)
    assert d(far, ARC_CW) == pytest.approx(1.0)                              # the 270-degree CW arc passes there
    # a full turn (start == end): every angle is on it
    full = _one([[0.0, 0.0, -6.0]], [s, s], kind=[RAPID, ARC_CW], centre=[[np.nan] * 3, c], plane=[0, PLANE_ZX])
    assert full[1] == pytest.approx(1.0)


def test_helix_known_distance():
    # G17 half helix about the Z axis, radius 4, rising 2 mm: a point on its axis at mid height
    s, e, c = [4.0, 0.0, 0.0], [-4.0, 0.0, 2.0], [0.0, 0.0, 0.0]
    got = _one([[0.0, 0.0, 1.0], [0.0, 4.0, 1.0], [0.0, 5.0, 1.0]][:1], [s, e], kind=[RAPID, ARC_CCW],
               centre=[[np.nan] * 3, c], plane=[0, PLANE_XY])
    assert got[1] == pytest.approx(4.0)
    # the helix passes through (0, 4, 1) at mid sweep; a point 1 mm outside it radially
    got = _one([[0.0, 5.0, 1.0]], [s, e], kind=[RAPID, ARC_CCW], centre=[[np.nan] * 3, c], plane=[0, PLANE_XY])
    assert got[1] == pytest.approx(1.0, abs=1e-9)


def test_spiral_end_mismatch_is_a_lower_bound():
    # end 0.01 mm off the start radius: the reported value never exceeds the distance to the
    # spiral moves.densify draws
    s, e, c = [0.0, 0.0, 5.0], [5.01, 0.0, 0.0], [0.0, 0.0, 0.0]
    rng = np.random.default_rng(2)
    pts = rng.uniform(-7, 7, size=(300, 3))
    tp = Toolpath(np.array([s, e]), np.array([RAPID, ARC_CCW], np.int8), np.array([[np.nan] * 3, c]),
                  np.array([0, PLANE_ZX], np.int8), np.full(2, USE_CUT, np.int8))
    from planning.toolpath.moves import densify
    q, _ = densify(tp, 1e-4)
    ref = cKDTree(q).query(pts)[0].min()
    got = move_clearance(tp, pts, 1.0, cutoff_mm=np.inf)[1]
    assert got <= ref + 1e-12 and ref - got <= 0.01 + 1e-4


# ----------------------------------------------------------------------------- cut-off, selection, report

def test_cutoff_selection_and_report():
    rng = np.random.default_rng(5)
    pts = rng.uniform([-10, -10, -1], [10, 10, 0], size=(3000, 3))
    x = np.linspace(-9, 9, 40)
    cl = np.column_stack([x, np.zeros(40), np.where(np.arange(40) < 20, 0.8, 5.0)])
    use = np.full(40, USE_CUT, np.int8)
    use[0] = USE_RAPID
    use[25] = USE_RAPID
    tp = lines(cl, use)
    exact = move_clearance(tp, pts, 2.0, cutoff_mm=np.inf)
    got = move_clearance(tp, pts, 2.0)                           # default cut-off R = 2
    feed = tp.kind == FEED
    assert np.all(np.isnan(got[~feed])) and np.all(np.isfinite(got[feed]))
    np.testing.assert_allclose(got[feed], np.minimum(exact[feed], 2.0), atol=1e-12)
    assert np.all(got[26:] == 2.0)                               # 5 mm up: nothing within the cut-off
    got3 = move_clearance(tp, pts, 2.0, cutoff_mm=0.5)
    np.testing.assert_allclose(got3[feed], np.minimum(exact[feed], 0.5), atol=1e-12)
    # selection by mask and by indices; rapids are measured as straight moves when asked
    idx = np.array([0, 3, 25, 7])
    sel = move_clearance(tp, pts, 2.0, moves=idx, cutoff_mm=np.inf)
    assert np.isnan(sel[0]) and np.count_nonzero(np.isfinite(sel)) == 3
    np.testing.assert_allclose(sel[[3, 7]], exact[[3, 7]], atol=1e-12)
    assert sel[25] == pytest.approx(_seg_ref(pts, cl[24], cl[25]).min(), abs=1e-12)
    mask = np.zeros(40, bool)
    mask[5:9] = True
    assert np.count_nonzero(np.isfinite(move_clearance(tp, pts, 2.0, moves=mask))) == 4
    # the report
    rep = clearance_report(tp, pts, 2.0, 1e-3)
    assert rep.min_clearance_mm == pytest.approx(np.nanmin(got)) and rep.worst_move == int(np.nanargmin(got))
    assert rep.n_below == int(np.count_nonzero(got[feed] < 2.0 - 1e-3)) > 0 and not rep.ok
    assert rep.n_measured == int(feed.sum()) and rep.threshold_mm == pytest.approx(2.0 - 1e-3)
    # a binned cloud gives the same answers
    bc = BinnedCloud(pts, 0.5)
    np.testing.assert_array_equal(move_clearance(tp, bc, 2.0), got)
    # an empty cloud: everything at the cut-off
    assert np.all(move_clearance(tp, np.zeros((0, 3)), 2.0)[feed] == 2.0)


def test_bad_parameters():
    tp = lines(np.zeros((3, 3)), np.full(3, USE_CUT, np.int8))
    pts = np.zeros((4, 3))
    with pytest.raises(ParameterError):
        move_clearance(tp, pts, 0.0)
    with pytest.raises(ParameterError):
        move_clearance(tp, pts, 1.0, cutoff_mm=0.0)
    with pytest.raises(ParameterError):
        move_clearance(tp, pts, 1.0, moves=[5])
    with pytest.raises(ParameterError):
        move_clearance(tp, np.zeros((4, 2)), 1.0)
    with pytest.raises(ParameterError):
        clearance_report(tp, pts, 1.0, 2.0)
    bad = Toolpath(np.zeros((2, 3)), np.array([RAPID, ARC_CW], np.int8), np.zeros((2, 3)),
                   np.zeros(2, np.int8), np.zeros(2, np.int8))
    with pytest.raises(ParameterError):
        move_clearance(bad, pts, 1.0)                            # an arc without a plane
    nocentre = Toolpath(np.zeros((2, 3)), np.array([RAPID, ARC_CW], np.int8), np.full((2, 3), np.nan),
                        np.array([0, PLANE_ZX], np.int8), np.zeros(2, np.int8))
    with pytest.raises(ParameterError):
        move_clearance(nocentre, pts, 1.0)


def _densify_reference(tp, step, start_index):
    """moves.densify written plainly, one arc at a time with arc_sweep_rad: the reference of the
    vectorised version."""
    from planning.toolpath.moves import arc_sweep_rad

    out, mv = [tp.xyz_mm[start_index - 1]], [start_index - 1]
    for i in range(start_index, tp.n_moves):
        if tp.kind[i] not in (ARC_CW, ARC_CCW):
            out.append(tp.xyz_mm[i]), mv.append(i)
            continue
        s, e, c = tp.xyz_mm[i - 1], tp.xyz_mm[i], tp.centre_mm[i]
        a, b, n = PLANE_AXES[int(tp.plane[i])]
        t0, sw, r = arc_sweep_rad(s, e, c, tp.plane[i], tp.kind[i] == ARC_CCW)
        m = max(2, math.ceil(abs(sw) * max(r, 1e-9) / step))
        r1 = math.hypot(e[a] - c[a], e[b] - c[b])
        for k in range(1, m + 1):
            t = k / m
            q = np.empty(3)
            q[a] = c[a] + (r + (r1 - r) * t) * math.cos(t0 + sw * t)
            q[b] = c[b] + (r + (r1 - r) * t) * math.sin(t0 + sw * t)
            q[n] = s[n] + (e[n] - s[n]) * t
            out.append(e if k == m else q), mv.append(i)
    return np.array(out), np.array(mv)


@pytest.mark.parametrize("step, start_index", [(0.05, 1), (0.7, 1), (0.7, 4)])
def test_densify_matches_a_plain_per_arc_reference(step, start_index):
    rng = np.random.default_rng(11)
    n = 300
    kind = rng.choice([RAPID, FEED, ARC_CW, ARC_CCW], size=n).astype(np.int8)
    kind[0] = RAPID
    plane = np.where(kind >= ARC_CW, rng.choice([PLANE_XY, PLANE_ZX, PLANE_YZ], size=n), 0).astype(np.int8)
    xyz = np.cumsum(rng.normal(size=(n, 3)), axis=0)
    centre = np.full((n, 3), np.nan)
    for i in np.flatnonzero(kind >= ARC_CW):          # an end on the start's circle (a spiral's on some)
        a, b, _ = PLANE_AXES[int(plane[i])]
        c = xyz[i - 1] + rng.normal(size=3)
        r = math.hypot(xyz[i - 1][a] - c[a], xyz[i - 1][b] - c[b]) * rng.choice([1.0, 1.01])
        ang = rng.uniform(-math.pi, math.pi)
        xyz[i, a], xyz[i, b] = c[a] + r * math.cos(ang), c[b] + r * math.sin(ang)
        centre[i] = c
    tp = Toolpath(xyz, kind, centre, plane, rng.integers(0, 4, n).astype(np.int8))
    from planning.toolpath.moves import densify
    got, got_mv = densify(tp, step, start_index=start_index)
    ref, ref_mv = _densify_reference(tp, step, start_index)
    assert np.array_equal(got_mv, ref_mv)
    assert np.abs(got - ref).max() <= 1e-12
