"""CL reduction and arc fitting (planning.toolpath.reduce): tolerance bounded (every original CL
point within tol of the new path, measured here independently), gouge safe (verify's clearance
>= R - tol, agreeing with a brute-force clearance), arcs of the analytic radius and direction on
cylinders and a sphere, a plane reduced to its pass ends, and a spike that keeps its point."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from planning.errors import ParameterError
from planning.toolpath.balldrop import ball_drop
from planning.toolpath.moves import (ARC_CCW, ARC_CW, FEED, PLANE_AXES, PLANE_ZX, RAPID, USE_CUT, USE_PLUNGE,
                                     USE_RAPID, USE_RETRACT, Toolpath, arc_sweep_rad, densify, lines)
from planning.toolpath.reduce import fit_arcs, reduce_cl
from planning.toolpath.verify import clearance_report, move_clearance


# ----------------------------------------------------------------------------- helpers

def _raster(points, R, xs, ys, *, zigzag=True, safe=30.0):
    """Passes along X at each y (ball drop on ``points``): rapid above the start, plunge, cut,
    retract. Returns the Toolpath and the (K,3) CL points of the passes."""
    xyz, use, cls = [], [], []
    for k, y in enumerate(ys):
        x = xs[::-1] if (zigzag and k % 2) else xs
        z = ball_drop(points, np.column_stack([x, np.full(x.size, y)]), R).z_mm
        assert np.all(np.isfinite(z))
        line = np.column_stack([x, np.full(x.size, y), z])
        cls.append(line)
        xyz += [[[line[0, 0], y, safe]], line, [[line[-1, 0], y, safe]]]
        use += [[USE_RAPID], [USE_PLUNGE] + [USE_CUT] * (len(line) - 1), [USE_RETRACT]]
    tp = lines(np.concatenate([np.asarray(a, float).reshape(-1, 3) for a in xyz]),
               np.concatenate([np.asarray(u, np.int8) for u in use]), tip_offset_mm=R)
    return tp, np.concatenate(cls)


def _arc_geometry(tp, i):
    s, e, c = tp.xyz_mm[i - 1], tp.xyz_mm[i], tp.centre_mm[i]
    return s, e, c, arc_sweep_rad(s, e, c, tp.plane[i], tp.kind[i] == ARC_CCW)


def _dist_to_path(q, tp):
    """Exact distance from each point q (K,3) to the FEED and arc moves of ``tp`` (independent
    numpy: every point against every move; arcs planar, by the nearest point of their circle)."""
    best = np.full(len(q), np.inf)
    for i in range(1, tp.n_moves):
        s, e = tp.xyz_mm[i - 1], tp.xyz_mm[i]
        if tp.kind[i] == FEED:
            d = e - s
            L2 = d @ d
            u = np.clip((q - s) @ d / L2, 0, 1) if L2 > 0 else np.zeros(len(q))
            dist = np.linalg.norm(q - (s + u[:, None] * d), axis=1)
        elif tp.kind[i] in (ARC_CW, ARC_CCW):
            a, b, n = PLANE_AXES[int(tp.plane[i])]
            _, _, c, (t0, sw, r) = _arc_geometry(tp, i)
            assert s[n] == e[n]                                # fitted arcs are planar here
            u, v = q[:, a] - c[a], q[:, b] - c[b]
            ang = np.arctan2(v, u)
            rel = np.mod(ang - t0, 2 * np.pi) if sw > 0 else np.mod(t0 - ang, 2 * np.pi)
            on = rel <= abs(sw)
            dist = np.where(on, np.hypot(np.hypot(u, v) - r, q[:, n] - s[n]),
                            np.minimum(np.linalg.norm(q - s, axis=1), np.linalg.norm(q - e, axis=1)))
        else:
            continue
        best = np.minimum(best, dist)
    return best


def _brute_clearance(tp, pts, R, step=5e-3):
    """Per FEED / arc move: the smallest distance from any cloud point to the move sampled every
    ``step`` mm (moves.densify; KD-tree on the cloud), capped at R like verify's default."""
    q, mv = densify(tp, step)
    cut = np.isin(tp.kind, (FEED, ARC_CW, ARC_CCW))
    # straight moves: add interior samples too (densify gives only their ends)
    extra, emv = [], []
    for i in np.flatnonzero(cut & (tp.kind == FEED)):
        if i == 0:
            continue
        s, e = tp.xyz_mm[i - 1], tp.xyz_mm[i]
        n = max(2, int(math.ceil(np.linalg.norm(e - s) / step)))
        t = np.linspace(0, 1, n + 1)[:, None]
        extra.append(s + t * (e - s))
        emv.append(np.full(n + 1, i))
    q = np.concatenate([q] + extra)
    mv = np.concatenate([mv] + emv)
    d = cKDTree(pts).query(q, distance_upper_bound=R + 1)[0]
    out = np.full(tp.n_moves, np.nan)
    keep = cut[mv] & (mv > 0)
    # each sample counts for the move densify (or the loop above) generated it for
    np.fmin.at(out, mv[keep], np.minimum(d[keep], R))
    return out


