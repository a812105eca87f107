"""Tool and holder against fixtures (planning.geometry.fixtures, Makki 2010 §2.2.4)."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest

from planning.errors import InputError, ParameterError
from planning.geometry.fixtures import (
    BoxFixture,
    CylinderFixture,
    MeshFixture,
    TableFixture,
    brute_force_fixture_collision_free,
    fixture_collision_free,
    load_mesh,
)
from planning.geometry.tool import Segment, ToolAssembly, ball_tool


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _rotation(rng):
    q = _unit(rng.normal(size=4))
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _mesh(o3d_mesh, *, solid=False, shift=(0, 0, 0), name="mesh"):
    return MeshFixture(np.asarray(o3d_mesh.vertices) + np.asarray(shift, float),
                       np.asarray(o3d_mesh.triangles), name=name, solid=solid)


def _tilt(theta_deg, phi_deg=0.0):
    th, ph = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])


TOOLS = {
    # ball R 2, cutter to 8, holder r 6 to 30 (bounded)
    "short": ball_tool(2.0, flute_length_mm=10.0, holder=[(6.0, 20.0, None)]),
    # cone holder (sliced into many segments), unbounded spindle cylinder
    "cone": ball_tool(3.0, flute_length_mm=12.0, stickout_mm=25.0, shank_radius_mm=2.5,
                      holder=[(8.0, 15.0, 9.0), (14.0, None, None)]),
}


def _random_scene(rng):
    lo = rng.uniform(-30, 10, 3)
    box = BoxFixture(lo, lo + rng.uniform(4, 30, 3), name="box")
    lo2 = rng.uniform(-30, 10, 3)
    rbox = BoxFixture(lo2, lo2 + rng.uniform(4, 25, 3), rotation=_rotation(rng), name="rotated")
    cyl = CylinderFixture(rng.uniform(-25, 25, 3), rng.normal(size=3), rng.uniform(2, 10),
                          rng.uniform(5, 30), name="post")
    mesh = _mesh(o3d.geometry.TriangleMesh.create_cylinder(5.0, 12.0, resolution=12),
                 solid=True, shift=rng.uniform(-25, 25, 3), name="mesh")
    return [box, rbox, cyl, mesh, TableFixture(-35.0)]


# ----------------------------------------------------------------------------------------------
# fast method == FCL on every pair

@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("tool", sorted(TOOLS))
def test_fast_matches_brute_force(seed, tool):
    rng = np.random.default_rng(seed)
    fixtures = _random_scene(rng)
    centres = rng.uniform(-35, 35, (40, 3))
    axes = np.concatenate([_unit(rng.normal(size=(14, 3))),                 # anywhere, also down
                           [_tilt(th, ph) for th, ph in rng.uniform((0, 0), (85, 360), (10, 2))]])
    stats = {}
    fast = fixture_collision_free(centres, axes, TOOLS[tool], fixtures, stats=stats)
    ref = brute_force_fixture_collision_free(centres, axes, TOOLS[tool], fixtures)
    assert fast.dtype == bool and fast.shape == (40, 24)
    np.testing.assert_array_equal(fast, ref)
    assert 0 < fast.mean() < 1
    assert stats["pairs"] == fast.size
    assert 0 < stats["pairs_fcl"] < fast.size          # both numpy and FCL decide some pairs


def test_fast_matches_brute_force_on_a_clamped_part():
    """Centres on a part's top and side with a vise, two clamps (one turned) and the table."""
    rng = np.random.default_rng(7)
    fixtures = [BoxFixture((-25, -20, -30), (25, 20, 0), name="vise"),
                BoxFixture((22, -5, 10), (32, 5, 16), name="clamp"),
                BoxFixture((-32, -5, 10), (-22, 5, 16), name="turned clamp",
                           rotation=[[math.cos(0.3), -math.sin(0.3), 0], [math.sin(0.3), math.cos(0.3), 0], [0, 0, 1]]),
                TableFixture(-30.0)]
    top = np.c_[rng.uniform(-30, 30, 60), rng.uniform(-15, 15, 60), np.full(60, 10.0 + 3.0)]
    side = np.c_[np.full(30, 33.0), rng.uniform(-15, 15, 30), rng.uniform(0, 10, 30)]
    centres = np.concatenate([top, side])
    axes = np.array([_tilt(th, ph) for th in (0, 20, 40, 60, 80) for ph in range(0, 360, 45)])
    tool = ball_tool(3.0, flute_length_mm=15.0, stickout_mm=30.0, holder=[(10.0, 20.0, None), (15.0, None, None)])
    fast = fixture_collision_free(centres, axes, tool, fixtures)
    ref = brute_force_fixture_collision_free(centres, axes, tool, fixtures)
    np.testing.assert_array_equal(fast, ref)
    assert 0.1 < fast.mean() < 0.9


