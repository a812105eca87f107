"""Exact confirmation of suspected gouges (planning/simulate/gouge.py) against analytic answers."""

from __future__ import annotations

import math

import numpy as np

from planning.simulate.gouge import penetration_mm
from planning.simulate.motion import FEED, RAPID, ProgramMotion, ToolShape

BALL = ToolShape(number=1, kind="ball", radius_mm=3.0, corner_radius_mm=3.0, flute_length_mm=15.0,
                 pieces=((15.0, math.inf, 5.0),), gauge_length_mm=90.0)
FLAT = ToolShape(number=2, kind="flat", radius_mm=5.0, corner_radius_mm=0.0, flute_length_mm=25.0,
                 pieces=((25.0, math.inf, 10.0),), gauge_length_mm=90.0)


def _motion(start, end, tool, kind=FEED, axis=(0.0, 0.0, 1.0)) -> ProgramMotion:
    s, e = np.atleast_2d(np.asarray(start, float)), np.atleast_2d(np.asarray(end, float))
    P = s.shape[0]
    return ProgramMotion(program="t", area=0, line=np.arange(1, P + 1), kind=np.full(P, kind, np.int8),
                         tool=np.full(P, tool), start_mm=s, end_mm=e,
                         axis=np.broadcast_to(np.asarray(axis, float), (P, 3)).copy(),
                         machine_mm=np.zeros((P, 3)), rotary_deg=np.zeros((P, 2)))


def test_ball_depth_is_radius_minus_distance_to_the_centre_line():
    # the ball's tip runs along y at z = -0.05: its centre 2.95 above the points on z = 0
    m = _motion([[-10, 0, -0.05]], [[10, 0, -0.05]], 1)
    pts = np.array([[0, 0, 0], [3, 0, 0], [0, 1, 0.0], [0, 10, 0], [12.0, 0, 0]])
    pen = penetration_mm(pts, [m], {1: BALL})
    expect = 3.0 - np.hypot(pts[:, 1], 2.95 - pts[:, 2])
    expect[4] = 3.0 - math.hypot(2.0, 2.95)
    finite = np.isfinite(pen)
    assert np.allclose(pen[finite], expect[finite], atol=1e-9)
    assert pen[0] > 0.049 and pen[3] < 0


def test_flat_depth_is_the_nearer_of_the_bottom_face_and_the_side():
    m = _motion([[-20, 0, -1.0]], [[20, 0, -1.0]], 2)
    pts = np.array([[0, 0, 0.0],        # 1 mm above the bottom face, on the axis: depth 1
                    [0, 4.7, 3.0],      # 0.3 mm inside the side
                    [0, 5.2, 0.0],      # outside the radius
                    [0, 0, 30.0]])      # above the flutes
    pen = penetration_mm(pts, [m], {2: FLAT})
    assert np.isclose(pen[0], 1.0, atol=1e-9)
    assert np.isclose(pen[1], 0.3, atol=1e-9)
    assert not pen[2] > 0 and not pen[3] > 0


def test_a_tilted_plunge_and_rapids():
    a = np.array([1.0, 0.0, 1.0]) / math.sqrt(2)
    # a plunge along the axis ending with the tip 0.5 below the point along the axis
    p = np.array([[0.0, 0.0, 0.0]])
    m = _motion([p[0] + 10 * a], [p[0] - 0.5 * a], 2, axis=a)
    assert np.isclose(penetration_mm(p, [m], {2: FLAT})[0], 0.5, atol=1e-9)
    # the same move as a rapid cuts nothing
    r = _motion([p[0] + 10 * a], [p[0] - 0.5 * a], 2, kind=RAPID, axis=a)
    assert penetration_mm(p, [r], {2: FLAT})[0] == -np.inf


def test_against_dense_sampling_on_random_moves():
    """A ball without a fluted cylinder above it (flute length R): the exact depth equals a dense
    sampling of the ball centre along every move."""
    ball_only = ToolShape(number=1, kind="ball", radius_mm=3.0, corner_radius_mm=3.0, flute_length_mm=3.0)
    rng = np.random.default_rng(3)
    s = rng.uniform(-5, 5, (40, 3))
    e = s + rng.uniform(-6, 6, (40, 3))
    pts = rng.uniform(-6, 6, (60, 3))
    pen = penetration_mm(pts, [_motion(s, e, 1)], {1: ball_only})
    t = np.linspace(0, 1, 4001)
    c = s[:, None, :] + t[None, :, None] * (e - s)[:, None, :] + np.array([0, 0, 3.0])   # ball centres
    ref = 3.0 - np.linalg.norm(pts[:, None, None, :] - c[None], axis=3).min(axis=(1, 2))
    reached = ref > 0.0
    assert reached.sum() > 5
    assert np.allclose(pen[reached], ref[reached], atol=2e-3)
    assert np.all(np.maximum(pen, 0) >= np.maximum(ref, 0) - 1e-9)


