"""Ball-end finishing passes by ball drop (planning.toolpath.finishing)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from planning.toolpath.balldrop import ball_drop
from planning.errors import ParameterError
from planning.toolpath.finishing import finishing_passes, step_over_mm
from planning.toolpath.moves import FEED, RAPID, USE_PLUNGE, USE_RETRACT


def min_clearance(cl_mm: np.ndarray, feed: np.ndarray, points: np.ndarray, radius_mm: float, *,
                  tree: cKDTree | None = None) -> np.ndarray:
    """Reference (KD-tree, numpy) for the numba clearance of :mod:`planning.toolpath.verify`. Per feed move i (from ``cl_mm[i-1]`` to ``cl_mm[i]`` where ``feed[i]``): the smallest distance
    from a cloud point to that segment (``inf`` where no point is within ``2 R``; NaN for non-feed
    entries). Exact point-to-segment distances over the points a KD-tree (``tree``, built on
    ``points`` when not given) finds near each move, in chunks of moves."""
    cl = np.asarray(cl_mm, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64)
    out = np.full(cl.shape[0], np.nan)
    idx = np.flatnonzero(np.asarray(feed, dtype=bool))
    idx = idx[idx > 0]
    if idx.size == 0:
        return out
    out[idx] = np.inf
    tree = cKDTree(points) if tree is None else tree
    a, b = cl[idx - 1], cl[idx]
    mid = 0.5 * (a + b)
    reach = 0.5 * np.linalg.norm(b - a, axis=1) + 2 * float(radius_mm)
    for c0 in range(0, idx.size, 256):
        c1 = min(c0 + 256, idx.size)
        near = tree.query_ball_point(mid[c0:c1], reach[c0:c1])
        counts = np.fromiter((len(x) for x in near), dtype=np.int64, count=c1 - c0)
        if counts.sum() == 0:
            continue
        own = np.repeat(np.arange(c0, c1), counts)
        q = points[np.concatenate([np.asarray(x, dtype=np.int64) for x in near])]
        d = b[own] - a[own]
        L2 = (d * d).sum(axis=1)
        u = np.clip(np.where(L2 > 0, ((q - a[own]) * d).sum(axis=1) / np.where(L2 > 0, L2, 1.0), 0.0), 0.0, 1.0)
        dist = np.sqrt(((q - (a[own] + u[:, None] * d)) ** 2).sum(axis=1))
        has = np.flatnonzero(counts)
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])[has]
        out[idx[c0 + has]] = np.minimum.reduceat(dist, first)
    return out


def _plane(half=20.0, spacing=0.2, z=-10.0):
    g = np.arange(-half, half + 1e-9, spacing)
    X, Y = np.meshgrid(g, g, indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], 1)


def test_step_over_gives_the_target_scallop_on_a_plane():
    R, h = 3.0, 0.01
    s = step_over_mm(R, h)
    # two balls s apart on a plane: the ridge between them is h high
    assert R - np.sqrt(R * R - (s / 2) ** 2) == pytest.approx(h)
    with pytest.raises(ParameterError):
        step_over_mm(3.0, 0.0)


def test_plane_area_passes():
    pts = _plane()
    area = (np.abs(pts[:, 0]) <= 10) & (np.abs(pts[:, 1]) <= 5)
    R = 3.0
    path = finishing_passes(pts, area, radius_mm=R, scallop_mm=0.01, margin_mm=1.0)
    on = path.cl_mm[path.pass_index >= 0]           # the passes (not links, leads, retracts)
    # R above the plane, less the point-sampling error: the nearest point is within spacing/sqrt(2)
    # of the line, so the drop is at most (0.2 / sqrt(2))^2 / (2 R) low
    assert np.all(on[:, 2] <= -10.0 + R + 1e-12)
    assert np.all(on[:, 2] >= -10.0 + R - (0.2 / np.sqrt(2)) ** 2 / (2 * R) - 1e-12)
    ys = np.unique(np.round(on[:, 1], 9))
    # adaptive side steps on a plane: the plane's step-over, within what the 0.2 mm sampling's height
    # jitter reads as curvature across the passes (planning/toolpath/scallop.py: a few per cent)
    assert np.all(np.diff(ys)[:-1] <= 1.03 * path.step_over_mm)
    assert np.all(np.diff(ys)[:-1] >= 0.95 * path.step_over_mm)
    assert ys.min() <= -5 + path.step_over_mm and ys.max() >= 5 - path.step_over_mm
    # the passes cover the area plus the margin, not the rest of the plane
    assert on[:, 0].min() <= -10 and on[:, 0].max() >= 10
    assert on[:, 0].min() >= -10 - 1.0 - path.step_over_mm and on[:, 0].max() <= 10 + 1.0 + path.step_over_mm
    assert np.all(np.abs(on[:, 1]) <= 5 + 1.0 + path.step_over_mm)
    assert R - 1e-3 <= path.min_clearance_mm <= R + 1e-9      # default tol_mm = 1e-3
    assert path.move[0] == RAPID and path.n_passes == ys.size
    # zig-zag on a plane: neighbouring passes are linked on the surface, one lead-in, one lead-out
    assert path.n_retracts == 0
    assert (path.toolpath.use == USE_PLUNGE).sum() == 1 and (path.toolpath.use == USE_RETRACT).sum() == 1


def test_gouge_free_on_a_bumpy_surface_and_zigzag():
    rng = np.random.default_rng(0)
    g = np.arange(-15, 15.001, 0.25)
    X, Y = np.meshgrid(g, g, indexing="ij")
    Z = 2.0 * np.sin(X / 2.0) * np.cos(Y / 3.0) + rng.normal(scale=0.02, size=X.shape)
    pts = np.stack([X.ravel(), Y.ravel(), Z.ravel() - 5.0], 1)
    area = np.hypot(pts[:, 0], pts[:, 1]) < 8
    R = 2.0
    path = finishing_passes(pts, area, radius_mm=R, scallop_mm=0.02, step_mm=1.5, tol_mm=1e-3)
    assert path.min_clearance_mm >= R - 1e-3
    # the reported clearance is the exact minimum over the feed moves
    clear = min_clearance(path.cl_mm, path.move == FEED, pts, R)
    assert np.nanmin(clear) == pytest.approx(path.min_clearance_mm)
    # every CL point on the surface is at its exact ball-drop height or above
    feed = path.cl_mm[path.move == FEED]
    z = ball_drop(pts, feed[:, :2], R).z_mm
    assert np.all(feed[:, 2] >= z - 1e-12)
    # zig-zag: consecutive passes run in opposite directions
    on = path.cl_mm[path.pass_index >= 0]
    dirs = []
    for y in np.unique(np.round(on[:, 1], 9))[:4]:
        xs = on[np.isclose(on[:, 1], y), 0]
        dirs.append(np.sign(xs[-1] - xs[0]))
    assert all(a != b for a, b in zip(dirs[:-1], dirs[1:]))


def test_min_clearance_against_brute_force():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-5, 5, size=(400, 3))
    cl = rng.uniform(-5, 5, size=(30, 3))
    feed = np.ones(30, dtype=bool)
    feed[0] = False
    got = min_clearance(cl, feed, pts, 10.0)         # 2R = 20 covers everything
    for i in range(1, 30):
        a, b = cl[i - 1], cl[i]
        u = np.clip((pts - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
        ref = np.sqrt(((pts - (a + u[:, None] * (b - a))) ** 2).sum(1)).min()
        assert got[i] == pytest.approx(ref)
    assert np.isnan(got[0])


def test_one_way_retracts_between_passes_and_rapids_never_touch():
    rng = np.random.default_rng(1)
    g = np.arange(-12, 12.001, 0.25)
    X, Y = np.meshgrid(g, g, indexing="ij")
    Z = 1.5 * np.cos(X / 3.0) + 0.5 * np.sin(Y / 2.0) + rng.normal(scale=0.01, size=X.shape)
    pts = np.stack([X.ravel(), Y.ravel(), Z.ravel() - 4.0], 1)
    area = (np.abs(pts[:, 0]) < 6) & (np.abs(pts[:, 1]) < 3)
    R = 2.0
    zig = finishing_passes(pts, area, radius_mm=R, scallop_mm=0.05, lead_mm=2.0)
    one = finishing_passes(pts, area, radius_mm=R, scallop_mm=0.05, lead_mm=2.0, zigzag=False)
    assert one.n_passes == zig.n_passes
    assert one.n_retracts >= one.n_passes - 1 and zig.n_retracts < one.n_retracts
    for path in (zig, one):
        tp = path.toolpath
        # every move the ball makes at feed keeps R - tol; rapids keep the full R
        assert path.min_clearance_mm >= R - 1e-3
        rapid = tp.kind == RAPID
        rapid[0] = False
        clear_rapid = min_clearance(tp.xyz_mm, rapid, pts, R)
        assert np.nanmin(clear_rapid) >= R - 1e-9
        # one-way: every pass runs the same way (+X)
        if path is one:
            for p in np.unique(path.pass_index[path.pass_index >= 0]):
                x = tp.xyz_mm[path.pass_index == p, 0]
                assert np.all(np.diff(x) > 0)
        # lead-in ramps end on a pass start and are 45 degrees or vertical
        for i in np.flatnonzero(tp.use == USE_PLUNGE):
            d = tp.xyz_mm[i] - tp.xyz_mm[i - 1]
            assert d[2] < 0 and (np.isclose(np.hypot(d[0], d[1]), -d[2]) or np.hypot(d[0], d[1]) < 1e-12)
            assert path.pass_index[i] >= 0


def _measured_scallop(path, surface_pts, R, window):
    """Largest distance from a surface point inside ``window`` (|x| < wx, |y| < wy) to the swept ball:
    min over the passes' ball-centre polylines (densified every 0.02 mm) of the distance, less R."""
    tp = path.toolpath
    dense = []
    for p in np.unique(path.pass_index[path.pass_index >= 0]):
        line = tp.xyz_mm[path.pass_index == p]
        seg = np.linalg.norm(np.diff(line, axis=0), axis=1)
        for a, b, L in zip(line[:-1], line[1:], seg):
            t = np.linspace(0, 1, max(2, int(np.ceil(L / 0.02)) + 1))
            dense.append(a + t[:, None] * (b - a))
    d, _ = cKDTree(np.concatenate(dense)).query(surface_pts)
    wx, wy = window
    inside = (np.abs(surface_pts[:, 0]) < wx) & (np.abs(surface_pts[:, 1]) < wy)
    return float((d[inside] - R).max())