def test_candidates_and_progress():
    rng = np.random.default_rng(3)
    fixtures = _random_scene(rng)
    centres = rng.uniform(-30, 30, (25, 3))
    axes = _unit(rng.normal(size=(9, 3)))
    cand = rng.random((25, 9)) < 0.5
    calls = []
    fast = fixture_collision_free(centres, axes, TOOLS["short"], fixtures, candidates=cand,
                                  progress=lambda d, t: calls.append((d, t)))
    full = brute_force_fixture_collision_free(centres, axes, TOOLS["short"], fixtures)
    np.testing.assert_array_equal(fast, full & cand)
    np.testing.assert_array_equal(
        brute_force_fixture_collision_free(centres, axes, TOOLS["short"], fixtures, candidates=cand), full & cand)
    assert calls == [(j + 1, 9) for j in range(9)]
    assert fixture_collision_free(np.zeros((0, 3)), axes, TOOLS["short"], fixtures).shape == (0, 9)
    assert fixture_collision_free(centres, np.zeros((0, 3)), TOOLS["short"], fixtures).shape == (25, 0)
    assert fixture_collision_free(centres, axes, TOOLS["short"], []).all()


# ----------------------------------------------------------------------------------------------
# an independent reference without FCL: points sampled on the tool's surface

def _tool_surface(tool: ToolAssembly, c, t, h):
    """Points on the boundary of every part of the (bounded) tool, spacing <= h, and the covering
    radius: every boundary point lies within that distance of a sample."""
    u = _unit(np.cross(t, [1.0, 0, 0] if abs(t[0]) < 0.9 else [0, 1.0, 0]))
    v = np.cross(t, u)
    R = tool.radius_mm
    pts = []
    n_lat = math.ceil(math.pi * R / h) + 1
    for lat in np.linspace(0, math.pi, n_lat):
        k = max(1, math.ceil(2 * math.pi * R * math.sin(lat) / h))
        ph = np.arange(k) * 2 * math.pi / k
        d = (np.cos(lat) * t[None] + math.sin(lat) * (np.cos(ph)[:, None] * u + np.sin(ph)[:, None] * v))
        pts.append(c + R * d)
    for s in tool.segments:
        lo, hi, r = s.lo_mm, s.hi_mm, s.radius_mm
        k = math.ceil(2 * math.pi * r / h)
        ph = np.arange(k) * 2 * math.pi / k
        ring = np.cos(ph)[:, None] * u + np.sin(ph)[:, None] * v
        for a in np.linspace(lo, hi, math.ceil((hi - lo) / h) + 1):
            pts.append(c + a * t + r * ring)
        for rr in np.linspace(0, r, math.ceil(r / h) + 1):
            kk = max(1, math.ceil(2 * math.pi * rr / h))
            ring2 = np.cos(np.arange(kk) * 2 * math.pi / kk)[:, None] * u \
                + np.sin(np.arange(kk) * 2 * math.pi / kk)[:, None] * v
            pts += [c + lo * t + rr * ring2, c + hi * t + rr * ring2]
    return np.concatenate(pts), h          # grid steps <= h: covering radius <= h / sqrt(2) < h


def _in_tool(q, tool, c, t, tol=1e-9):
    d = q - c
    inside = np.linalg.norm(d, axis=-1) <= tool.radius_mm + tol
    a = d @ t
    rho = np.linalg.norm(d - a[..., None] * t, axis=-1)
    for s in tool.segments:
        inside |= (a >= s.lo_mm - tol) & (a <= s.hi_mm + tol) & (rho <= s.radius_mm + tol)
    return inside