# ------------------------------------------------------------------ the kernels against the numpy code
# The numpy implementation the kernels replaced (issue 30), kept as the reference with the same
# operations: a k-d tree over the moves' pieces, the (point, move) pairs through np.unique, the depths
# vectorised over the pairs. bench/bench_gouge.py imports it from here to time the kernels against it.

REF_PIECE_MM = 4.0


def _ref_ball_depth(p, s, e, R):
    v = e - s
    L2 = np.einsum("ij,ij->i", v, v)
    t = np.clip(np.einsum("ij,ij->i", p - s, v) / np.maximum(L2, 1e-300), 0.0, 1.0)
    q = s + t[:, None] * v
    return R - np.linalg.norm(p - q, axis=1)


def _ref_flat_depth(p, s, e, a, Rt, L, samples=65, side_only=False):
    v = e - s
    w0 = p - s
    vv = v - np.einsum("ij,ij->i", v, a)[:, None] * a
    ww = w0 - np.einsum("ij,ij->i", w0, a)[:, None] * a
    A = np.einsum("ij,ij->i", vv, vv)
    B = -2.0 * np.einsum("ij,ij->i", ww, vv)
    C = np.einsum("ij,ij->i", ww, ww) - Rt * Rt
    disc = B * B - 4.0 * A * C
    moving = A > 1e-18
    root = np.sqrt(np.maximum(disc, 0.0))
    t0 = np.where(moving, (-B - root) / (2.0 * np.maximum(A, 1e-300)), 0.0)
    t1 = np.where(moving, (-B + root) / (2.0 * np.maximum(A, 1e-300)), 1.0)
    t0, t1 = np.clip(t0, 0.0, 1.0), np.clip(t1, 0.0, 1.0)
    hit = np.where(moving, disc >= 0.0, C <= 0.0) & (t1 >= t0)
    out = np.full(p.shape[0], -np.inf)
    f = np.linspace(0.0, 1.0, samples)
    hits = np.flatnonzero(hit)
    for c0 in range(0, hits.size, 20_000):
        idx = hits[c0:c0 + 20_000]
        t = t0[idx, None] + (t1 - t0)[idx, None] * f[None, :]
        w = w0[idx, None, :] - t[:, :, None] * v[idx, None, :]
        h = np.einsum("msk,mk->ms", w, a[idx])
        r = np.linalg.norm(w - h[:, :, None] * a[idx, None, :], axis=2)
        inside = (h >= 0.0) & (h <= L) & (r <= Rt + 1e-12)
        d = np.where(inside, (Rt - r) if side_only else np.minimum(h, Rt - r), -np.inf)
        out[idx] = d.max(axis=1)
    return out


def _ref_depth_pairs(pts, s, e, a, shape):
    """Depth of every row of ``pts`` against the move in the same row (the numpy formulas)."""
    if shape.kind == "ball":
        R = shape.radius_mm
        d = _ref_ball_depth(pts, s + R * a, e + R * a, R)
        if shape.flute_length_mm > R:
            side = _ref_flat_depth(pts, s + R * a, e + R * a, a, R, shape.flute_length_mm - R, side_only=True)
            d = np.maximum(d, side)
        return d
    return _ref_flat_depth(pts, s, e, a, shape.radius_mm, shape.flute_length_mm)


