"""Cloud collisions of a ball-end cutter and holder (planning.geometry.collision)."""

from __future__ import annotations

import numpy as np
import pytest

from planning.geometry.collision import brute_force_collision_free, centres_collision_free, cloud_collision_free
from planning.errors import ParameterError
from planning.geometry.tool import Segment, ToolAssembly, ball_tool


def _tool(tool_radius_mm, flute_length_mm, holder_radius_mm=None, holder_length_mm=None):
    """Cutter cylinder of radius R up to flute_length_mm above the ball centre, then an optional
    holder (radius, length; length None = unbounded)."""
    L = float(flute_length_mm)
    segs = [Segment(0.0, L, tool_radius_mm, "cutter")]
    if holder_radius_mm is not None:
        segs.append(Segment(L, None if holder_length_mm is None else L + holder_length_mm,
                            holder_radius_mm, "holder"))
    return ToolAssembly(tool_radius_mm, tuple(segs), 100.0)


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _axes(rng, m, max_deg=85.0, hemisphere=True):
    """m random unit axes; within max_deg of +Z when hemisphere, else anywhere."""
    if hemisphere:
        ct = rng.uniform(np.cos(np.radians(max_deg)), 1.0, m)
        ph = rng.uniform(0, 2 * np.pi, m)
        st = np.sqrt(1 - ct ** 2)
        return np.stack([st * np.cos(ph), st * np.sin(ph), ct], axis=1)
    return _unit(rng.normal(size=(m, 3)))


def _bumpy(rng, n=324):
    k = int(np.sqrt(n))
    x, y = np.meshgrid(np.linspace(-15, 15, k), np.linspace(-15, 15, k))
    x = x.ravel() + rng.uniform(-0.4, 0.4, x.size)
    y = y.ravel() + rng.uniform(-0.4, 0.4, y.size)
    z = 3 * np.sin(x / 4) * np.cos(y / 5)
    fx = 3 / 4 * np.cos(x / 4) * np.cos(y / 5)
    fy = -3 / 5 * np.sin(x / 4) * np.sin(y / 5)
    return np.stack([x, y, z], 1), _unit(np.stack([-fx, -fy, np.ones_like(x)], 1))


def _slot(rng):
    """A plate with a 6 mm wide, 4 mm deep slot along y: floor, walls, top faces."""
    pts, nrm = [], []
    for x in np.linspace(-15, 15, 21):
        for y in np.linspace(-10, 10, 11):
            if abs(x) < 3:
                pts.append((x, y, -4.0)); nrm.append((0, 0, 1))
            elif abs(x) > 3:
                pts.append((x, y, 0.0)); nrm.append((0, 0, 1))
    for s in (-1, 1):
        for y in np.linspace(-10, 10, 11):
            for z in np.linspace(-3.5, -0.5, 5):
                pts.append((s * 3.0, y, z)); nrm.append((-s, 0, 0))
    pts = np.asarray(pts) + rng.normal(scale=0.05, size=(len(pts), 3))
    return pts, np.asarray(nrm, float)


def _post_wall(rng, g=10.0, r_p=2.0, hp=13.0):
    """Floor around the origin, a vertical post whose nearest generator is at x = g, a wall at y=12."""
    pts, nrm = [], []
    for x in np.linspace(-12, 12, 17):
        for y in np.linspace(-12, 12, 17):
            if np.hypot(x - (g + r_p), y) > r_p:
                pts.append((x, y, 0.0)); nrm.append((0, 0, 1))
    xp = g + r_p
    for ph in np.linspace(0, 2 * np.pi, 16, endpoint=False):
        for z in np.linspace(0, hp, 14):
            pts.append((xp - r_p * np.cos(ph), -r_p * np.sin(ph), z))
            nrm.append((-np.cos(ph), -np.sin(ph), 0))
    for x in np.linspace(-12, 12, 13):
        for z in np.linspace(0, 8, 5):
            pts.append((x, 12.0, z)); nrm.append((0, -1, 0))
    return np.asarray(pts), np.asarray(nrm, float)


def _noise_cloud(rng, n=300):
    pts = rng.uniform(-8, 8, size=(n, 3)) * np.array([1, 1, 0.4])
    return pts, _unit(rng.normal(size=(n, 3)) + np.array([0, 0, 1.5]))