def _box_local(box: BoxFixture, pts):
    return (pts - box.centre) @ box.rotation_matrix


@pytest.mark.parametrize("seed", [0, 1])
def test_boxes_and_table_against_surface_sampling(seed):
    rng = np.random.default_rng(seed)
    tool = ball_tool(2.0, flute_length_mm=8.0, holder=[(5.0, 12.0, None)])     # top at a = 18
    boxes = [BoxFixture((-6, -20, -4), (14, 20, 3)),
             BoxFixture((-4, -4, 8), (4, 4, 14), rotation=_rotation(rng)),
             BoxFixture((8, -3, 12), (16, 3, 20), rotation=_rotation(rng))]
    table_z = -6.0
    fixtures = boxes + [TableFixture(table_z)]
    centres = rng.uniform((-12, -12, -2), (12, 12, 12), (30, 3))
    axes = np.array([_tilt(th, ph) for th, ph in rng.uniform((0, 0), (100, 360), (16, 2))])
    fast = fixture_collision_free(centres, axes, tool, fixtures)
    each = [fixture_collision_free(centres, axes, tool, [f]) for f in fixtures]
    np.testing.assert_array_equal(fast, np.logical_and.reduce(each))
    h = 0.4
    n_checked = 0
    for i, c in enumerate(centres):
        for j, t in enumerate(axes):
            pts, cover = _tool_surface(tool, c, t, h)
            for b, box in enumerate(boxes):
                q = np.abs(_box_local(box, pts)) - box.half_mm
                strictly_in = (q < -1e-9).all(axis=1).any()
                dist = np.linalg.norm(np.maximum(q, 0), axis=1).min()
                corners = box.centre + (np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1)
                                                  for z in (-1, 1)]) * box.half_mm) @ box.rotation_matrix.T
                corner_in = _in_tool(corners, tool, c, t).any()
                if strictly_in:                                     # sampling never over-detects
                    assert not each[b][i, j], (i, j, b)
                if not each[b][i, j]:                               # a hit is real (up to sampling)
                    assert dist <= cover or corner_in, (i, j, b, dist)
                n_checked += 1
            low = pts[:, 2].min()
            if low < table_z - 1e-9:
                assert not each[-1][i, j]
            if not each[-1][i, j]:
                assert low <= table_z + cover
    assert n_checked == 30 * 16 * 3
    assert 0.05 < np.mean([e.mean() for e in each[:3]]) < 0.95


def test_table_formula():
    """The analytic half-space test: lowest point c_z + min(lo t_z, hi t_z) - r sqrt(1 - t_z^2)."""
    tool = ball_tool(3.0, flute_length_mm=15.0, stickout_mm=33.0, holder=[(20.0, None, None)])
    c = np.array([[0.0, 0.0, 3.0]])
    z = -10.0                                       # table top 10 mm below the ball centre
    # holder from a = 30, r = 20, unbounded: blocked iff 30 cos(th) - 20 sin(th) <= -10 (the
    # ball, cutter and shank never reach 10 mm below c)
    theta_star = math.degrees(math.acos(-10 / math.hypot(30, 20)) - math.atan2(20, 30))
    assert theta_star == pytest.approx(72.41, abs=0.01)
    ths = np.arange(0.0, 90.0, 0.25)
    free = fixture_collision_free(c, np.array([_tilt(th, 33.0) for th in ths]), tool,
                                  [TableFixture(c[0, 2] + z)])[0]
    np.testing.assert_array_equal(free, ths < theta_star)
    # pointing down with an unbounded holder always hits; horizontal: lowest point c_z - r
    axes = np.array([[0, 0, -1.0], _tilt(95.0), [1.0, 0, 0]])
    assert not fixture_collision_free(c, axes, tool, [TableFixture(-1000.0)])[0, :2].any()
    assert fixture_collision_free(c, axes[2:], tool, [TableFixture(3.0 - 20.0 - 1e-6)])[0, 0]
    assert not fixture_collision_free(c, axes[2:], tool, [TableFixture(3.0 - 20.0 + 1e-6)])[0, 0]


