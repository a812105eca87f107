"""Ball-end finishing passes by ball drop (planning.toolpath.finishing)."""

from __future__ import annotations

import numpy as np
import pytest

from planning.toolpath.balldrop import ball_drop
from planning.errors import ParameterError
from planning.toolpath.finishing import FEED, RAPID, finishing_passes, min_clearance, step_over_mm


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
    area = pts[(np.abs(pts[:, 0]) <= 10) & (np.abs(pts[:, 1]) <= 5)]
    R = 3.0
    path = finishing_passes(pts, area, radius_mm=R, scallop_mm=0.01, margin_mm=1.0)
    feed = path.cl_mm[path.move == FEED]
    on = feed[feed[:, 2] < 0]                       # the cutting moves (not the retracts)
    # R above the plane, less the point-sampling error: the nearest point is within spacing/sqrt(2)
    # of the line, so the drop is at most (0.2 / sqrt(2))^2 / (2 R) low
    assert np.all(on[:, 2] <= -10.0 + R + 1e-12)
    assert np.all(on[:, 2] >= -10.0 + R - (0.2 / np.sqrt(2)) ** 2 / (2 * R) - 1e-12)
    ys = np.unique(np.round(on[:, 1], 9))
    assert np.allclose(np.diff(ys), path.step_over_mm)
    assert ys.min() <= -5 + path.step_over_mm and ys.max() >= 5 - path.step_over_mm
    # the passes cover the area plus the margin, not the rest of the plane
    assert on[:, 0].min() <= -10 and on[:, 0].max() >= 10
    assert on[:, 0].min() >= -10 - 1.0 - path.step_over_mm and on[:, 0].max() <= 10 + 1.0 + path.step_over_mm
    assert np.all(np.abs(on[:, 1]) <= 5 + 1.0 + path.step_over_mm)
    assert R - 1e-3 <= path.min_clearance_mm <= R + 1e-9      # default tol_mm = 1e-3
    assert path.move[0] == RAPID and path.n_passes == ys.size


def test_gouge_free_on_a_bumpy_surface_and_zigzag():
    rng = np.random.default_rng(0)
    g = np.arange(-15, 15.001, 0.25)
    X, Y = np.meshgrid(g, g, indexing="ij")
    Z = 2.0 * np.sin(X / 2.0) * np.cos(Y / 3.0) + rng.normal(scale=0.02, size=X.shape)
    pts = np.stack([X.ravel(), Y.ravel(), Z.ravel() - 5.0], 1)
    area = pts[np.hypot(pts[:, 0], pts[:, 1]) < 8]
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
    on = feed[feed[:, 2] < 0]
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