def reference_penetration_mm(points, motions, tools):
    """The numpy :func:`penetration_mm` before the kernels (issue 30)."""
    from scipy.spatial import cKDTree

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.full(pts.shape[0], -np.inf)
    if pts.shape[0] == 0:
        return out
    for m in motions:
        for number, shape in tools.items():
            sel = np.flatnonzero((m.kind == FEED) & (m.tool == number))
            if sel.size == 0:
                continue
            s, e, a = m.start_mm[sel], m.end_mm[sel], m.axis[sel]
            reach = max(float(np.hypot(shape.radius_mm, shape.flute_length_mm)), 2.0 * shape.radius_mm) + 1e-6
            length = np.linalg.norm(e - s, axis=1)
            n = np.maximum(1, np.ceil(length / REF_PIECE_MM).astype(np.int64))
            owner = np.repeat(np.arange(sel.size), n)
            k = np.arange(owner.size) - np.repeat(np.cumsum(n) - n, n)
            f = ((k + 0.5) / n[owner])[:, None]
            mids = s[owner] + f * (e - s)[owner]
            near = cKDTree(mids).query_ball_point(pts, 0.5 * REF_PIECE_MM + reach)
            cnt = np.fromiter((len(x) for x in near), dtype=np.int64, count=len(near))
            if cnt.sum() == 0:
                continue
            pair = np.unique(np.c_[np.repeat(np.arange(pts.shape[0]), cnt),
                                   owner[np.concatenate([np.asarray(x, dtype=np.int64) for x in near if x])]], axis=0)
            pi, mv = pair[:, 0], pair[:, 1]
            d = _ref_depth_pairs(pts[pi], s[mv], e[mv], a[mv], shape)
            np.maximum.at(out, pi, d)
    return out


def brute_force_depth(points, motions, tools):
    """The deepest depth of each point over EVERY feed move of its tools (no search radius): (n,)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.full(pts.shape[0], -np.inf)
    for m in motions:
        for number, shape in tools.items():
            sel = np.flatnonzero((m.kind == FEED) & (m.tool == number))
            for j in sel:
                n = pts.shape[0]
                d = _ref_depth_pairs(pts, np.repeat(m.start_mm[j:j + 1], n, 0), np.repeat(m.end_mm[j:j + 1], n, 0),
                                     np.repeat(m.axis[j:j + 1], n, 0), shape)
                out = np.maximum(out, d)
    return out


TOOLS = {1: BALL, 2: FLAT,
         3: ToolShape(number=3, kind="bull", radius_mm=4.0, corner_radius_mm=1.0, flute_length_mm=12.0),
         4: ToolShape(number=4, kind="ball", radius_mm=2.0, corner_radius_mm=2.0, flute_length_mm=2.0),
         5: ToolShape(number=5, kind="ball", radius_mm=0.5, corner_radius_mm=0.5, flute_length_mm=6.0)}


def _random_case(seed: int, n_moves: int = 120, n_points: int = 400, box: float = 20.0):
    """Two programs of random feed moves and rapids over tools 0..6 (1-5 in TOOLS): random directions
    and axes, some vertical axes, zero-length moves, plunges along the axis; points around them,
    some of them placed on the tools' boundaries by construction."""
    rng = np.random.default_rng(seed)
    motions = []
    for _ in range(2):
        s = rng.uniform(-box, box, (n_moves, 3))
        e = s + rng.normal(0.0, 6.0, (n_moves, 3)) * rng.uniform(0.0, 1.0, (n_moves, 1))
        ax = rng.normal(size=(n_moves, 3))
        ax /= np.linalg.norm(ax, axis=1)[:, None]
        ax[rng.random(n_moves) < 0.3] = (0.0, 0.0, 1.0)
        zero = rng.random(n_moves) < 0.1
        e[zero] = s[zero]                                           # moves of zero length
        plunge = rng.random(n_moves) < 0.1
        e[plunge] = s[plunge] - rng.uniform(0.5, 8.0, (plunge.sum(), 1)) * ax[plunge]    # along the axis
        m = _motion(s, e, 0, axis=(0.0, 0.0, 1.0))
        m.kind[:] = np.where(rng.random(n_moves) < 0.85, FEED, RAPID)
        m.tool[:] = rng.integers(0, 7, n_moves)
        m.axis[:] = ax
        motions.append(m)
    pts = [rng.uniform(-box - 10, box + 10, (n_points, 3))]
    # points near the moves: on the tip segment, on the ball's surface, on the bottom face and the side
    m = motions[0]
    j = rng.integers(0, n_moves, 60)
    t = rng.uniform(0.0, 1.0, (60, 1))
    tip = m.start_mm[j] + t * (m.end_mm[j] - m.start_mm[j])
    perp = np.cross(m.axis[j], rng.normal(size=(60, 3)))
    perp /= np.linalg.norm(perp, axis=1)[:, None]
    pts += [tip, tip + rng.normal(0, 1.0, (60, 3)), tip + 3.0 * m.axis[j] + 3.0 * perp,   # the ball of T1
            tip + 5.0 * perp + 2.0 * m.axis[j], tip + 4.0 * perp + 0.5 * m.axis[j]]     # sides of T2, T3
    return motions, np.concatenate(pts)


