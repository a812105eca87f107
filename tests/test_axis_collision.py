"""Collision test with one tool axis per ball-centre position (planning.geometry.axis_collision)."""

from __future__ import annotations

import numpy as np
import pytest

from planning.errors import ParameterError
from planning.geometry import axis_collision as axc
from planning.geometry.axis_collision import (ObstacleGrid, brute_force_pointwise, default_cell_mm,
                                              pointwise_collision_free)
from planning.geometry.collision import EPS_MM, centres_collision_free
from planning.geometry.tool import Segment, ToolAssembly, ball_tool

DEFAULT = ball_tool(3.0, flute_length_mm=12.0, stickout_mm=30.0, holder=[(12.5, 45.0, None), (25.0, 40.0, None)])
UNBOUNDED = ball_tool(3.0, flute_length_mm=12.0, stickout_mm=30.0, holder=[(12.5, 45.0, None), (25.0, None, None)])
# a cone (sliced into 0.1 mm cylinders) below an unbounded holder; a thinner shank
CONE = ball_tool(2.0, flute_length_mm=8.0, stickout_mm=20.0, shank_radius_mm=1.6,
                 holder=[(6.0, 10.0, 7.2), (7.5, None, None)])
# hand-made: overlapping segments, a gap in a, a wider segment below a narrower one
ODD = ToolAssembly(2.0, (Segment(0.0, 5.0, 2.0, "cutter"), Segment(3.0, 9.0, 2.5, "shank"),
                         Segment(11.0, 14.0, 4.0, "holder"), Segment(12.0, None, 1.5, "holder")), 100.0)
TOOLS = {"default": DEFAULT, "unbounded": UNBOUNDED, "cone": CONE, "odd": ODD}


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _cap(rng, m, max_deg):
    ct = rng.uniform(np.cos(np.radians(max_deg)), 1.0, m)
    ph = rng.uniform(0, 2 * np.pi, m)
    st = np.sqrt(1 - ct * ct)
    return np.stack([st * np.cos(ph), st * np.sin(ph), ct], 1)


def _bumpy(rng, n=2500, half=30.0):
    """Points on a bumpy surface with their unit normals."""
    x, y = rng.uniform(-half, half, (2, n))
    z = 4 * np.sin(x / 5) * np.cos(y / 6) + 0.8 * np.sin(x + y)
    fx = 0.8 * np.cos(x / 5) * np.cos(y / 6) + 0.8 * np.cos(x + y)
    fy = -4 / 6 * np.sin(x / 5) * np.sin(y / 6) + 0.8 * np.cos(x + y)
    return np.stack([x, y, z], 1), _unit(np.stack([-fx, -fy, np.ones_like(x)], 1))