def _new_moves(new, tp):
    """Mask of the moves of ``new`` that are not moves of ``tp`` (another start or end)."""
    pos = {tuple(p): i for i, p in enumerate(tp.xyz_mm)}
    out = np.zeros(new.n_moves, bool)
    for i in range(1, new.n_moves):
        a, b = pos.get(tuple(new.xyz_mm[i - 1])), pos.get(tuple(new.xyz_mm[i]))
        out[i] = a is None or b is None or b != a + 1 or new.kind[i] != tp.kind[b]
    return out


def _check_path(new, tp, pts, R, tol, cl, *, input_ok=True):
    """The properties every reduced path must have (``input_ok``: the input path is gouge free;
    else only the new moves are held to R - tol)."""
    # every original CL point within tol of the new path
    dev = _dist_to_path(cl, new)
    assert dev.max() <= tol + 1e-9
    # gouge free by verify, and verify agrees with brute force
    got = move_clearance(new, pts, R)
    if input_ok:
        rep = clearance_report(new, pts, R, tol)
        assert rep.ok and rep.min_clearance_mm >= R - tol
    assert np.all(got[_new_moves(new, tp)] >= R - tol)
    bf = _brute_clearance(new, pts, R)
    m = np.isfinite(got)
    assert np.array_equal(m, np.isfinite(bf))
    assert np.all(got[m] <= bf[m] + 1e-12) and np.all(bf[m] - got[m] < 1e-5)
    # moves that are not cutting moves are kept as they were
    for u in (USE_RAPID, USE_PLUNGE, USE_RETRACT):
        np.testing.assert_array_equal(new.xyz_mm[new.use == u], tp.xyz_mm[tp.use == u])
    assert new.tip_offset_mm == tp.tip_offset_mm
    return dev


# ----------------------------------------------------------------------------- arcs on known shapes

def _cylinder(Rs, zc, convex, half_x, half_y, spacing):
    g = np.arange(-half_x, half_x + 1e-9, spacing)
    h = np.arange(-half_y, half_y + 1e-9, spacing)
    X, Y = np.meshgrid(g, h, indexing="ij")
    Z = zc + (1 if convex else -1) * np.sqrt(Rs * Rs - X * X)
    return np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])