def test_the_kernels_equal_the_numpy_implementation_on_random_moves():
    worst, cut = 0.0, 0
    for seed in range(6):
        motions, pts = _random_case(seed)
        ref = reference_penetration_mm(pts, motions, TOOLS)
        got = penetration_mm(pts, motions, TOOLS)
        assert np.array_equal(np.isneginf(ref), np.isneginf(got)), seed        # the same points reached
        fin = np.isfinite(ref)
        assert np.all(np.isfinite(got[fin]))
        worst = max(worst, float(np.abs(ref[fin] - got[fin]).max(initial=0.0)))
        cut += int((ref > 0).sum())
    assert worst <= 1e-9, worst
    assert cut > 200                                # the cases do cut points, not only miss them


def test_the_cut_depth_equals_a_brute_force_over_every_pair():
    """Positive depths do not depend on the search radius: against every (point, feed move) pair."""
    for seed in (11, 12):
        motions, pts = _random_case(seed, n_moves=60, n_points=200)
        brute = brute_force_depth(pts, motions, TOOLS)
        got = penetration_mm(pts, motions, TOOLS)
        assert np.allclose(np.maximum(got, 0.0), np.maximum(brute, 0.0), rtol=0.0, atol=1e-9)
        assert (brute > 0).sum() > 20
        assert np.all(got <= brute + 1e-9)          # the candidates are a subset of all the moves


def test_points_on_the_boundaries_of_the_tools():
    """Axis +z, moves along x: points exactly on the ball's surface, the cylinder's bottom face, its
    side, at the top of the flutes, and a move of zero length (a point of the tool at rest)."""
    moves = _motion([[-10, 0, 0], [0, 20, 0], [30, 0, 0]], [[10, 0, 0], [0, 20, 0], [30, 0, -2]], 0)
    moves.tool[:] = 2
    ball = _motion([[-10, 40, 0]], [[10, 40, 0]], 1)
    pts = np.array([
        [0, 40, 0.0], [0, 43, 3.0], [12, 40, 3.0], [13, 40, 3.0], [0, 40, 15.0], [0, 43, 15.0],   # ball, T1
        [0, 40, 15.0 + 1e-9], [0, 43 + 1e-9, 9.0], [0, 43 - 1e-9, 9.0],
        [0, 20, 0.0], [0, 25, 0.0], [0, 25, 10.0], [0, 20, 25.0], [0, 20, 25.0 + 1e-9],            # flat at rest
        [3, 24, 0.0], [30, 0, -2.0], [30, 5, 0.0], [30, 0, 23.0], [30, 0, -2.0 - 1e-9],         # flat plunge
        [-10, 0, 0.0], [10, 0, 0.0], [0, -5, 1.0], [0, 5.0 + 1e-9, 1.0], [15, 0, 0.0],           # flat line
    ])
    tools = {1: BALL, 2: FLAT}
    ref = reference_penetration_mm(pts, [moves, ball], tools)
    got = penetration_mm(pts, [moves, ball], tools)
    assert np.array_equal(np.isneginf(ref), np.isneginf(got))
    fin = np.isfinite(ref)
    assert np.allclose(got[fin], ref[fin], rtol=0.0, atol=1e-9)
    # on the ball (tip, equator, end), inside its end, the top of its flutes: on the axis and the side
    assert got[0] == got[1] == got[3] == 0.0 and np.isclose(got[2], 1.0) and got[4] == 3.0 and got[5] == 0.0
    assert np.isclose(got[6], -9.000000001) and got[8] > 0.0 > got[7]      # just above, out of and in the side
    # the flat at rest: on its bottom face, its side, the top of its flutes, just above
    assert got[9] == got[10] == got[11] == 0.0 and got[12] == 5.0 and got[13] == -np.inf
    # the plunge: its last tip, its side, just below the tip
    assert got[15] == got[16] == 0.0 and got[17] == 5.0 and got[18] == -np.inf
    # the line: both ends, the side, just outside the side, beyond the end
    assert got[19] == got[20] == got[21] == got[23] == 0.0 and got[22] == -np.inf