def test_touching_counts_as_collision():
    tool = ball_tool(3.0, flute_length_mm=10.0)                      # ball + cutter to a = 7
    up = np.array([[0, 0, 1.0]])
    c = np.array([[0.0, 0.0, 3.0]])
    for fx in ([TableFixture(0.0)], [BoxFixture((-5, -5, -5), (5, 5, 0))],
               [BoxFixture((3, -5, -5), (8, 5, 20))]):              # ball/cutter side touch x = 3
        assert not fixture_collision_free(c, up, tool, fx)[0, 0]
        assert not brute_force_fixture_collision_free(c, up, tool, fx)[0, 0]
    for fx in ([TableFixture(-1e-3)], [BoxFixture((-5, -5, -5), (5, 5, -1e-3))],
               [BoxFixture((3 + 1e-3, -5, -5), (8, 5, 20))]):
        assert fixture_collision_free(c, up, tool, fx)[0, 0]
        assert brute_force_fixture_collision_free(c, up, tool, fx)[0, 0]


# ----------------------------------------------------------------------------------------------
# known answers: the limiting tilt towards a clamp

# Tool: ball R 3 at c, cutter + shank r 3 to a = 30, holder r 20 from a = 30 (unbounded). In the
# plane of the tilt a long clamp's top inner edge K lies d = 40 mm beside and h = 20 mm above c.
# Tilting by theta towards it, the holder's side line (distance 20 from the axis) reaches K when
# d cos(theta) - h sin(theta) = 20: theta* = 36.87 deg (sin 0.6, cos 0.8); K is then at a = 40 on
# the axis, above the holder face, and no other part of the tool is within reach of the clamp.
CLAMP_TOOL = ball_tool(3.0, flute_length_mm=15.0, stickout_mm=33.0, holder=[(20.0, None, None)])
THETA_STAR = math.degrees(math.asin(0.6))


@pytest.mark.parametrize("turn_deg", [0.0, 30.0, 117.0])
def test_clamp_blocks_known_tilt_band(turn_deg):
    c0 = np.array([0.0, 0.0, 3.0])                      # ball centre over the flat part top z = 0
    ca, sa = math.cos(math.radians(turn_deg)), math.sin(math.radians(turn_deg))
    Rz = np.array([[ca, -sa, 0], [sa, ca, 0], [0, 0, 1.0]])
    # clamp: x 40..80 from the centre, z from the part top (c_z - 3) to c_z + 20, long in y;
    # the whole scene turned by turn_deg about the vertical through c (a rotated box)
    lo, hi = np.array([40.0, -100.0, -3.0]), np.array([80.0, 100.0, 20.0])
    mid = c0 + Rz @ ((lo + hi) / 2)
    clamp = BoxFixture(mid - (hi - lo) / 2, mid + (hi - lo) / 2, rotation=Rz, name="clamp")
    ths = np.arange(0.0, 85.0, 0.5)
    axes = np.array([Rz @ _tilt(th) for th in ths])
    free = fixture_collision_free(c0[None], axes, CLAMP_TOOL, [clamp, TableFixture(-50.0)])[0]
    np.testing.assert_array_equal(free, ths < THETA_STAR)
    fine = np.array([Rz @ _tilt(THETA_STAR - 0.01), Rz @ _tilt(THETA_STAR + 0.01)])
    np.testing.assert_array_equal(fixture_collision_free(c0[None], fine, CLAMP_TOOL, [clamp])[0], [True, False])
    # tilting away from the clamp or sideways along it never reaches it
    away = np.array([Rz @ _tilt(th, 180.0) for th in ths])
    assert fixture_collision_free(c0[None], away, CLAMP_TOOL, [clamp]).all()