@pytest.mark.parametrize("convex", [True, False])
def test_arcs_on_a_cylinder_along_y(convex):
    Rs, R, tol = 10.0, 2.0, 0.005
    zc = -Rs if convex else Rs - 3.0
    pts = _cylinder(Rs, zc, convex, 8.0, 3.0, 0.05)
    xs = np.arange(-5.0, 5.0 + 1e-9, 0.25)
    tp, cl = _raster(pts, R, xs, [-1.0, 0.0, 1.0])
    new = fit_arcs(tp, pts, R, tol_mm=tol)
    _check_path(new, tp, pts, R, tol, cl)
    arcs = np.flatnonzero(np.isin(new.kind, (ARC_CW, ARC_CCW)))
    cut = np.flatnonzero(new.use == USE_CUT)
    assert arcs.size >= 3 and arcs.size == cut.size <= 6          # one or two arcs per pass
    r_exact = Rs + R if convex else Rs - R                          # the ball centre's circle
    for i in arcs:
        s, e, c, (_, sw, r) = _arc_geometry(new, i)
        assert new.plane[i] == PLANE_ZX and s[1] == e[1]
        # the arc is the analytic circle: centre on the cylinder axis, radius R_s +- R
        assert c[0] == pytest.approx(0.0, abs=0.02) and c[2] == pytest.approx(zc, abs=0.02)
        assert r == pytest.approx(r_exact, abs=0.02)
        q, _ = densify(Toolpath(new.xyz_mm[i - 1:i + 1], new.kind[i - 1:i + 1], new.centre_mm[i - 1:i + 1],
                                 new.plane[i - 1:i + 1], new.use[i - 1:i + 1]), 0.01)
        assert np.abs(np.hypot(q[:, 0], q[:, 2] - zc) - r_exact).max() <= tol + 1e-9
        # direction: over a bump (centre below) +X turns from +Z towards +X: CCW; in a valley CW
        forward = e[0] > s[0]
        assert new.kind[i] == (ARC_CCW if forward == convex else ARC_CW)
        assert abs(sw) <= math.pi


def test_arcs_on_a_sphere_cap():
    Rs, R, tol = 15.0, 3.0, 0.005
    g = np.arange(-9.0, 9.0 + 1e-9, 0.06)
    X, Y = np.meshgrid(g, g, indexing="ij")
    keep = X * X + Y * Y < 81
    X, Y = X[keep], Y[keep]
    pts = np.column_stack([X, Y, np.sqrt(Rs * Rs - X * X - Y * Y) - Rs])
    xs = np.arange(-4.0, 4.0 + 1e-9, 0.2)
    ys = [-2.0, 0.5, 2.5]
    tp, cl = _raster(pts, R, xs, ys)
    new = fit_arcs(tp, pts, R, tol_mm=tol, min_points=5)
    _check_path(new, tp, pts, R, tol, cl)
    arcs = np.flatnonzero(np.isin(new.kind, (ARC_CW, ARC_CCW)))
    assert arcs.size >= len(ys)
    for i in arcs:
        s, e, c, (_, _, r) = _arc_geometry(new, i)
        # the ball centre runs on the sphere of radius Rs + R: in the plane y, a circle of radius
        # sqrt((Rs + R)^2 - y^2) about (0, y, -Rs)
        assert r == pytest.approx(math.sqrt((Rs + R) ** 2 - s[1] ** 2), abs=0.03)
        assert c[0] == pytest.approx(0.0, abs=0.03) and c[2] == pytest.approx(-Rs, abs=0.03)
        assert new.kind[i] == (ARC_CCW if e[0] > s[0] else ARC_CW)


# ----------------------------------------------------------------------------- reduction

def test_plane_reduces_to_the_pass_ends():
    g = np.arange(-12.0, 12.0 + 1e-9, 0.2)
    X, Y = np.meshgrid(g, g, indexing="ij")
    pts = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, -4.0)])
    R, tol = 3.0, 0.01
    xs = np.arange(-8.0, 8.0 + 1e-9, 0.5)
    ys = np.arange(-4.0, 4.0 + 1e-9, 1.0)
    tp, cl = _raster(pts, R, xs, ys)
    for new in (reduce_cl(tp, pts, R, tol_mm=tol), fit_arcs(tp, pts, R, tol_mm=tol)):
        _check_path(new, tp, pts, R, tol, cl)
        assert np.count_nonzero(new.use == USE_CUT) == len(ys)       # one straight move per pass
        assert np.all(new.kind[new.use == USE_CUT] == FEED)
        ends = new.xyz_mm[new.use == USE_CUT]
        np.testing.assert_allclose(np.abs(ends[:, 0]), 8.0)
    # a tolerance below the ball drop's sampling error on the plane keeps more points
    fine = reduce_cl(tp, pts, R, tol_mm=1e-5)
    assert np.count_nonzero(fine.use == USE_CUT) > len(ys)
    assert not clearance_report(tp, pts, R, 1e-5).ok     # straight moves between drops dip
    _check_path(fine, tp, pts, R, 1e-5, cl, input_ok=False)