def test_edge_inputs():
    motions, pts = _random_case(5, n_moves=30, n_points=40)
    assert penetration_mm(np.zeros((0, 3)), motions, TOOLS).shape == (0,)
    assert np.all(penetration_mm(pts, [], TOOLS) == -np.inf)
    assert np.all(penetration_mm(pts, motions, {}) == -np.inf)
    assert np.all(penetration_mm(pts, motions, {9: BALL}) == -np.inf)          # a tool that never ran
    bad = pts.copy()
    bad[3] = (np.nan, 0.0, 0.0)
    bad[7] = (np.inf, 1.0, 1.0)
    got, ref = penetration_mm(bad, motions, TOOLS), penetration_mm(pts, motions, TOOLS)
    assert got[3] == -np.inf and got[7] == -np.inf
    keep = np.ones(len(pts), bool)
    keep[[3, 7]] = False
    assert np.array_equal(got[keep], ref[keep])
    # points far away (the numpy code's k-d tree overflows at 1e300): reached by nothing
    far = np.array([[1e12, 0.0, 0.0], [-1e12, 5.0, 5.0], [0.0, 0.0, 1e300], [-1e308, 1e308, 0.0]])
    assert np.all(penetration_mm(np.vstack([far, pts[:3]]), motions, TOOLS) == np.r_[[-np.inf] * 4, ref[:3]])
    # one point, given flat; and a list input
    assert np.array_equal(penetration_mm(pts[5], motions, TOOLS), ref[5:6])
    assert np.array_equal(penetration_mm(pts.tolist(), motions, TOOLS), ref)


def test_many_points_over_many_moves_in_chunks():
    """More points than the blocks of every chunk, over a dense zig-zag: the same as the numpy code."""
    x = np.linspace(-30, 30, 61)
    rows = [np.c_[x if k % 2 == 0 else x[::-1], np.full_like(x, y), 0.05 * np.sin(x + y)]
            for k, y in enumerate(np.arange(-30, 30.1, 3.0))]
    path = np.concatenate(rows)
    m = _motion(path[:-1], path[1:], 1)
    rng = np.random.default_rng(8)
    pts = np.c_[rng.uniform(-32, 32, (1200, 2)), rng.uniform(-0.3, 0.3, 1200)]
    ref = reference_penetration_mm(pts, [m], {1: BALL})
    got = penetration_mm(pts, [m], {1: BALL})
    fin = np.isfinite(ref)
    assert np.array_equal(fin, np.isfinite(got))
    assert np.abs(got[fin] - ref[fin]).max() <= 1e-9
    assert (got > 0).sum() > 100


def test_the_result_does_not_depend_on_the_thread_count():
    import numba
    import pytest

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("numba runs on one thread here (NUMBA_NUM_THREADS)")
    motions, pts = _random_case(21, n_moves=200, n_points=2000)
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = penetration_mm(pts, motions, TOOLS)
        numba.set_num_threads(2)
        two = penetration_mm(pts, motions, TOOLS)
    finally:
        numba.set_num_threads(before)
    assert np.array_equal(one, two)
    assert (one > 0).sum() > 50


