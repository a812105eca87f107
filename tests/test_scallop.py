"""The scallop held on every curvature (issue 31 item 2; planning/toolpath/scallop.py): the formula
against the exact geometry of two balls on a circle, the running median against numpy's, the forward
step on a concave stretch, and finishing on analytic surfaces measured after the fact from the moves
(planning/simulate/finish.py, the exact distance to the swept ball) against the target."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scallop_cases

from planning.toolpath import finishing, scallop
from planning.toolpath.balldrop import DropSurface
from planning.toolpath.finishing import finishing_passes

R = scallop_cases.R


def _exact_scallop_on_circle(rho: float, phi1: float, phi2: float, concave: bool) -> float:
    """The cusp of two balls resting on a circle of radius rho (centres at rho -/+ R from its centre
    O, at angles phi1, phi2 from the downward / upward vertical), its distance to the circle: brute
    force on the cusp found as the intersection of the two balls' circles."""
    D = rho - R if concave else rho + R
    sgn = -1.0 if concave else 1.0                 # concave: O above the surface; convex: below
    c1 = np.array([D * math.sin(phi1), sgn * D * math.cos(phi1)])
    c2 = np.array([D * math.sin(phi2), sgn * D * math.cos(phi2)])
    m, d = 0.5 * (c1 + c2), float(np.linalg.norm(c2 - c1))
    u = (c2 - c1) / d
    n = np.array([-u[1], u[0]])
    cands = [m + t * math.sqrt(R * R - d * d / 4) * n for t in (1.0, -1.0)]
    # the cusp on the surface's side: nearer the surface circle
    return min(abs(float(np.linalg.norm(q)) - rho) for q in cands)


@pytest.mark.parametrize("concave", [True, False])
@pytest.mark.parametrize("rho", [6.0, 10.0, 30.0])
def test_the_scallop_formula_equals_two_balls_on_a_circle(concave, rho):
    """Ball centres on the offset of a circle (a cylinder's section), three passes dy apart: the
    scallop from the curvature the three give equals the cusp's distance to the circle found by
    intersecting the balls, within 5 % for steps up to 0.2 times the offset's radius (the parabola
    through three points stands in for the circle: 10 % low at 0.3 times, 40 degrees up the side; a
    scallop of 0.01 mm with R 3 mm takes steps of 0.5 mm at most, so an offset radius of 2.5 mm)."""
    D = rho - R if concave else rho + R
    sgn = -1.0 if concave else 1.0
    for dy in [d for d in (0.3, 0.5, 0.9) if d <= 0.2 * D]:
        ys = np.array([0.2, 0.2 + dy, 0.2 + 2 * dy])
        zs = sgn * np.sqrt(D * D - ys * ys)        # the offset circle about O = (0, 0)
        c = scallop.curvature_across(ys[0], zs[:1], ys[1], zs[1:2], ys[2], zs[2:], window=1)
        got = float(scallop.scallop_across_mm(R, ys[1], zs[1:2], ys[2], zs[2:], c)[0])
        want = _exact_scallop_on_circle(rho, math.asin(ys[1] / D), math.asin(ys[2] / D), concave)
        assert got == pytest.approx(want, rel=0.05)
        plane = R - math.sqrt(R * R - (dy * dy + (zs[2] - zs[1]) ** 2) / 4)
        # concave leaves more than the plane formula at the same centre distance, convex less
        assert (got > plane) if concave else (got < plane)
    # at rho = 2 R concave, about rho / (rho - R) = 2x the plane's (issue 31)
    if concave and rho == 2 * R:
        ys = np.array([-0.5, 0.0, 0.5])
        zs = -np.sqrt(D * D - ys * ys)
        c = scallop.curvature_across(ys[0], zs[:1], ys[1], zs[1:2], ys[2], zs[2:], window=1)
        got = float(scallop.scallop_across_mm(R, ys[1], zs[1:2], ys[2], zs[2:], c)[0])
        d = math.hypot(0.5, zs[2] - zs[1])
        assert got / (R - math.sqrt(R * R - d * d / 4)) == pytest.approx(rho / (rho - R), rel=0.05)


def test_balls_that_do_not_meet_and_missing_heights():
    z = np.array([0.0, 0.0, np.nan])
    h = scallop.scallop_across_mm(R, 0.0, z, 6.5, np.array([0.0, np.nan, 0.0]))
    assert h[0] == np.inf and np.isnan(h[1]) and np.isnan(h[2])
    assert scallop.worst(np.array([np.nan, np.nan])) == 0.0
    assert scallop.worst(np.array([np.nan, 0.2, 0.1])) == 0.2


