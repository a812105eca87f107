"""3D biarc fitting of ball-centre paths (planning.toolpath.fiveaxis.biarc; Chui et al. 2008 App. A)."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from planning.toolpath.fiveaxis.biarc import (
    biarc,
    biarc_chords,
    distance_to_biarcs,
    fit_biarcs,
    path_tangents,
)


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _seg_distance(Q, P, k=8):
    """Distance from points Q (k,3) to the polyline P (n,3), over the segments next to the k nearest
    vertices of P: an upper bound of the exact distance (more segments can only make it smaller),
    so a bound asserted on it also holds for the exact distance."""
    _, near = cKDTree(P).query(Q, k=min(k, len(P)))
    near = np.asarray(near).reshape(len(Q), -1)
    i = np.clip(np.concatenate([near - 1, near], axis=1), 0, len(P) - 2)
    a, b = P[i], P[i + 1]
    ab = b - a
    l2 = np.maximum((ab * ab).sum(-1), 1e-300)
    t = np.clip(((Q[:, None, :] - a) * ab).sum(-1) / l2, 0.0, 1.0)
    d = Q[:, None, :] - (a + t[..., None] * ab)
    return np.sqrt((d * d).sum(-1)).min(1)


def _tilted_frame():
    e1 = _unit([1.0, 0.2, 0.3])
    e2 = _unit(np.cross(e1, [0.1, 0.3, 1.0]))
    return e1, e2


def _helix(t, r=20.0, pitch=5.0):
    c = pitch / (2 * np.pi)
    return np.stack([r * np.cos(t), r * np.sin(t), c * t], axis=1)


def _sphere_wave(phi, rs=30.0):
    lat = np.radians(60.0) + 0.3 * np.sin(3 * phi)
    return rs * np.stack([np.sin(lat) * np.cos(phi), np.sin(lat) * np.sin(phi), np.cos(lat)], axis=1)


def _check_junctions(fit):
    """G1 inside each biarc and between consecutive biarcs of one piece, from the arcs themselves."""
    bi = fit.biarcs
    et = bi.end_tangent
    ep = bi.end
    assert np.abs(et[:, 0] - bi.tangent[:, 1]).max() < 1e-9  # arc 1 ends along t2
    assert np.abs(ep[:, 0] - bi.start[:, 1]).max() < 1e-9  # ... at B
    assert np.abs(et[:, 1] - bi.t3).max() < 1e-9  # arc 2 ends along t3
    assert np.abs(ep[:, 1] - bi.C).max() < 1e-9
    same = fit.path_piece[1:] == fit.path_piece[:-1]
    assert np.abs(et[:-1, 1][same] - bi.t1[1:][same]).max(initial=0) < 1e-9
    assert np.array_equal(bi.C[:-1][same], bi.A[1:][same])


def test_circle_arc_in_tilted_plane_is_one_biarc():
    R = 25.0
    e1, e2 = _tilted_frame()
    th = np.linspace(0.0, np.radians(250.0), 120)
    P = np.array([3.0, 4.0, 5.0]) + R * (np.cos(th)[:, None] * e1 + np.sin(th)[:, None] * e2)
    for method in ("equal", "chui"):
        fit = fit_biarcs(P, 1e-3, method=method)
        assert fit.n_biarcs == 1 and fit.n_arcs_out == 2
        assert np.allclose(fit.biarcs.radius, R, rtol=1e-9)
        assert fit.max_error_mm < 1e-9 * R
        assert fit.biarcs.kind[0] == "C" and fit.biarcs.twist_rad[0] < 1e-9
        assert np.allclose(np.abs(fit.biarcs.normal[0] @ np.cross(e1, e2)), 1.0)
        assert np.allclose(fit.biarcs.centre[0], [3.0, 4.0, 5.0], atol=1e-9 * R)
        assert np.isclose(fit.biarcs.sweep_rad.sum(), np.radians(250.0))


def test_path_tangents_exact_on_circle_with_uneven_spacing():
    e1, e2 = _tilted_frame()
    th = np.sort(np.random.default_rng(3).uniform(0.0, 2.0, 30))
    P = 7.0 * (np.cos(th)[:, None] * e1 + np.sin(th)[:, None] * e2)
    true = -np.sin(th)[:, None] * e1 + np.cos(th)[:, None] * e2
    assert np.abs(path_tangents(P) - true).max() < 1e-12
    line = np.outer(np.arange(5.0) ** 2, [1.0, 2.0, 2.0])
    assert np.allclose(path_tangents(line), [1 / 3, 2 / 3, 2 / 3])


@pytest.mark.parametrize("tol", [0.01, 0.001])
@pytest.mark.parametrize("curve", ["helix", "sphere"])
def test_space_curves_within_tolerance_against_the_true_curve(curve, tol):
    n = 400 if curve == "helix" else 1000
    if curve == "helix":
        par = np.linspace(0.0, 4 * np.pi, n)
        fn = _helix
    else:
        par = np.linspace(0.0, 1.8 * np.pi, n)
        fn = _sphere_wave
    P = fn(par)
    fit = fit_biarcs(P, tol)
    assert fit.max_error_mm <= tol
    assert fit.n_points_in == n
    assert fit.n_arcs_out < n / 5
    _check_junctions(fit)
    # dense samples of the analytic curve between the input points (50 per segment)
    f = np.linspace(0.0, 1.0, 51)[:-1]
    dense_par = (par[:-1, None] + f[None, :] * np.diff(par)[:, None]).reshape(-1)
    Q = fn(dense_par)
    seg = np.repeat(np.arange(n - 1), 50)
    a, b = P[seg], P[seg + 1]
    t = ((Q - a) * (b - a)).sum(1) / ((b - a) ** 2).sum(1)
    chord_err = np.linalg.norm(Q - (a + t[:, None] * (b - a)), axis=1).max()
    if curve == "helix":  # analytic: radial sagitta r (1 - cos(dphi / 2))
        assert np.isclose(chord_err, 20.0 * (1 - np.cos((par[1] - par[0]) / 2)), rtol=1e-3)
    chord_tol = tol / 20
    _, C = biarc_chords(fit.biarcs, chord_tol)
    d = _seg_distance(Q, C)
    assert d.max() <= tol + chord_err + chord_tol
    # and the input points against the chord polyline (an implementation independent of the fit's)
    assert _seg_distance(P, C).max() <= tol + chord_tol


def test_s_type_two_quarter_circles_parallel_tangents():
    r = 10.0
    A, C = np.zeros(3), np.array([2 * r, 2 * r, 0.0])
    t = np.array([1.0, 0.0, 0.0])
    bi = biarc(A, t, C, t)  # w = 0
    assert np.allclose(bi.B[0], [r, r, 0.0])
    assert np.allclose(bi.t2[0], [0.0, 1.0, 0.0])
    assert np.allclose(bi.radius[0], r)
    assert np.allclose(bi.sweep_rad[0], np.pi / 2)
    assert np.allclose(bi.centre[0], [[0.0, r, 0.0], [2 * r, r, 0.0]])
    assert bi.kind[0] == "S" and bi.twist_rad[0] < 1e-12
    assert bi.proper[0]


def _hand_biarc(R1, sweep1, sweep2, turn2):
    """Planar biarc built by hand with a = b: arc 1 turns left by sweep1 with radius R1, arc 2 turns
    by sweep2 (left if turn2 > 0) with the radius a = b forces, R2 = R1 tan(sweep1/2) / tan(sweep2/2)."""
    a = R1 * np.tan(sweep1 / 2)
    R2 = a / np.tan(sweep2 / 2)
    t1 = np.array([1.0, 0.0, 0.0])
    t2 = np.array([np.cos(sweep1), np.sin(sweep1), 0.0])
    ang = sweep1 + turn2 * sweep2
    t3 = np.array([np.cos(ang), np.sin(ang), 0.0])
    A = np.array([1.0, -2.0, 3.0])
    B = A + a * (t1 + t2)
    C = B + a * (t2 + t3)
    return A, t1, B, t2, C, t3, R2


@pytest.mark.parametrize("kind,turn2", [("C", +1), ("S", -1)])
def test_c_and_s_type_with_known_junction(kind, turn2):
    A, t1, B, t2, C, t3, R2 = _hand_biarc(10.0, np.pi / 2, np.pi / 3, turn2)
    bi = biarc(A, t1, C, t3)
    assert bi.kind[0] == kind
    assert np.allclose(bi.B[0], B) and np.allclose(bi.t2[0], t2)
    assert np.allclose(bi.radius[0], [10.0, R2])
    assert np.isclose(R2, 10.0 / np.tan(np.pi / 6))
    assert np.allclose(bi.sweep_rad[0], [np.pi / 2, np.pi / 3])
    assert bi.twist_rad[0] < 1e-9
    # the paper's curvature formulas (§3.4, with |.|) give the same radii
    s = C - A
    a, b = bi.a[0], bi.b[0]
    k1 = np.linalg.norm(np.cross(t1, s) - b * np.cross(t1, t3)) / abs(s @ s / 2 - b * (s @ t3))
    k2 = np.linalg.norm(np.cross(s, t3) - a * np.cross(t1, t3)) / abs(s @ s / 2 - a * (s @ t1))
    assert np.allclose(bi.curvature[0], [k1, k2])


def test_twisted_3d_biarc_is_tangent_everywhere():
    rng = np.random.default_rng(7)
    m = 200
    A = rng.normal(size=(m, 3))
    s = rng.normal(size=(m, 3)) * 5
    t1 = _unit(_unit(s) + 0.7 * rng.normal(size=(m, 3)))
    t3 = _unit(_unit(s) + 0.7 * rng.normal(size=(m, 3)))
    for method in ("equal", "chui"):
        bi = biarc(A, t1, A + s, t3, method=method)
        assert bi.proper.all()
        assert np.abs(bi.end_tangent[:, 0] - bi.t2).max() < 1e-9
        assert np.abs(bi.end_tangent[:, 1] - t3).max() < 1e-9
        assert np.abs(bi.end[:, 0] - bi.B).max() < 1e-9
        assert np.abs(bi.end[:, 1] - (A + s)).max() < 1e-9
        assert (bi.sweep_rad < np.pi).all()
        # A.6 holds for the (a, b) used
        p, q = (s * t1).sum(1), (s * t3).sum(1)
        w = 1 - (t1 * t3).sum(1)
        a, b = bi.a, bi.b
        assert np.allclose(a * b * w + a * p + b * q, (s * s).sum(1) / 2)
    assert bi.twist_rad.max() > 0.1 and set(bi.kind) <= {"C", "S"}


def test_errata_a8_minimises_a_plus_b_and_printed_form_fails_a6():
    rng = np.random.default_rng(11)
    m = 500
    s = rng.normal(size=(m, 3)) * 3
    t1 = _unit(_unit(s) + 0.4 * rng.normal(size=(m, 3)))
    t3 = _unit(_unit(s) + 0.4 * rng.normal(size=(m, 3)))
    p, q, ss = (s * t1).sum(1), (s * t3).sum(1), (s * s).sum(1)
    w = 1 - (t1 * t3).sum(1)
    u = np.sqrt(p * q + w * ss / 2)
    a_pr, b_pr = -q + u / w, -p + u / w  # as printed in §3.4
    assert not np.allclose(a_pr * b_pr * w + a_pr * p + b_pr * q, ss / 2)
    ch = biarc(np.zeros((m, 3)), t1, s, t3, method="chui")
    eq = biarc(np.zeros((m, 3)), t1, s, t3, method="equal")
    assert np.all(ch.a + ch.b <= eq.a + eq.b + 1e-9)
    used = ~np.isclose(ch.a, eq.a)  # spans where A.8 was proper (else the 'equal' fall-back)
    assert used.sum() > 50
    assert np.allclose(ch.a[used], ((u - q) / w)[used]) and np.allclose(ch.b[used], ((u - p) / w)[used])


def test_parallel_tangents_and_straight_line():
    # straight line: t1 = t3 along AC
    d = _unit([1.0, 2.0, -0.5])
    bi = biarc([0, 0, 0], d, 10 * d, d)
    assert np.all(np.isinf(bi.radius)) and bi.kind[0] == "L"
    assert np.allclose(bi.B[0], 5 * d) and np.isclose(bi.length.sum(), 10.0)
    for arr in (bi.centre, bi.normal, bi.a, bi.b, bi.curvature, bi.sweep_rad, bi.twist_rad):
        assert not np.isnan(arr).any()
    P = np.outer(np.linspace(0, 50, 101), d) + [1.0, 1.0, 1.0]
    fit = fit_biarcs(P, 1e-3)
    assert fit.n_biarcs == 1 and fit.n_arcs_out == 1 and fit.n_lines_out == 1
    assert fit.max_error_mm < 1e-12
    # parallel tangents off the chord, including tangents across and behind it: finite, G1
    t = np.array([[1.0, 0, 0], [0.0, 1, 0], [-1.0, 0.3, 0], [0.6, 0.0, 0.8]])
    t = _unit(t)
    C = np.array([4.0, 1.0, 0.5])
    bi = biarc(np.zeros((4, 3)), t, np.tile(C, (4, 1)), t)
    for arr in (bi.B, bi.t2, bi.centre, bi.normal, bi.curvature, bi.length, bi.sweep_rad, bi.twist_rad):
        assert np.isfinite(arr).all()
    assert np.allclose(bi.B, C / 2)  # equal chords
    assert np.abs(bi.end_tangent[:, 1] - t).max() < 1e-9
    assert np.abs(bi.end[:, 1] - C).max() < 1e-9
    assert list(bi.proper) == [True, True, False, True]  # the third points back: arcs over 180 deg
    # degenerate: A = C
    bi = biarc([1, 2, 3], [1, 0, 0], [1, 2, 3], [0, 1, 0])
    assert np.isfinite(bi.B).all() and not bi.proper[0] and np.all(bi.length == 0)


def test_corner_of_90_degrees_is_split_and_within_tolerance():
    # a quarter circle, then a 90-degree corner, then a helix-like climb
    th = np.linspace(0.0, np.pi / 2, 60)
    leg1 = np.stack([30 * np.sin(th), 30 * (1 - np.cos(th)), np.zeros_like(th)], 1)  # ends heading +y
    s = np.linspace(0.0, 40.0, 80)[1:]
    leg2 = leg1[-1] + np.stack([s, 2 * np.sin(s / 8), 0.1 * s], 1)  # leaves heading +x
    P = np.vstack([leg1, leg2])
    corner = len(leg1) - 1
    fit = fit_biarcs(P, 0.005)
    assert corner in fit.corners
    assert corner in fit.span_end and corner in fit.span_start
    assert fit.max_error_mm <= 0.005
    k = np.flatnonzero(fit.span_end == corner)[0]
    assert np.allclose(fit.biarcs.t3[k], [0, 1, 0], atol=1e-6)
    assert np.allclose(fit.biarcs.t1[k + 1], _unit([1.0, 0.25, 0.1]), atol=0.01)
    _check_junctions(fit)
    assert fit.n_arcs_out < len(P) / 5
    # an explicit break (a retract): the link move is not fitted, and the chords show the jump
    Q = np.vstack([leg1, leg1 + [0.0, 0.0, 20.0]])
    fit = fit_biarcs(Q, 0.005, breaks=[len(leg1)])
    assert fit.n_biarcs == 2 and fit.path_piece.tolist() == [0, 1] and len(fit.corners) == 0
    _, pts = fit.points(0.001)
    jump = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    assert jump.max() > 19.0 and (jump > 1.0).sum() == 1


def test_chords_stay_within_tolerance_of_their_arcs():
    rng = np.random.default_rng(5)
    m = 50
    s = rng.normal(size=(m, 3)) * 20
    bi = biarc(rng.normal(size=(m, 3)), _unit(_unit(s) + 0.8 * rng.normal(size=(m, 3))), s,
               _unit(_unit(s) + 0.8 * rng.normal(size=(m, 3))))
    tol = 0.002
    owner, pts = biarc_chords(bi, tol)
    assert np.all(np.diff(owner) >= 0)
    # every vertex lies on its biarc, every chord midpoint within tol of it
    assert distance_to_biarcs(pts, bi, owner).max() < 1e-9
    new = np.r_[True, owner[1:] != owner[:-1]]  # each biarc's first point (a jump in between)
    mid = (pts[:-1] + pts[1:])[~new[1:]] / 2
    assert distance_to_biarcs(mid, bi, owner[1:][~new[1:]]).max() <= tol
    assert len(pts) < 20 * m * 10


@pytest.mark.parametrize("seed", range(6))
def test_random_smooth_curves_stay_within_tolerance(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(150, 400))
    u = np.linspace(0.0, 1.0, n)
    k = np.arange(1, 4)
    amp = rng.normal(size=(3, 3)) * 15 / k[None, :] ** 1.5
    ph = rng.uniform(0, 2 * np.pi, size=(3, 3))
    P = (amp[None] * np.sin(2 * np.pi * k[None, None, :] * u[:, None, None] + ph[None])).sum(-1)
    P += np.outer(u, rng.normal(size=3) * 40)
    tol = float(rng.choice([0.001, 0.005, 0.02]))
    fit = fit_biarcs(P, tol, method="equal" if seed % 2 else "chui")
    assert fit.max_error_mm <= tol
    assert distance_to_biarcs(P, fit.biarcs).max() <= tol
    _, C = biarc_chords(fit.biarcs, tol / 100)
    assert _seg_distance(P, C).max() <= tol * 1.01
    assert not np.isnan(fit.biarcs.centre).any()
    _check_junctions(fit)


def test_a_refit_with_more_corners_through_the_memo_is_the_fresh_fit():
    rng = np.random.default_rng(11)
    u = np.linspace(0.0, 1.0, 600)
    P = np.stack([40 * u, 8 * np.sin(6 * u) + rng.normal(scale=0.002, size=u.size), 5 * np.cos(4 * u)], 1)
    memo: dict = {}
    fit_biarcs(P, 0.005, breaks=[300], memo=memo)
    n_pieces = len(memo)
    for corners in ([150], [150, 450], [75, 150, 450]):
        got = fit_biarcs(P, 0.005, breaks=[300], corners=corners, memo=memo)
        want = fit_biarcs(P, 0.005, breaks=[300], corners=corners)
        assert np.array_equal(got.span_start, want.span_start) and np.array_equal(got.span_end, want.span_end)
        assert np.array_equal(got.path_piece, want.path_piece) and got.max_error_mm == want.max_error_mm
    assert len(memo) == n_pieces + 6         # each new corner split one piece in two: only those were fitted
    # another tolerance is another fit, never one taken from the memo
    other = fit_biarcs(P, 0.05, breaks=[300], memo=memo)
    assert other.n_biarcs < got.n_biarcs - 2 and other.n_biarcs == fit_biarcs(P, 0.05, breaks=[300]).n_biarcs


def test_the_compiled_span_search_finds_the_spans_of_the_numpy_reference():
    """``fit_biarcs`` runs the greedy span search compiled (``_fit_piece_equal``); on noisy 3-D curves (a
    helix, a wavy line, a random walk) at several tolerances it must choose exactly the spans of the numpy
    reference ``_fit_piece`` (the same formulas, one span at a time)."""
    from planning.toolpath.fiveaxis.biarc import _fit_piece, _fit_piece_equal, path_tangents

    rng = np.random.default_rng(7)
    t = np.linspace(0.0, 6.0 * np.pi, 400)
    curves = [np.c_[20 * np.cos(t), 20 * np.sin(t), 2.0 * t],
              np.c_[np.linspace(0, 80, 300), 3.0 * np.sin(np.linspace(0, 9, 300)), np.zeros(300)],
              np.cumsum(rng.normal(size=(250, 3)) * [0.3, 0.3, 0.05] + [0.4, 0.0, 0.0], axis=0)]
    n_spans = 0
    for P in curves:
        P = P + rng.normal(scale=0.002, size=P.shape)
        T = path_tangents(P)
        for tol in (0.001, 0.005, 0.02):
            ref = _fit_piece(P, T, tol, "equal")
            fast = [(int(a), int(b)) for a, b in _fit_piece_equal(P, T, tol)]
            assert fast == ref, (tol, len(fast), len(ref))
            n_spans += len(ref)
    assert n_spans > 100              # the curves are not fitted by a handful of spans