def test_noisy_surface_reduce_and_fit():
    rng = np.random.default_rng(11)
    n = 20_000
    x = rng.uniform(-15, 15, n)
    y = rng.uniform(-6, 6, n)
    z = 2.0 * np.sin(x / 3.0) * np.cos(y / 4.0) + 0.5 * np.sin(x / 1.3) + rng.normal(0, 0.005, n) - 5
    pts = np.column_stack([x, y, z])
    R, tol = 3.0, 0.01
    xs = np.arange(-10.0, 10.0 + 1e-9, 0.2)
    ys = np.arange(-2.0, 2.0 + 1e-9, 0.5)
    tp, cl = _raster(pts, R, xs, ys)
    assert clearance_report(tp, pts, R, tol).ok                    # the input is gouge free
    red = reduce_cl(tp, pts, R, tol_mm=tol)
    arc = fit_arcs(tp, pts, R, tol_mm=tol)
    for new in (red, arc):
        _check_path(new, tp, pts, R, tol, cl)
    n_cut = np.count_nonzero(tp.use == USE_CUT)
    assert np.count_nonzero(red.use == USE_CUT) < 0.8 * n_cut
    assert np.count_nonzero(arc.use == USE_CUT) < np.count_nonzero(red.use == USE_CUT)
    assert np.isin(arc.kind, (ARC_CW, ARC_CCW)).sum() > 0
    # without line reduction only arcs replace moves: the other CL points all stay
    only = fit_arcs(tp, pts, R, tol_mm=tol, reduce_lines=False)
    _check_path(only, tp, pts, R, tol, cl)
    is_arc = np.isin(only.kind, (ARC_CW, ARC_CCW))
    assert is_arc.any() and not np.isin(only.kind[~is_arc], (ARC_CW, ARC_CCW)).any()
    # every kept line end is an original point
    kept = only.xyz_mm[only.kind == FEED]
    assert np.all(cKDTree(tp.xyz_mm).query(kept)[0] == 0.0)


def test_a_spike_keeps_the_point_a_plain_chord_would_drop():
    # CL points R above a sparse plane; a narrow spike under the middle move lifts its two ends by
    # 0.008 mm: every original move clears the spike by R - 0.007, every CL point is within the
    # tolerance 0.01 of the straight line over all of them, and that line passes R - 0.015 from the
    # spike: a gouge. The reduction must keep a point near the spike.
    R, tol, s, lift = 3.0, 0.01, 0.015, 0.008
    g = np.arange(-3.0, 13.0 + 1e-9, 0.5)
    X, Y = np.meshgrid(g, np.arange(-3.0, 3.0 + 1e-9, 0.5), indexing="ij")
    pts = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    pts = np.vstack([pts, [[5.5, 0.0, s]]])
    x = np.arange(0.0, 10.0 + 1e-9, 1.0)
    z = np.full(x.size, R)
    z[[5, 6]] += lift
    cl = np.column_stack([x, np.zeros(x.size), z])
    tp = lines(cl, np.r_[USE_RAPID, np.full(x.size - 1, USE_CUT)].astype(np.int8), tip_offset_mm=R)
    assert clearance_report(tp, pts, R, tol).ok
    plain = lines(cl[[0, -1]], [USE_RAPID, USE_CUT])
    assert move_clearance(plain, pts, R)[1] == pytest.approx(R - s)   # the plain chord gouges
    for new in (reduce_cl(tp, pts, R, tol_mm=tol), fit_arcs(tp, pts, R, tol_mm=tol)):
        _check_path(new, tp, pts, R, tol, cl)
        assert 3 <= new.n_moves < tp.n_moves
        inner = new.xyz_mm[1:-1, 0]
        assert np.any((inner >= 4.0) & (inner <= 7.0))                 # a point by the spike stays
    # without the spike the whole line is one move
    flat = reduce_cl(tp, pts[:-1], R, tol_mm=tol)
    assert flat.n_moves == 2