def test_scallop_on_analytic_surfaces():
    """Scallop measured from the swept ball against the target: exact on a plane, kept by the
    adaptive side step on a 40-degree slope across the passes, exceeded as the plane formula predicts
    (h / cos^2) with a constant step-over; smaller than the target on a convex cylinder."""
    R, h = 3.0, 0.02
    g = np.arange(-8, 8.0001, 0.08)
    X, Y = np.meshgrid(g, g, indexing="ij")
    x, y = X.ravel(), Y.ravel()
    win = (5.0, 3.0)
    # plane
    plane = np.stack([x, y, np.full(x.size, -5.0)], 1)
    p = finishing_passes(plane, (np.abs(x) < 6) & (np.abs(y) < 4), radius_mm=R, scallop_mm=h, step_mm=0.5)
    assert _measured_scallop(p, plane, R, win) == pytest.approx(h, abs=0.002)
    # slope across the passes (frame Y)
    a = np.radians(40.0)
    slope = np.stack([x, y, -5.0 + np.tan(a) * y], 1)
    area = (np.abs(x) < 6) & (np.abs(y) < 4)
    adapt = finishing_passes(slope, area, radius_mm=R, scallop_mm=h, step_mm=0.5)
    const = finishing_passes(slope, area, radius_mm=R, scallop_mm=h, step_mm=0.5, adaptive=False)
    s = adapt.step_over_mm
    expected_const = R - np.sqrt(R * R - (s / np.cos(a) / 2) ** 2)          # ~ h / cos^2(40 deg)
    assert _measured_scallop(adapt, slope, R, win) <= h + 0.002
    assert _measured_scallop(const, slope, R, win) == pytest.approx(expected_const, abs=0.003)
    assert expected_const > 1.6 * h
    # convex cylinder along X (passes run along its generators): the scallop is below the target
    rc = 10.0
    cyl = np.stack([x, y, -5.0 + np.sqrt(np.maximum(rc * rc - y * y, 0.0)) - rc], 1)
    cp = finishing_passes(cyl, (np.abs(x) < 6) & (np.abs(y) < 4), radius_mm=R, scallop_mm=h, step_mm=0.5)
    assert _measured_scallop(cp, cyl, R, win) <= h + 0.002