def test_running_median_is_numpys_nanmedian_over_the_window():
    rng = np.random.default_rng(3)
    v = rng.normal(size=200)
    v[rng.random(200) < 0.3] = np.nan
    v[50:70] = np.nan
    for w in (1, 3, 9):
        got = scallop.running_median(v, w)
        k = w // 2
        for i in range(v.size):
            win = v[max(0, i - k):i + k + 1]
            if np.isfinite(win).any():
                assert got[i] == pytest.approx(float(np.nanmedian(win)), abs=1e-15)
            else:
                assert np.isnan(got[i])


def test_chords_over_a_valley_are_bisected_until_they_keep_the_tolerance():
    """Ball drops every 0.75 mm along a valley (a concave cylinder across the pass, rho = 6): the chord
    between two leaves up to L^2 / (8 (rho - R)) (0.023 mm) above the drop; after refine_chords every
    move's midpoint lies within chord_mm of the drop there, and the points added are drops."""
    rho = 6.0
    g = np.arange(-5.0, 5.0001, 0.05)
    X, Y = np.meshgrid(g, g, indexing="ij")
    x, y = X.ravel(), Y.ravel()
    pts = np.column_stack([x, y, rho - np.sqrt(rho * rho - x * x) - 2.0])
    surf = DropSurface(pts, R)
    xs = np.arange(-1.5, 1.5001, 0.75)
    line = np.column_stack([xs, np.zeros_like(xs), surf.drop(np.column_stack([xs, np.zeros_like(xs)])).z_mm])
    mid = 0.5 * (line[1:] + line[:-1])
    before = mid[:, 2] - surf.drop(mid[:, :2]).z_mm
    assert before.max() > 0.015                      # what the fixed forward step leaves
    chord = 0.001
    out = scallop.refine_chords(lambda q: surf.drop(q).z_mm, [line, line[::-1].copy()], chord)
    for ln in out:
        mid = 0.5 * (ln[1:] + ln[:-1])
        seg = np.diff(ln, axis=0)
        above = (mid[:, 2] - surf.drop(mid[:, :2]).z_mm) * np.hypot(seg[:, 0], seg[:, 1]) / np.linalg.norm(seg, axis=1)
        assert above.max() <= chord
        np.testing.assert_allclose(ln[:, 2], surf.drop(ln[:, :2]).z_mm, atol=1e-12)
        assert ln.shape[0] > line.shape[0]
    # a plane needs nothing: the lines come back as they were
    flat = np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)])
    same = scallop.refine_chords(lambda q: np.zeros(q.shape[0]), [flat], chord)
    np.testing.assert_array_equal(same[0], flat)


# ------------------------------------------------------------------------------------------------
# finishing on analytic surfaces, measured from the moves
# ------------------------------------------------------------------------------------------------

def _left_after(kind: str, h: float, tol: float):
    """Finish the middle of an analytic surface and measure from the finishing moves the material left
    over its points away from the area's edges (tests/scallop_cases.py): (largest, the path)."""
    left, fin = scallop_cases.finish_and_measure(kind, h, tol, every=2)
    assert np.isfinite(left).all()                  # every inner point is reached
    return float(left.max()), fin


@pytest.mark.parametrize("kind", scallop_cases.SURFACES)
def test_the_scallop_after_finishing_is_the_target_on_every_curvature(kind):
    """Issue 31's acceptance: the scallop measured after the fact never exceeds the target by more
    than 10 % (concave included), and it is not far below it (the passes are not wastefully dense).
    The centre-distance rule of before left 1.9x on the concave cylinder across the passes, 3.5x along
    them, 2.4x in the bowl and 1.6x on the saddle (BENCHMARKS.md, issue 31 item 2)."""
    h, tol = 0.01, 0.001
    worst, _ = _left_after(kind, h, tol)
    assert worst <= 1.1 * h + tol / 2
    assert worst >= 0.8 * h


def test_without_the_forward_step_a_valley_along_the_passes_keeps_too_much(monkeypatch):
    """The same valley along the passes with refine_chords switched off: the fixed R / 4 forward step
    leaves well over the target, which is what the forward step is for."""
    monkeypatch.setattr(scallop, "refine_chords", lambda drop, lines, chord_mm, **kw: lines)
    worst, _ = _left_after("concave_cylinder_along", 0.01, 0.001)
    assert worst > 1.5 * 0.01