TOOLS = [
    dict(tool_radius_mm=3.0, flute_length_mm=12.0),                                    # cutter only
    dict(tool_radius_mm=2.0, flute_length_mm=6.0, holder_radius_mm=6.0),               # infinite holder
    dict(tool_radius_mm=3.0, flute_length_mm=5.0, holder_radius_mm=8.0, holder_length_mm=10.0),
    dict(tool_radius_mm=3.0, flute_length_mm=4.0, holder_radius_mm=2.0),               # thin neck
    dict(tool_radius_mm=1.5, flute_length_mm=3.0, holder_radius_mm=1.0, holder_length_mm=4.0),
]


@pytest.mark.parametrize("cloud", ["bumpy", "slot", "post_wall", "noise"])
@pytest.mark.parametrize("tool", range(len(TOOLS)))
def test_fast_matches_brute_force(cloud, tool):
    rng = np.random.default_rng(100 * ["bumpy", "slot", "post_wall", "noise"].index(cloud) + tool)
    pts, nrm = {"bumpy": _bumpy, "slot": _slot, "post_wall": _post_wall, "noise": _noise_cloud}[cloud](rng)
    sample = rng.choice(pts.shape[0], size=min(60, pts.shape[0]), replace=False)
    axes = np.concatenate([_axes(rng, 20), _axes(rng, 6, hemisphere=False), [[0, 0, 1.0]]])
    kw = TOOLS[tool]
    fast = cloud_collision_free(pts, sample, nrm[sample], axes, tool=_tool(**kw))
    ref = brute_force_collision_free(pts, sample, nrm[sample], axes, tool=_tool(**kw))
    assert fast.shape == ref.shape == (sample.size, axes.shape[0])
    assert not np.any(fast & ~ref), "a colliding pair was called free"
    assert np.array_equal(fast, ref)
    # the test must exercise both outcomes
    assert ref.any() and not ref.all()


def test_candidates_and_progress():
    rng = np.random.default_rng(7)
    pts, nrm = _bumpy(rng)
    sample = np.arange(0, pts.shape[0], 5)
    axes = _axes(rng, 12)
    cand = rng.random((sample.size, axes.shape[0])) < 0.5
    calls = []
    kw = dict(tool_radius_mm=2.0, flute_length_mm=8.0, holder_radius_mm=5.0)
    fast = cloud_collision_free(pts, sample, nrm[sample], axes, candidates=cand,
                                progress=lambda d, t: calls.append((d, t)), tool=_tool(**kw))
    ref = brute_force_collision_free(pts, sample, nrm[sample], axes, candidates=cand, tool=_tool(**kw))
    full = brute_force_collision_free(pts, sample, nrm[sample], axes, tool=_tool(**kw))
    assert np.array_equal(fast, ref)
    assert not np.any(fast & ~cand)
    assert np.array_equal(fast[cand], full[cand])
    assert calls[-1] == (axes.shape[0], axes.shape[0]) and len(calls) == axes.shape[0]


def test_flat_plate_never_collides():
    # A ball on a plane: the cutter cylinder along any axis with t_z > 0 stays above the plane
    # (a point at distance s along the tilt has a = s sin(th) - R cos(th) and
    # rho = s cos(th) + R sin(th) >= R / sin(th) >= R whenever a > 0).
    x, y = np.meshgrid(np.linspace(-20, 20, 41), np.linspace(-20, 20, 41))
    pts = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    nrm = np.tile([0.0, 0.0, 1.0], (pts.shape[0], 1))
    rng = np.random.default_rng(3)
    axes = np.concatenate([_axes(rng, 40, max_deg=89.0), [[0, 0, 1.0], [1, 0, 1e-3]]])
    axes = _unit(axes)
    sample = np.arange(pts.shape[0])
    free = cloud_collision_free(pts, sample, nrm, axes, tool=_tool(tool_radius_mm=3.0, flute_length_mm=50.0))
    assert free.all()