def _cloud_and_poses(rng, R, n=240, n_air=12):
    """A bumpy surface plus random points above it; ball centres on the surface (p + R n) and a few
    random ones; axes: within 90 deg of +Z, anywhere on the sphere, and exactly axis aligned."""
    P, N = _bumpy(rng)
    obst = np.concatenate([P, rng.uniform([-30, -30, 2], [30, 30, 40], (n_air, 3))])
    pick = rng.choice(P.shape[0], n - 40, replace=False)
    C = np.concatenate([P[pick] + R * N[pick], rng.uniform([-30, -30, -2], [30, 30, 15], (40, 3))])
    A = np.concatenate([_cap(rng, n // 2, 90.0), _unit(rng.normal(size=(n - n // 2, 3)))])
    eye = np.concatenate([np.eye(3), -np.eye(3)])
    A[:30] = eye[np.arange(30) % 6]
    A[30:40] = [0.0, 0.0, 1.0]
    return obst, C, A


@pytest.mark.parametrize("name", sorted(TOOLS))
def test_agrees_with_brute_force_on_random_clouds(name):
    tool = TOOLS[name]
    rng = np.random.default_rng(sorted(TOOLS).index(name))
    obst, C, A = _cloud_and_poses(rng, tool.radius_mm)
    ref = brute_force_pointwise(obst, C, A, tool)
    assert 0.1 < ref.mean() < 0.9                   # both answers occur
    assert np.array_equal(pointwise_collision_free(obst, C, A, tool), ref)
    for cell in (0.3, 1.7, 9.0):                    # the cell changes the speed, never the answer
        assert np.array_equal(ObstacleGrid(obst, cell).free(C, A, tool), ref)


def _perp(t, rng):
    """A random unit vector normal to t."""
    u = np.cross(t, _unit(rng.normal(size=3)))
    return u / np.linalg.norm(u)


def _straddle(c, t, q, step_dir, tool):
    """The two neighbouring floats of ``q`` (stepping its coordinate most along ``step_dir`` one ulp at
    a time, at most 40 steps) across which the reference's answer for the single point flips, as
    (inside, outside); None where it does not flip."""
    j = int(np.argmax(np.abs(step_dir)))
    ref = lambda x: not brute_force_pointwise(x[None], c[None], t[None], tool)[0]
    q = q.copy()
    was = ref(q)
    for _ in range(40):
        nxt = q.copy()
        # towards the outside when inside, and back
        nxt[j] = np.nextafter(q[j], np.inf if (step_dir[j] > 0) == was else -np.inf)
        now = ref(nxt)
        if now != was:
            return (q, nxt) if was else (nxt, q)
        q = nxt
    return None


@pytest.mark.parametrize("name", ["default", "unbounded", "cone", "odd"])
def test_agrees_on_points_placed_at_the_boundaries(name):
    """Single obstacle points on the cylinder walls (rho = r - EPS_MM), at the tops (a = hi) and the
    bottoms (a = lo) of the segments, moved one ulp at a time until the reference's answer flips: the
    last float inside and the first outside. Any other rounding of ``a`` or ``rho`` than the
    reference's would flip some of them."""
    tool = TOOLS[name]
    rng = np.random.default_rng(7)
    segs = [(s.lo_mm, s.hi_mm, s.radius_mm) for s in tool.segments]
    cases = []
    for i in range(90):
        c = rng.uniform(-2, 2, 3)
        if i % 6 == 0:                               # exactly axis aligned
            t = np.eye(3)[i % 3] * (1 if i % 12 else -1)
        else:
            t = _cap(rng, 1, 90.0)[0]
        lo, hi, r = segs[rng.integers(len(segs))]
        top = lo + 5.0 if hi is None else hi
        u = _perp(t, rng)
        kind = i % 3
        if kind == 0:                                # on the wall, anywhere along the segment
            q, d = c + rng.uniform(lo, top) * t + (r - EPS_MM) * u, u
        elif kind == 1 and hi is not None:           # at the top
            q, d = c + hi * t + rng.uniform(0, r - 0.01) * u, t
        else:                                        # at the bottom
            q, d = c + lo * t + rng.uniform(0, r - 0.01) * u, -t
        pair = _straddle(c, t, q, d, tool)
        if pair is not None:
            cases += [(c, t, pair[0], False), (c, t, pair[1], True)]
    assert len(cases) >= 60
    for c, t, q, free in cases:
        assert pointwise_collision_free(q[None], c[None], t[None], tool)[0] == free, (c, t, q)
    # the same points all at once, each with its own tool position far from the others
    off = np.arange(len(cases))[:, None] * np.array([500.0, 0.0, 0.0])
    C = np.array([k[0] for k in cases]) + off
    A = np.array([k[1] for k in cases])
    Q = np.array([k[2] for k in cases]) + off
    ref = brute_force_pointwise(Q, C, A, tool)
    assert np.array_equal(pointwise_collision_free(Q, C, A, tool), ref)
    assert np.array_equal(ObstacleGrid(Q, 0.5).free(C, A, tool), ref)


def test_exact_boundaries_known_answers():
    """Axis +Z, centre at the origin, default tool (cutter and shank r 3 to a = 27, holder r 12.5 above):
    a = hi belongs to the lower segment, a = lo not to the upper one; a <= 0 (the ball) is never tested."""
    tool = DEFAULT
    c = np.zeros((1, 3))
    t = np.array([[0.0, 0.0, 1.0]])
    cases = [((5.0, 0.0, 27.0), True),            # a = 27: shank top (r 3 < 5), holder needs a > 27
             ((5.0, 0.0, 27.25), False),          # in the holder
             ((2.5, 0.0, 0.0), True),             # a = 0: the ball, not tested
             ((0.0, 0.0, -1.0), True),
             ((2.5, 0.0, 1e-9), False),           # just above the ball centre, inside the cutter
             ((3.0, 0.0, 5.0), True),             # on the cutter wall
             ((0.0, 2.9, 5.0), False),
             ((12.0, 0.0, 112.0), False),         # a = 112: the top of the holder (r 25), included
             ((12.0, 0.0, 112.5), True)]          # above the holder
    for q, free in cases:
        q = np.array([q])
        assert pointwise_collision_free(q, c, t, tool)[0] == free, q
        assert brute_force_pointwise(q, c, t, tool)[0] == free, q


@pytest.mark.parametrize("name", ["default", "unbounded", "cone"])
def test_same_axis_everywhere_matches_centres_collision_free(name):
    tool = TOOLS[name]
    rng = np.random.default_rng(11)
    P, N = _bumpy(rng, n=3000)
    obst = np.concatenate([P, rng.uniform([-30, -30, 0], [30, 30, 30], (100, 3))])
    pick = rng.choice(P.shape[0], 400, replace=False)
    C = P[pick] + tool.radius_mm * N[pick]
    for axis in ([0.0, 0.0, 1.0], _cap(rng, 1, 50.0)[0], [1.0, 0.0, 0.0], _cap(rng, 1, 85.0)[0]):
        axis = np.asarray(axis, dtype=float)
        one = centres_collision_free(obst, C, axis[None], tool)[:, 0]
        got = pointwise_collision_free(obst, C, np.tile(axis, (C.shape[0], 1)), tool)
        assert np.array_equal(got, one), axis
    assert 0 < one.sum() < one.size


def _wall():
    """A vertical plane wall of points: x = 10, -30 <= y <= 30, 0 <= z <= 60."""
    y, z = np.meshgrid(np.linspace(-30, 30, 61), np.linspace(0, 60, 61))
    return np.stack([np.full(y.size, 10.0), y.ravel(), z.ravel()], 1)


def _post():
    """A vertical cylinder wall of points: radius 6 about the line x = 16, y = 0, 0 <= z <= 60."""
    ph, z = np.meshgrid(np.linspace(0, 2 * np.pi, 90, endpoint=False), np.linspace(0, 60, 121))
    return np.stack([16 + 6 * np.cos(ph.ravel()), 6 * np.sin(ph.ravel()), z.ravel()], 1)


@pytest.mark.parametrize("wall", [_wall(), _post()], ids=["plane", "cylinder"])
def test_wall_tilted_towards_collides_tilted_away_is_free(wall):
    """The default tool with its ball centre 6 mm from a vertical wall (the cutter, r 3, clears it)."""
    c = np.array([[4.0, 0.0, 3.0]] * 3)
    s, k = np.sin(np.radians(30)), np.cos(np.radians(30))
    axes = np.array([[s, 0.0, k], [-s, 0.0, k], [0.0, 0.0, 1.0]])   # towards, away, vertical
    free = pointwise_collision_free(wall, c, axes, DEFAULT)
    assert free.tolist() == [False, True, False]            # vertical: the holder (r 12.5) reaches x = 16.5
    assert np.array_equal(free, brute_force_pointwise(wall, c, axes, DEFAULT))
    # only the tool itself (cutter, shank): tilted 30 deg towards the wall the shank top is at x = 17.5
    assert pointwise_collision_free(wall, c, axes, DEFAULT, parts=("cutter", "shank")).tolist() == [False, True, True]


def test_parts_restrict_the_test():
    rng = np.random.default_rng(3)
    obst, C, A = _cloud_and_poses(rng, 3.0)
    grid = ObstacleGrid(obst, default_cell_mm(DEFAULT))
    every = grid.free(C, A, DEFAULT)
    for parts in (("cutter",), ("cutter", "shank"), ("holder",), "holder", ("shank", "holder")):
        got = grid.free(C, A, DEFAULT, parts=parts)
        assert np.array_equal(got, brute_force_pointwise(obst, C, A, DEFAULT, parts=parts)), parts
        assert np.all(got >= every)                         # fewer segments, fewer collisions
    tool_only = grid.free(C, A, DEFAULT, parts=("cutter", "shank"))
    holder = grid.free(C, A, DEFAULT, parts=("holder",))
    assert np.array_equal(every, tool_only & holder)
    assert not np.array_equal(tool_only, every) and not np.array_equal(holder, every)
    # a holder alone beside a wall: the tool clears it, the holder does not
    wall = _wall()
    c, t = np.array([[4.0, 0.0, 3.0]]), np.array([[0.0, 0.0, 1.0]])
    assert pointwise_collision_free(wall, c, t, DEFAULT, parts=("cutter", "shank"))[0]
    assert not pointwise_collision_free(wall, c, t, DEFAULT, parts=("holder",))[0]
    assert pointwise_collision_free(wall, c, t, ball_tool(3.0, flute_length_mm=12.0), parts=("holder",))[0]


def test_batches_progress_and_axis_scaling(monkeypatch):
    rng = np.random.default_rng(5)
    obst, C, A = _cloud_and_poses(rng, 3.0, n=120)
    ref = brute_force_pointwise(obst, C, A, UNBOUNDED)
    monkeypatch.setattr(axc, "_BATCH", 7)
    seen = []
    got = pointwise_collision_free(obst, C, A * rng.uniform(0.2, 5.0, (C.shape[0], 1)), UNBOUNDED,
                                   progress=lambda done, total: seen.append((done, total)))
    assert np.array_equal(got, ref)
    assert seen[-1] == (120, 120) and len(seen) == 18
    assert [d for d, _ in seen] == sorted(d for d, _ in seen)


def test_degenerate_inputs():
    rng = np.random.default_rng(9)
    C = rng.uniform(-5, 5, (4, 3))
    A = _cap(rng, 4, 60.0)
    assert pointwise_collision_free(np.zeros((0, 3)), C, A, DEFAULT).all()
    assert pointwise_collision_free(rng.normal(size=(50, 3)), np.zeros((0, 3)), np.zeros((0, 3)), DEFAULT).shape == (0,)
    one = np.array([[0.0, 0.0, 5.0]])
    assert not pointwise_collision_free(one, np.zeros((1, 3)), [[0.0, 0.0, 1.0]], DEFAULT)[0]
    assert pointwise_collision_free(one, np.zeros((1, 3)), [[0.0, 0.0, 1.0]], DEFAULT, parts=("holder",))[0]
    # a huge box with a tiny cell: the cell is raised to fit 2^20 cells a side, same answer
    far = np.concatenate([rng.uniform(-3, 3, (200, 3)), [[5e6, 5e6, 5e6], [-5e6, 0, 0]]])
    Cf, Af = rng.uniform(-3, 3, (30, 3)), _cap(rng, 30, 90.0)
    grid = ObstacleGrid(far, 1e-3)
    assert grid.cell_mm > 1e-3
    assert np.array_equal(grid.free(Cf, Af, DEFAULT), brute_force_pointwise(far, Cf, Af, DEFAULT))


@pytest.mark.parametrize("kwargs, match", [
    (dict(obstacles=np.zeros((5, 2))), "obstacles"),
    (dict(obstacles=np.full((5, 3), np.nan)), "obstacles"),
    (dict(centres=np.zeros((3, 3))), "one row per centre"),
    (dict(centres=np.array([[np.inf, 0, 0], [0, 0, 0]])), "centres"),
    (dict(axes=np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])), "zero length"),
    (dict(axes=np.array([[0.0, 0.0, 1.0], [np.nan, 0.0, 1.0]])), "axes"),
    (dict(parts=("spindle",)), "unknown tool part"),
    (dict(tool="ball"), "ToolAssembly"),
])
def test_invalid_inputs_raise(kwargs, match):
    args = dict(obstacles=np.zeros((5, 3)), centres=np.zeros((2, 3)), axes=np.array([[0.0, 0.0, 1.0]] * 2),
                tool=DEFAULT, parts=None)
    args.update(kwargs)
    with pytest.raises(ParameterError, match=match):
        pointwise_collision_free(args["obstacles"], args["centres"], args["axes"], args["tool"], parts=args["parts"])
    with pytest.raises(ParameterError, match=match):
        brute_force_pointwise(args["obstacles"], args["centres"], args["axes"], args["tool"], parts=args["parts"])
    with pytest.raises(ParameterError):
        ObstacleGrid(np.zeros((5, 3)), 0.0)