def test_without_the_curvature_the_concave_cylinder_keeps_too_much(monkeypatch):
    """The concave cylinder across the passes with the curvature read as 0 (the plane's formula on the
    centre distance): about rho / (rho - R) = 2x the target."""
    monkeypatch.setattr(scallop, "curvature_across", lambda *a, **k: np.zeros_like(np.asarray(a[1], float)))
    worst, _ = _left_after("concave_cylinder_across", 0.01, 0.001)
    assert worst > 1.5 * 0.01


def test_scan_noise_is_not_read_as_curvature():
    """A plane sampled as a scan is (0.3 mm spacing, 0.03 mm of noise): the ball drop's jitter would
    read as curvature across the passes and narrow the steps; after the running median and the
    standard-error shrink the passes are within 6 % of the plane's step-over count (before the shrink:
    40 passes where 34 do, bench/bench_scallop_analytic.py --root 9be9ddb), while a true concave section of the same scan is still seen."""
    rng = np.random.default_rng(2)
    n = int(40 * 20 / 0.3 ** 2)
    x, y = rng.uniform(-20, 20, n), rng.uniform(-10, 10, n)
    noise = rng.normal(0.0, 0.03, n)
    area = (np.abs(x) < 15) & (np.abs(y) < 7)
    plane = np.column_stack([x, y, noise])
    fin = finishing_passes(plane, area, radius_mm=R, scallop_mm=0.01, tol_mm=0.01)
    s = finishing.step_over_mm(R, 0.01)
    ys = np.unique(np.round(fin.toolpath.xyz_mm[fin.pass_index >= 0, 1], 9))
    steps = np.diff(ys)[1:-1]
    assert np.median(steps) >= 0.97 * s
    assert fin.n_passes <= 1.06 * ((ys.max() - ys.min()) / s + 1)
    # a concave cylinder (rho = 2 R, across the passes) under the same noise: steps about 1/sqrt(2)
    # of the plane's, as the curvature says
    groove = np.column_stack([x, y, 6.0 - np.sqrt(np.maximum(36.0 - y * y, 0.0)) + noise])
    garea = (np.abs(x) < 15) & (np.abs(y) < 3)
    gfin = finishing_passes(groove, garea, radius_mm=R, scallop_mm=0.01, tol_mm=0.01)
    gys = np.unique(np.round(gfin.toolpath.xyz_mm[gfin.pass_index >= 0, 1], 9))
    mid = np.diff(gys)[np.abs(0.5 * (gys[1:] + gys[:-1])) < 0.8]
    assert mid.size >= 3 and np.median(mid) <= 0.8 * s


def test_robust_sigma_reads_normal_noise():
    rng = np.random.default_rng(5)
    v = rng.normal(0.0, 0.02, 4000)
    v[:200] = 5.0                                   # outliers do not move it
    assert scallop.robust_sigma(v) == pytest.approx(0.02, rel=0.1)
    assert scallop.robust_sigma(np.array([1.0, np.nan, 2.0])) == 0.0


def test_the_jitter_seen_across_the_passes_is_the_heights_noise():
    """Three passes of heights with normal noise sigma (a plane): curvature_across reports a jitter
    of about sigma, and the curvature it returns is 0 (the shrink takes the noise away)."""
    rng = np.random.default_rng(11)
    sigma = 0.004
    za, zb, zc = (rng.normal(0.0, sigma, 400) for _ in range(3))
    said = []
    c = scallop.curvature_across(0.0, za, 0.45, zb, 0.95, zc, noise=said)
    assert len(said) == 1 and said[0] == pytest.approx(sigma, rel=0.2)
    assert np.mean(c == 0.0) > 0.9


def test_chords_over_noise_are_not_bisected_when_the_noise_is_known():
    """A noisy flat line of drops: with the jitter given, hardly a move is split; without, many are (a
    chord over the noise is no chord over a valley)."""
    rng = np.random.default_rng(4)
    xs = np.arange(0.0, 60.0, 0.75)
    line = np.column_stack([xs, np.zeros_like(xs), rng.normal(0.0, 0.004, xs.size)])

    def drop(q):
        return np.random.default_rng(int(1e6 * q[0, 0]) % 2**31).normal(0.0, 0.004, q.shape[0])

    plain = scallop.refine_chords(drop, [line], 0.005)[0]
    aware = scallop.refine_chords(drop, [line], 0.005, noise_mm=0.004)[0]
    assert plain.shape[0] - line.shape[0] > 3 * (aware.shape[0] - line.shape[0])