def test_bar_blocks_known_tilt():
    """A horizontal round bar (cylinder along y) 50 mm beside and 25 mm above c, radius 5: the
    holder side touches it when 50 cos(theta) - 25 sin(theta) = 20 + 5, theta* = 36.87 deg."""
    c0 = np.array([[0.0, 0.0, 3.0]])
    bar = CylinderFixture((50.0, -100.0, 28.0), (0, 1, 0), 5.0, 200.0, name="bar")
    ths = np.arange(0.0, 60.0, 0.5)
    free = fixture_collision_free(c0, np.array([_tilt(th) for th in ths]), CLAMP_TOOL, [bar])[0]
    np.testing.assert_array_equal(free, ths < THETA_STAR)
    fine = np.array([_tilt(THETA_STAR - 0.01), _tilt(THETA_STAR + 0.01)])
    np.testing.assert_array_equal(fixture_collision_free(c0, fine, CLAMP_TOOL, [bar])[0], [True, False])
    np.testing.assert_array_equal(brute_force_fixture_collision_free(c0, fine, CLAMP_TOOL, [bar])[0],
                                  [True, False])


# ----------------------------------------------------------------------------------------------
# meshes

def test_mesh_box_equals_box_fixture():
    rng = np.random.default_rng(11)
    m = o3d.geometry.TriangleMesh.create_box(20.0, 12.0, 8.0)
    mesh = _mesh(m, solid=True, shift=(-10, -6, -8))
    box = BoxFixture((-10, -6, -8), (10, 6, 0))
    centres = rng.uniform((-20, -15, 0), (20, 15, 12), (60, 3))
    axes = np.array([_tilt(th, ph) for th, ph in rng.uniform((0, 0), (90, 360), (20, 2))])
    tool = TOOLS["short"]
    np.testing.assert_array_equal(fixture_collision_free(centres, axes, tool, [mesh]),
                                  fixture_collision_free(centres, axes, tool, [box]))


def test_solid_mesh_interior():
    """A tool wholly inside a closed mesh touches no triangle: only a solid mesh blocks it."""
    m = o3d.geometry.TriangleMesh.create_box(100.0, 100.0, 100.0)
    c = np.array([[50.0, 50.0, 30.0]])
    up = np.array([[0, 0, 1.0]])
    tool = ball_tool(2.0, flute_length_mm=10.0, holder=[(4.0, 10.0, None)])     # top at a = 18
    assert not fixture_collision_free(c, up, tool, [_mesh(m, solid=True)])[0, 0]
    assert fixture_collision_free(c, up, tool, [_mesh(m, solid=False)])[0, 0]
    assert not brute_force_fixture_collision_free(c, up, tool, [_mesh(m, solid=True)])[0, 0]
    # a part of the tool detached from the ball (a gap in the stack) inside the solid
    gap = ToolAssembly(2.0, (Segment(0.0, 3.0, 2.0, "cutter"), Segment(60.0, 70.0, 4.0, "holder")), 80.0)
    below = np.array([[50.0, 50.0, -40.0]])                  # ball and cutter under the mesh
    assert not fixture_collision_free(below, up, gap, [_mesh(m, solid=True)])[0, 0]
    assert not brute_force_fixture_collision_free(below, up, gap, [_mesh(m, solid=True)])[0, 0]
    assert fixture_collision_free(below, up, gap, [_mesh(m, solid=False)])[0, 0]
    with pytest.raises(ParameterError):
        MeshFixture(np.asarray(m.vertices), np.asarray(m.triangles)[:-1], solid=True)


@pytest.mark.parametrize("ext", ["stl", "obj", "ply"])
def test_load_mesh_round_trip(tmp_path, ext):
    m = o3d.geometry.TriangleMesh.create_box(2.0, 3.0, 4.0)
    m.compute_triangle_normals()
    path = tmp_path / f"jaw.{ext}"
    assert o3d.io.write_triangle_mesh(str(path), m)
    fx = load_mesh(path)
    assert fx.kind == "mesh" and fx.name == "jaw" and fx.solid
    assert fx.triangles.shape == (12, 3)
    got = np.unique(np.round(fx.vertices, 9), axis=0)
    np.testing.assert_allclose(got, np.unique(np.asarray(m.vertices), axis=0))
    inch = load_mesh(path, units=25.4, name="jaw in", solid=False)
    np.testing.assert_allclose(inch.vertices.max(axis=0), [50.8, 76.2, 101.6])
    assert inch.name == "jaw in" and not inch.solid