def test_runs_split_by_use_and_pass_index_and_bad_parameters():
    g = np.arange(-6.0, 6.0 + 1e-9, 0.25)
    X, Y = np.meshgrid(g, g, indexing="ij")
    pts = np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, -3.0)])
    R = 2.0
    x = np.arange(-4.0, 4.0 + 1e-9, 0.5)
    # two passes joined by a cutting move (a link on the surface)
    cl = np.vstack([np.column_stack([x, np.zeros(x.size), np.full(x.size, -1.0)]),
                    np.column_stack([x[::-1], np.full(x.size, 0.5), np.full(x.size, -1.0)])])
    use = np.full(len(cl), USE_CUT, np.int8)
    use[0] = USE_RAPID
    tp = lines(cl, use, tip_offset_mm=R)
    one = reduce_cl(tp, pts, R, tol_mm=0.01)
    assert one.n_moves == 4                       # start, pass end, link end, pass end
    pi = np.r_[np.zeros(x.size), np.ones(x.size)].astype(np.int32)
    pi[x.size] = -1                               # the link's end is not a pass point...
    two = reduce_cl(tp, pts, R, tol_mm=0.01, pass_index=pi)
    # ... so neither the link nor the move after it joins a run
    assert two.n_moves == 5
    np.testing.assert_array_equal(two.xyz_mm[2:4], tp.xyz_mm[x.size:x.size + 2])
    # moves of other uses are never merged
    use2 = use.copy()
    use2[5:9] = USE_PLUNGE
    mixed = reduce_cl(lines(cl, use2, tip_offset_mm=R), pts, R, tol_mm=0.01)
    np.testing.assert_array_equal(mixed.xyz_mm[mixed.use == USE_PLUNGE], cl[5:9])
    with pytest.raises(ParameterError):
        reduce_cl(tp, pts, R, tol_mm=0.0)
    with pytest.raises(ParameterError):
        reduce_cl(tp, pts, R, tol_mm=R)
    with pytest.raises(ParameterError):
        fit_arcs(tp, pts, R, tol_mm=0.01, plane=20)
    with pytest.raises(ParameterError):
        fit_arcs(tp, pts, R, tol_mm=0.01, min_points=2)
    with pytest.raises(ParameterError):
        fit_arcs(tp, pts, R, tol_mm=0.01, min_radius_mm=5.0, max_radius_mm=1.0)
    with pytest.raises(ParameterError):
        reduce_cl(tp, pts, R, tol_mm=0.01, pass_index=np.zeros(3))
    # nothing to reduce: the same path back
    short = lines(cl[:2], use[:2], tip_offset_mm=R)
    same = reduce_cl(short, pts, R, tol_mm=0.01)
    np.testing.assert_array_equal(same.xyz_mm, short.xyz_mm)
    assert RAPID == same.kind[0]


def test_an_arc_never_bulges_more_than_the_tolerance_between_two_cl_points():
    """Points exactly on a circle (radius 2 mm, in the ZX plane) but 60 degrees apart: an arc through
    them passes every point, yet swings 0.27 mm off the straight move between two neighbours (its
    sagitta), which the ball's clearance check alone does not see and the flutes above the ball would
    (the range half sphere's plan cut a wall 0.77 mm so); it is not fitted at tol 0.01. At 10 degrees
    apart (sagitta 0.008 mm) it is."""
    from planning.toolpath.reduce import _arc_fit

    ia, ib, inn = PLANE_AXES[PLANE_ZX]
    for step_deg, fits in ((60.0, False), (10.0, True)):
        t = np.radians(np.arange(0.0, 180.0 + 1e-9, step_deg))
        xyz = np.column_stack([2.0 * np.cos(t), np.zeros_like(t), 2.0 * np.sin(t)])
        ok, *_ = _arc_fit(np.ascontiguousarray(xyz), 0, t.size - 1, 0.01, ia, ib, inn, 1e-6, 0.5, 500.0)
        assert ok is fits, step_deg