def test_post_collides_when_tilt_reaches_its_top():
    # Contact at the origin on the floor (normal +Z, ball centre (0,0,R)), post whose nearest
    # generator is the line x = g, z in [0, hp]; axis t = (sin th, 0, cos th). For q = (g, 0, R + w):
    # a = g sin th + w cos th, rho = |g cos th - w sin th|. rho < R needs w > (g cos th - R)/sin th,
    # so (long flutes) the post's top w = hp - R is reached once g cos th - (hp - R) sin th < R:
    # th* = acos(R / sqrt(g^2 + (hp-R)^2)) - atan2(hp - R, g).
    g, r_p, hp, R = 10.0, 2.0, 13.0, 3.0
    pts, nrm = _post_wall(np.random.default_rng(0), g=g, r_p=r_p, hp=hp)
    pts = np.concatenate([pts, [[0.0, 0.0, 0.0]]])
    nrm = np.concatenate([nrm, [[0.0, 0.0, 1.0]]])
    i0 = pts.shape[0] - 1
    th_star = np.degrees(np.arccos(R / np.hypot(g, hp - R)) - np.arctan2(hp - R, g))
    assert 30 < th_star < 35
    ths = np.concatenate([np.linspace(0, th_star - 0.5, 8), np.linspace(th_star + 0.5, 80, 8)])
    axes = np.stack([np.sin(np.radians(ths)), np.zeros_like(ths), np.cos(np.radians(ths))], 1)
    kw = dict(tool_radius_mm=R, flute_length_mm=40.0)
    free = cloud_collision_free(pts, [i0], nrm[[i0]], axes, tool=_tool(**kw))[0]
    assert np.array_equal(free, ths < th_star)
    # tilting away from the post (towards -x) never meets it, nor the wall at y = 12
    away = axes * np.array([-1, 1, 1])
    assert cloud_collision_free(pts, [i0], nrm[[i0]], away, tool=_tool(**kw)).all()
    # a short cutter with no holder fits under the post top: a <= L cuts off the line
    assert np.array_equal(free, brute_force_collision_free(pts, [i0], nrm[[i0]], axes, tool=_tool(**kw))[0])


def test_invalid_arguments():
    pts = np.zeros((4, 3))
    tool = _tool(tool_radius_mm=1, flute_length_mm=1)
    with pytest.raises(ParameterError):
        cloud_collision_free(pts, [0], [[0, 0, 1]], [[0, 0, 1]], tool=None)
    with pytest.raises(ParameterError):
        cloud_collision_free(pts, [9], [[0, 0, 1]], [[0, 0, 1]], tool=tool)
    with pytest.raises(ParameterError):
        cloud_collision_free(pts, [0], [[0, 0, 1]], [[0, 0, 1]], tool=tool, candidates=np.ones((2, 1), bool))
    with pytest.raises(ParameterError):
        cloud_collision_free(pts, [0], [[0, 0, 1]], [[0, 0, 1]], tool=tool, obstacles=[[np.nan, 0, 0]])
    with pytest.raises(ParameterError):
        ball_tool(0.0, flute_length_mm=1)
    with pytest.raises(ParameterError):
        ball_tool(3.0, flute_length_mm=2)           # flutes shorter than the ball radius
    with pytest.raises(ParameterError):
        ball_tool(3.0, flute_length_mm=10, stickout_mm=5)


STACKS = [
    # a narrow neck under a wide holder, then a cone
    ball_tool(2.0, flute_length_mm=5.0, stickout_mm=12.0, shank_radius_mm=1.5,
              holder=[(5.0, 6.0, 8.0), (10.0, None, None)]),
    # a finite two-step holder, nothing above it
    ball_tool(3.0, flute_length_mm=8.0, stickout_mm=14.0, holder=[(6.0, 5.0, None), (9.0, 4.0, None)]),
]