def test_load_mesh_errors(tmp_path):
    with pytest.raises(InputError) as e:
        load_mesh(tmp_path / "missing.stl")
    assert e.value.code == "bad_fixture"
    (tmp_path / "jaw.step").write_text("ISO-10303-21;")
    with pytest.raises(InputError, match="unknown format"):
        load_mesh(tmp_path / "jaw.step")
    (tmp_path / "junk.stl").write_text("hello")
    with pytest.raises(InputError, match="no triangles"):
        load_mesh(tmp_path / "junk.stl")
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.random.default_rng(0).random((10, 3))))
    o3d.io.write_point_cloud(str(tmp_path / "cloud.ply"), pc)
    with pytest.raises(InputError, match="no triangles"):
        load_mesh(tmp_path / "cloud.ply")
    (tmp_path / "nan.obj").write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="non-finite"):
        load_mesh(tmp_path / "nan.obj")
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert not load_mesh(tmp_path / "tri.obj").solid
    with pytest.raises(InputError, match="not closed"):
        load_mesh(tmp_path / "tri.obj", solid=True)
    with pytest.raises(ParameterError):
        load_mesh(tmp_path / "tri.obj", units=0)


# ----------------------------------------------------------------------------------------------
# parameters

def test_bad_parameters():
    tool = TOOLS["short"]
    box = BoxFixture((0, 0, 0), (1, 1, 1))
    c, a = np.zeros((2, 3)), np.array([[0, 0, 1.0]])
    with pytest.raises(ParameterError):
        fixture_collision_free(np.zeros((2, 2)), a, tool, [box])
    with pytest.raises(ParameterError):
        fixture_collision_free(c, np.zeros((1, 4)), tool, [box])
    with pytest.raises(ParameterError):
        fixture_collision_free(c, np.array([[0, 0, 2.0]]), tool, [box])          # not unit
    with pytest.raises(ParameterError):
        fixture_collision_free(np.array([[np.nan, 0, 0]]), a, tool, [box])
    with pytest.raises(ParameterError):
        fixture_collision_free(c, a, tool, [box], candidates=np.ones((1, 1), bool))
    with pytest.raises(ParameterError):
        fixture_collision_free(c, a, tool, ["vise"])
    with pytest.raises(ParameterError):
        brute_force_fixture_collision_free(c, a, "tool", [box])
    with pytest.raises(ParameterError):
        BoxFixture((0, 0, 0), (1, -1, 1))
    with pytest.raises(ParameterError):
        BoxFixture((0, 0), (1, 1))
    with pytest.raises(ParameterError):
        BoxFixture((0, 0, 0), (1, 1, 1), rotation=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ParameterError):
        BoxFixture((0, 0, 0), (1, 1, 1), rotation=np.ones((3, 3)))
    with pytest.raises(ParameterError):
        CylinderFixture((0, 0, 0), (0, 0, 0), 1.0, 1.0)
    with pytest.raises(ParameterError):
        CylinderFixture((0, 0, 0), (0, 0, 1), -1.0, 1.0)
    with pytest.raises(ParameterError):
        CylinderFixture((0, 0, 0), (0, 0, 1), 1.0, float("inf"))
    with pytest.raises(ParameterError):
        MeshFixture(np.zeros((3, 2)), np.array([[0, 1, 2]]))
    with pytest.raises(ParameterError):
        MeshFixture(np.eye(3), np.array([[0, 1, 3]]))
    with pytest.raises(ParameterError):
        MeshFixture(np.eye(3), np.zeros((0, 3), int))
    with pytest.raises(ParameterError):
        MeshFixture(np.eye(3), np.array([[0.5, 1, 2]]))
    with pytest.raises(ParameterError):
        TableFixture(float("nan"))
    # normalised and reported
    cyl = CylinderFixture((0, 0, 0), (0, 0, 5), 1.0, 2.0)
    assert cyl.axis == (0.0, 0.0, 1.0) and cyl.kind == "cylinder"
    assert box.kind == "box" and TableFixture(0).kind == "table"