def test_the_warm_up_compiles_the_kernels_a_real_call_uses(tmp_path):
    """``warm_kernels`` (called by :func:`planning.warmup.warm`) into an empty numba cache; then a fresh
    process measures a plan-like input (two programs, a ball and a bull-nose, points given as float32)
    and compiles nothing: every kernel is loaded from the cache."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "SCANMILL_"))}
    env["SCANMILL_CACHE_DIR"] = str(tmp_path / "kernels")
    env["PYTHONPATH"] = os.pathsep.join([str(root), str(root / "tests")])
    warm = "from planning.simulate.gouge import warm_kernels; warm_kernels()"
    call = ("import json, numpy as np\n"
            "from planning.warmup import CompileCounter\n"
            "from planning.simulate.gouge import penetration_mm\n"
            "from test_simulate_gouge import TOOLS, _random_case\n"
            "motions, pts = _random_case(4)\n"
            "with CompileCounter() as c:\n"
            "    d = penetration_mm(pts.astype(np.float32), motions, {1: TOOLS[1], 3: TOOLS[3]})\n"
            "print(json.dumps({'compiled': c.compiled, 'cut': int((d > 0).sum())}))\n")
    for code in (warm, call):
        p = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                           timeout=900, check=False)
        assert p.returncode == 0, p.stderr[-3000:]
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert out["cut"] > 0
    assert [f for f in out["compiled"] if f.startswith("planning.")] == [], out["compiled"]


def _turning_steps(seed: int, n: int = 40, turn_deg: float = 0.7, step_mm: float = 0.25):
    """A 5-axis pass as the reader gives it: ball centres ``step_mm`` apart along a gentle curve, the axis
    turning ``turn_deg`` per step about a wandering direction, each step a move from the tip before to
    its own tip with its own (end) axis; a first move down to the first tip."""
    rng = np.random.default_rng(seed)
    R = BALL.radius_mm
    a = np.empty((n + 1, 3))
    a[0] = (0.3, -0.2, 0.93)
    a[0] /= np.linalg.norm(a[0])
    c = np.zeros((n + 1, 3))
    d = np.array([1.0, 0.3, 0.0]) / np.hypot(1.0, 0.3)
    for k in range(1, n + 1):
        d = d + rng.normal(0.0, 0.05, 3)
        d /= np.linalg.norm(d)
        c[k] = c[k - 1] + step_mm * d
        u = np.cross(a[k - 1], rng.normal(size=3))
        u /= np.linalg.norm(u)
        th = math.radians(turn_deg)
        a[k] = math.cos(th) * a[k - 1] + math.sin(th) * u
    tips = c - R * a
    start = np.vstack([tips[:1] + 20.0 * a[:1], tips[:-1]])
    m = _motion(start, tips, 1)
    m.axis[:] = a
    return m, c, a


def _true_depth(points, c, a, R, Lside, samples=801):
    """The depth of each point inside the ball or the side of its flutes over the steps run as a control
    runs them: the centre along its line, the axis turning between the steps' ends (normalised linear
    interpolation), sampled densely; (n,)."""
    out = np.full(points.shape[0], -np.inf)
    for k in range(1, c.shape[0]):
        for t in np.linspace(0.0, 1.0, samples):
            ax = (1 - t) * a[k - 1] + t * a[k]
            ax /= np.linalg.norm(ax)
            w = points - ((1 - t) * c[k - 1] + t * c[k])
            h = w @ ax
            r = np.linalg.norm(w - h[:, None] * ax, axis=1)
            ball = R - np.linalg.norm(w, axis=1)
            side = np.where((h >= 0.0) & (h <= Lside) & (r <= R), R - r, -np.inf)
            out = np.maximum(out, np.maximum(ball, side))
    return out


def test_the_flutes_turn_with_the_axis_on_a_five_axis_step():
    """Points beside the flutes of a pass whose axis turns 0.7 degrees a step: the measured depth is that
    of the tool run as the control runs it (the centre on its line, the axis turning), within the
    sampling, not that of flutes held at each step's end axis, which stand up to 0.15 mm off at the top
    of the flutes and read cuts the tool does not make. The 65 samples of a step lie at most a 64th of
    its path apart (0.004 mm of centre, 0.002 mm of turn at the flutes' top): a depth can read that much
    shallow, never deeper."""
    R, Lside = BALL.radius_mm, BALL.flute_length_mm - BALL.radius_mm
    worst, over, n_cut, n_false = 0.0, -np.inf, 0, 0
    for seed in (0, 1):
        m, c, a = _turning_steps(seed)
        rng = np.random.default_rng(100 + seed)
        k = rng.integers(1, c.shape[0], 300)
        t = rng.uniform(0.0, 1.0, (300, 1))
        ax = (1 - t) * a[k - 1] + t * a[k]
        ax /= np.linalg.norm(ax, axis=1)[:, None]
        perp = np.cross(ax, rng.normal(size=(300, 3)))
        perp /= np.linalg.norm(perp, axis=1)[:, None]
        h = rng.uniform(0.5, Lside - 0.5, (300, 1))
        pts = (1 - t) * c[k - 1] + t * c[k] + h * ax + (R + rng.uniform(-0.03, 0.06, (300, 1))) * perp
        got = penetration_mm(pts, [m], {1: BALL})
        true = _true_depth(pts, c, a, R, Lside)
        near = true > -0.2
        worst = max(worst, float((true[near] - got[near]).max()))
        over = max(over, float((got[near] - true[near]).max()))
        n_cut += int((true > 0.001).sum())
        # the same steps with the flutes held at each step's end axis (the measure before): deeper readings
        held = np.full(pts.shape[0], -np.inf)
        for j in range(1, c.shape[0]):
            held = np.maximum(held, _ref_depth_pairs(pts, np.repeat(c[j - 1:j] - R * a[j:j + 1], 300, 0),
                                                     np.repeat(c[j:j + 1] - R * a[j:j + 1], 300, 0),
                                                     np.repeat(a[j:j + 1], 300, 0), BALL))
        n_false += int(((held > true + 0.02) & near).sum())
    assert worst <= 0.006, worst
    assert over <= 1e-6, over
    assert n_cut > 50                     # points the flutes really cut, measured as deep as they are
    assert n_false > 50                   # and points the held flutes would read 0.02 mm or more too deep