@pytest.mark.parametrize("stack", range(len(STACKS)))
@pytest.mark.parametrize("cloud", ["bumpy", "post_wall", "noise"])
def test_tool_stacks_and_obstacles_match_brute_force(stack, cloud):
    rng = np.random.default_rng(50 + stack * 7 + ["bumpy", "post_wall", "noise"].index(cloud))
    pts, nrm = {"bumpy": _bumpy, "post_wall": _post_wall, "noise": _noise_cloud}[cloud](rng)
    sample = rng.choice(pts.shape[0], size=50, replace=False)
    axes = np.concatenate([_axes(rng, 16), _axes(rng, 4, hemisphere=False)])
    # extra forbidden points: a small block floating above part of the cloud
    extra = rng.uniform([-6, -6, 9], [0, 0, 14], size=(40, 3))
    tool = STACKS[stack]
    for obst in (None, extra):
        fast = cloud_collision_free(pts, sample, nrm[sample], axes, tool, obstacles=obst)
        ref = brute_force_collision_free(pts, sample, nrm[sample], axes, tool, obstacles=obst)
        assert np.array_equal(fast, ref)
        assert ref.any() and not ref.all()
    # the extra obstacles can only remove pairs
    assert not np.any(cloud_collision_free(pts, sample, nrm[sample], axes, tool, obstacles=extra)
                      & ~cloud_collision_free(pts, sample, nrm[sample], axes, tool))


def test_cell_size_changes_speed_only():
    rng = np.random.default_rng(11)
    pts, nrm = _bumpy(rng, n=900)
    sample = np.arange(0, pts.shape[0], 3)
    axes = _axes(rng, 24)
    tool = STACKS[0]
    ref = cloud_collision_free(pts, sample, nrm[sample], axes, tool)
    # a smaller cell than the default 0.35 and larger ones up to the largest allowed (0.1 costs 40 s here
    # and tests nothing 0.2 does not)
    for cf in (0.2, 1.0, 2.0):
        assert np.array_equal(cloud_collision_free(pts, sample, nrm[sample], axes, tool, cell_fraction=cf), ref)


def test_ball_tool_geometry():
    t = ball_tool(3.0, flute_length_mm=12.0, stickout_mm=30.0, shank_radius_mm=2.5,
                  holder=[(10.0, 40.0, None), (10.0, 20.0, 20.0)])
    cutter, shank = t.segments[0], t.segments[1]
    assert (cutter.lo_mm, cutter.hi_mm, cutter.radius_mm, cutter.part) == (0.0, 9.0, 3.0, "cutter")
    assert (shank.lo_mm, shank.hi_mm, shank.radius_mm, shank.part) == (9.0, 27.0, 2.5, "shank")
    holder = t.holder_segments
    assert holder[0].lo_mm == 27.0 and holder[0].hi_mm == 67.0
    cone = holder[1:]
    # the cone 10 -> 20 mm radius over 20 mm is sliced into cylinders that contain it
    assert cone[0].lo_mm == 67.0 and cone[-1].hi_mm == pytest.approx(87.0)
    for s in cone:
        r_top = 10.0 + 10.0 * (s.hi_mm - 67.0) / 20.0
        assert r_top - 1e-9 <= s.radius_mm <= r_top + 0.1 + 1e-9
    assert t.gauge_length_mm == pytest.approx(30.0 + 60.0)
    assert t.top_mm == pytest.approx(87.0)


def test_centres_match_the_rule_point_by_point():
    """Tool path CL points: centres given directly, checked against the collision rule written out
    in numpy for every (centre, axis, point)."""
    rng = np.random.default_rng(7)
    pts, _ = _bumpy(rng, 900)
    tool = ball_tool(3.0, flute_length_mm=8.0, stickout_mm=15.0, holder=[(8.0, 10.0, None)])
    centres = pts[rng.choice(pts.shape[0], 150, replace=False)] + rng.normal(scale=2.0, size=(150, 3))
    centres[:, 2] += 3.0
    axes = _axes(rng, 5, max_deg=50.0)
    got = centres_collision_free(pts, centres, axes, tool)
    ref = np.ones_like(got)
    for j, t in enumerate(axes):
        d = pts[None, :, :] - centres[:, None, :]
        a = d @ t
        rho = np.linalg.norm(d - a[..., None] * t, axis=2)
        for s in tool.segments:
            hi = np.inf if s.hi_mm is None else s.hi_mm
            ref[:, j] &= ~np.any((a > s.lo_mm) & (a <= hi) & (rho < s.radius_mm - 1e-6), axis=1)
    assert got.any() and (~got).any()
    assert np.array_equal(got, ref)