@pytest.mark.parametrize("adaptive", [True, False])
def test_progress_is_told_of_the_passes_and_changes_nothing(adaptive, monkeypatch):
    import planning.toolpath.finishing as fin_mod

    pts = _plane()
    area = (np.abs(pts[:, 0]) <= 10) & (np.abs(pts[:, 1]) <= 5)
    kw = {"radius_mm": 3.0, "scallop_mm": 0.01, "margin_mm": 1.0, "adaptive": adaptive}
    plain = finishing_passes(pts, area, **kw)
    calls = []
    monkeypatch.setattr(fin_mod, "PROGRESS_EVERY_S", 0.0)       # every pass reports
    told = finishing_passes(pts, area, progress=lambda f, m: calls.append((f, m)), **kw)
    assert np.array_equal(told.cl_mm, plain.cl_mm) and np.array_equal(told.pass_index, plain.pass_index)
    fr = [f for f, _ in calls]
    assert all(0.0 <= f <= 1.0 for f in fr) and fr == sorted(fr) and fr[-1] == 1.0
    n_pass = sum(m.startswith("pass ") and "/" in m and ":" not in m for _, m in calls)
    assert n_pass >= plain.n_passes                   # once per pass (those without a run included)
    assert all(m.startswith("pass ") for _, m in calls)
    # throttled: a slow clock allows only the last call
    calls.clear()
    monkeypatch.setattr(fin_mod, "PROGRESS_EVERY_S", 1e9)
    finishing_passes(pts, area, progress=lambda f, m: calls.append((f, m)), **kw)
    assert len(calls) == 2 and calls[-1][0] == 1.0          # the first pass, then the end
