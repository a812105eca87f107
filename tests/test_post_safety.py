"""Safety of the posted programs (issue 16, items 4 and 5): approach heights from arcs, arcs of a
large radius, the order of the tilted plane and the spindle, and the rotary axes' home at the end.

* The safe height counts the top of an arc's circle only where the arc passes over it
  (planning.post.arcs.safe_height_mm): a near-straight arc of metres' radius hanging from a centre
  far above is highest at its end points; a half circle over the top counts its top. The
  whole-array function equals the per-arc reference, and both bound a dense sampling of the arcs.
* No arc of a radius beyond the limit: fit_arcs fits none (the stretch stays gouge-checked straight
  moves) and the posts print any such arc of a toolpath as G1 chords within the chord tolerance
  (one G1 where its sagitta is within it); the whole-array posts still print what the per-move
  reference prints.
* ISO: per operation the tool change, then G68.2 and G53.1, then the spindle (M3); G69 before the
  rotary axes return to 0, then M30. Both dialects end with Z at the top and the rotary axes at 0,
  which the simulation's reader, LinuxCNC's rs274 and the test reader all read, with no travel
  excursion in the final rotary move.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from gcode_reader import read_program as gcode_read

from planning.errors import ParameterError
from planning.orientations.kinematics import (
    available_profiles,
    load_profile,
    machine_visibility,
)
from planning.post import Operation, PostOptions, iso_program, linuxcnc_program
from planning.post.arcs import _reference_safe_height_mm, safe_height_mm
from planning.simulate.motion import ToolShape
from planning.simulate.program import check_travel
from planning.simulate.program import read_program as sim_read_program
from planning.simulate.rs274 import INSTALL_HINT, rs274_available, run_rs274
from planning.toolpath.frames import AreaFrame, area_frame
from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    FEED,
    PLANE_AXES,
    PLANE_ZX,
    RAPID,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
    Toolpath,
    arc_sweep_rad,
)
from planning.toolpath.reduce import fit_arcs
from schemas.params import PostParams, parse_config

IDENT = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))


# ----------------------------------------------------------------------------------------------
# helpers


def path(points, kinds, centres=None, planes=None, uses=None, tip_offset=0.0) -> Toolpath:
    """A Toolpath from lists (centres / planes only on the arcs)."""
    n = len(points)
    cen = np.full((n, 3), np.nan)
    pl = np.zeros(n, np.int8)
    for i, k in enumerate(kinds):
        if k in (ARC_CW, ARC_CCW):
            cen[i] = centres[i]
            pl[i] = planes[i]
    if uses is None:
        uses = [USE_RAPID if k == RAPID else USE_CUT for k in kinds]
    return Toolpath(np.asarray(points, float), np.asarray(kinds, np.int8), cen, pl, np.asarray(uses, np.int8),
                    tip_offset_mm=tip_offset)


def arc_between(plane: int, start, end, radius: float, centre_side: int):
    """``(centre, ccw)`` of the MINOR arc of ``radius`` from ``start`` to ``end`` (same coordinate
    along the plane's normal) whose centre lies on side ``centre_side`` (+1: towards +z in the plane,
    -1: towards -z) of the chord."""
    a, b, _ = PLANE_AXES[plane]
    s, e = np.asarray(start, float), np.asarray(end, float)
    mid = 0.5 * (s + e)
    du, dv = e[a] - s[a], e[b] - s[b]
    L = math.hypot(du, dv)
    nu, nv = -dv / L, du / L                              # left normal of the chord in (a, b)
    h = math.sqrt(radius * radius - 0.25 * L * L)
    normal3 = np.zeros(3)
    normal3[a], normal3[b] = nu, nv
    if np.sign(normal3[2]) != centre_side:
        nu, nv = -nu, -nv
    c = mid.copy()
    c[a] += h * nu
    c[b] += h * nv
    for ccw in (True, False):
        if abs(arc_sweep_rad(s, e, c, plane, ccw)[1]) < math.pi:
            return c, ccw
    raise AssertionError("no minor arc")


def dense_top(s, e, c, plane: int, ccw: bool, n: int = 20001) -> tuple[float, float]:
    """``(highest z, bound on the sampling error)`` of an arc sampled at ``n`` equal angle steps
    (radius and normal coordinate interpolated from start to end, as the posts' chords)."""
    a, b, nn = PLANE_AXES[plane]
    t0, sw, r0 = arc_sweep_rad(s, e, c, plane, ccw)
    r1 = math.hypot(e[a] - c[a], e[b] - c[b])
    t = np.linspace(0.0, 1.0, n)
    q = np.empty((n, 3))
    q[:, a] = c[a] + (r0 + (r1 - r0) * t) * np.cos(t0 + sw * t)
    q[:, b] = c[b] + (r0 + (r1 - r0) * t) * np.sin(t0 + sw * t)
    q[:, nn] = s[nn] + (e[nn] - s[nn]) * t
    return float(q[:, 2].max()), max(r0, r1) * (1 - math.cos(abs(sw) / (n - 1) / 2)) + 1e-9


def op_of(tp: Toolpath, number: int = 1, name: str = "finishing") -> Operation:
    return Operation(name, tp, number, 6.0, "ball", 12000, 1500.0, 400.0, gauge_length_mm=100.0 + number)


def blocks_of(text: str) -> list[str]:
    """The program's blocks without comments, ``%`` and N numbers."""
    out = []
    for raw in text.splitlines():
        s = raw.split("(")[0].strip()
        if not s or s == "%":
            continue
        words = [w for w in s.split() if not w.startswith("N")]
        if words:
            out.append(" ".join(words))
    return out


def index_of(blocks: list[str], pred) -> list[int]:
    return [i for i, b in enumerate(blocks) if pred(b.split())]


def reference_text(post, *args, **kw) -> str:
    """The post's text with every operation printed by the per-move MotionEmitter."""
    from planning.post import motion

    motion._REFERENCE_MOTION = True
    try:
        return post(*args, **kw)
    finally:
        motion._REFERENCE_MOTION = False


# ----------------------------------------------------------------------------------------------
# safe heights


@pytest.mark.parametrize("plane", [18, 19])
@pytest.mark.parametrize("radius", [2500.0, 5000.0, 9000.0])
def test_a_near_straight_arc_of_metres_radius_is_highest_at_its_end_points(plane, radius):
    """The defect: the top of the circle of a near-straight arc hanging from a centre metres above
    put the approach at Z 1,250-5,770 mm. The arc sags below its chord; its end points are its
    highest points, so the safe height is max(safe_z, end points)."""
    a, b, n = PLANE_AXES[plane]
    horiz = a if a != 2 else b                            # the in-plane horizontal axis
    for z_end in ((-3.0, -3.0), (-3.0, -1.0)):
        s = np.zeros(3)
        e = np.zeros(3)
        s[horiz], e[horiz] = -20.0, 20.0
        s[2], e[2] = z_end
        s[n] = e[n] = 4.0
        c, ccw = arc_between(plane, s, e, radius, +1)
        assert c[2] > radius / 2                          # the centre metres above the part
        tp = path([s + [0, 0, 8.0], s, e, e + [0, 0, 8.0]], [RAPID, FEED, ARC_CCW if ccw else ARC_CW, FEED],
                  {2: c}, {2: plane}, [USE_RAPID, USE_PLUNGE, USE_CUT, USE_RETRACT], tip_offset=1.5)
        op = op_of(tp)
        tips = tp.tip_mm()
        for z_safe in (0.5, 10.0):
            o = PostOptions(safe_z_mm=z_safe)
            want = max(z_safe, float(tips[:, 2].max()))
            assert safe_height_mm(op, o) == _reference_safe_height_mm(op, o) == want
            top, err = dense_top(s, e, c, plane, ccw)
            assert top - tp.tip_offset_mm <= want + err
        # the program's approach and final retract stay at the tips' height, not metres above
        got = gcode_read(iso_program([op], IDENT, tool_axis=[0, 0, 1], options=PostOptions(safe_z_mm=10.0)))
        assert max(m.end[2] for m in got.moves) <= 10.0 + 1e-9


@pytest.mark.parametrize("plane", [18, 19])
def test_a_half_circle_over_the_top_counts_its_top(plane):
    """A half circle from one side over the top to the other (either direction, centre below):
    the safe height is the circle's top, as dense sampling finds; the same half circle run
    under its centre (through the bottom) counts its end points only."""
    a, b, n = PLANE_AXES[plane]
    horiz = a if a != 2 else b
    r = 20.0
    c = np.zeros(3)
    c[2] = -10.0
    c[n] = 2.0
    s, e = c.copy(), c.copy()
    s[horiz] -= r
    e[horiz] += r
    seen = []
    for over in (True, False):
        for ccw in (True, False):
            t0, sw, _ = arc_sweep_rad(s, e, c, plane, ccw)
            mid = t0 + sw / 2
            mid_z = c[2] + r * (math.cos(mid) if a == 2 else math.sin(mid))
            if (mid_z > c[2]) != over:
                continue
            seen.append(over)
            tp = path([s + [0, 0, 1.0], s, e], [RAPID, FEED, ARC_CCW if ccw else ARC_CW], {2: c}, {2: plane},
                      tip_offset=0.5)
            op = op_of(tp)
            o = PostOptions(safe_z_mm=0.1)
            got = safe_height_mm(op, o)
            assert got == _reference_safe_height_mm(op, o)
            top, err = dense_top(s, e, c, plane, ccw)
            if over:
                assert got == pytest.approx(c[2] + r - 0.5, abs=1e-12)
                assert top - 0.5 <= got + 1e-9 and got - (top - 0.5) <= err
            else:
                assert got == max(0.1, float(tp.tip_mm()[:, 2].max()))
    assert sorted(seen) == [False, True]                  # one direction over the top, the other under


def random_arc_path(seed: int, n_arcs: int = 150, big: bool = True) -> Toolpath:
    """Chained arcs in the three planes (helices among them), radii from 0.1 mm to 10 m (``big``),
    every sweep from tiny to nearly 360 degrees, both directions; some lines and rapids between."""
    rng = np.random.default_rng(seed)
    pts, kinds, cen, planes = [rng.uniform(-50, 50, 3)], [RAPID], {}, {}
    cur = pts[0].copy()
    for _ in range(n_arcs):
        if rng.uniform() < 0.2:
            cur = cur + rng.normal(scale=5.0, size=3)
            pts.append(cur.copy())
            kinds.append(FEED if rng.uniform() < 0.7 else RAPID)
            continue
        p = int(rng.choice([17, 18, 19]))
        a, b, nn = PLANE_AXES[p]
        rad = 10 ** rng.uniform(-1, 4 if big else 2)
        sweep = rng.choice([-1, 1]) * rng.choice([rng.uniform(1e-4, 0.05), rng.uniform(0.05, 3.0),
                                                   rng.uniform(3.0, 2 * math.pi - 1e-3)])
        phi0 = rng.uniform(-math.pi, math.pi)
        c = cur.copy()
        c[a] -= rad * math.cos(phi0)
        c[b] -= rad * math.sin(phi0)
        end = cur.copy()
        end[a] = c[a] + rad * math.cos(phi0 + sweep)
        end[b] = c[b] + rad * math.sin(phi0 + sweep)
        if rng.uniform() < 0.3:
            end[nn] += rng.uniform(-2, 2)                 # a helix
        cen[len(pts)], planes[len(pts)] = c, p
        pts.append(end)
        kinds.append(ARC_CCW if sweep > 0 else ARC_CW)
        cur = end
    return path(pts, kinds, cen, planes, tip_offset=float(rng.uniform(0, 3)))


@pytest.mark.parametrize("seed", range(6))
def test_safe_height_equals_the_reference_and_bounds_dense_sampling(seed):
    tp = random_arc_path(seed)
    op = op_of(tp)
    arcs = np.flatnonzero(np.isin(tp.kind, (ARC_CW, ARC_CCW)))
    worst = float(tp.tip_mm()[:, 2].max())
    for i in arcs:
        ccw = bool(tp.kind[i] == ARC_CCW)
        top, err = dense_top(tp.xyz_mm[i - 1], tp.xyz_mm[i], tp.centre_mm[i], int(tp.plane[i]), ccw, n=4001)
        worst = max(worst, top - tp.tip_offset_mm - err)
    for z in (0.01, 10.0, 1e3, 1e5):
        o = PostOptions(safe_z_mm=z)
        got = safe_height_mm(op, o)
        assert got == _reference_safe_height_mm(op, o)
        assert got >= max(z, worst) - 1e-9
    # the height is never above the highest point of any arc's circle that the arc sweeps: every arc
    # alone gives at most its circle's top and at least its end points
    for i in arcs[:40]:
        one = path(tp.xyz_mm[i - 1:i + 1], [FEED, int(tp.kind[i])], {1: tp.centre_mm[i]}, {1: int(tp.plane[i])},
                   tip_offset=tp.tip_offset_mm)
        o = PostOptions(safe_z_mm=1e-3)
        got = safe_height_mm(op_of(one), o)
        top, err = dense_top(one.xyz_mm[0], one.xyz_mm[1], one.centre_mm[1], int(one.plane[1]),
                             bool(one.kind[1] == ARC_CCW))
        a, b, _ = PLANE_AXES[int(one.plane[1])]
        dr = abs(math.hypot(*(one.xyz_mm[0, [a, b]] - one.centre_mm[1, [a, b]]))
                 - math.hypot(*(one.xyz_mm[1, [a, b]] - one.centre_mm[1, [a, b]])))
        assert top - one.tip_offset_mm - err - dr <= max(got, 1e-3) + 1e-9     # a helix may differ by dr
        assert got <= max(1e-3, top - one.tip_offset_mm + err + dr) + 1e-9


# ----------------------------------------------------------------------------------------------
# the arc radius limit


def test_post_params_carry_the_arc_radius_limit():
    assert PostParams().max_arc_radius_mm == 500.0
    assert PostOptions().max_arc_radius_mm == 500.0
    assert "mm" in PostParams.model_fields["max_arc_radius_mm"].description
    assert parse_config({"post": {"max_arc_radius_mm": 50}}).post.max_arc_radius_mm == 50.0
    with pytest.raises(ParameterError):
        parse_config({"post": {"max_arc_radius_mm": 0}})
    for bad in (0.0, -1.0, float("nan"), float("inf"), "500"):
        with pytest.raises(ParameterError, match="max_arc_radius_mm"):
            iso_program([op_of(random_arc_path(0, 5))], IDENT, tool_axis=[0, 0, 1],
                        options=PostOptions(max_arc_radius_mm=bad))


def test_programs_pass_the_limit_to_the_posts(monkeypatch):
    """planning.post.programs builds PostOptions with post.max_arc_radius_mm."""
    from types import SimpleNamespace

    from planning.post import programs

    seen = []

    def fake(ops, frame, **kw):
        seen.append(kw["options"].max_arc_radius_mm)
        return ""

    monkeypatch.setitem(programs._POSTS, "iso", fake)
    monkeypatch.setitem(programs._POSTS, "linuxcnc", fake)
    monkeypatch.setattr(programs, "neutral_json_arrays", lambda *a, **k: ("{}", None))
    config = parse_config({"post": {"max_arc_radius_mm": 123.5}})
    tp = random_arc_path(1, 5, big=False)
    info = SimpleNamespace(n_passes=1, n_regions=1, step_over_mm=0.5, toolpath=tp, n_retracts=0)
    ap = SimpleNamespace(area=0, roughing=None, finishing=tp, finishing_info=info, frame=IDENT, safe_z_mm=20.0,
                         n_arcs=0, min_clearance_mm=3.0, gouge_free=True, holder_collisions=0, fixture_collisions=0,
                         seconds={})
    files, _ = programs.post_areas([ap], setups_axes=[np.array([0, 0, 1.0])], rotary_deg=[(0.0, 0.0)],
                                   profile="compact_trunnion_bc", placement_mm=[0, 0, 60], gauge_length_mm=100.0,
                                   config=config)
    assert seen == [123.5, 123.5] and sorted(files) == ["area_0.iso.nc", "area_0.linuxcnc.nc", "area_0.moves.json.gz",
                                                        "area_0.moves.npz"]


def cylinder_path(Rs: float, R: float = 3.0, half: float = 30.0, step: float = 0.5):
    """Ball centres on a convex cylinder of radius ``Rs`` about the Y axis (top at z 0), one pass
    along X at y = 0 (plunge, cut, retract), and the cloud (points on the cylinder)."""
    xs = np.arange(-half, half + 1e-9, step)
    zc = -Rs
    cl = np.column_stack([xs, np.zeros_like(xs), zc + np.sqrt((Rs + R) ** 2 - xs ** 2)])
    gx, gy = np.meshgrid(np.arange(-half - 5, half + 5, 0.25), np.arange(-6, 6.01, 0.25), indexing="ij")
    pts = np.column_stack([gx.ravel(), gy.ravel(), zc + np.sqrt(Rs ** 2 - gx.ravel() ** 2)])
    xyz = np.vstack([cl[:1] + [0, 0, 10], cl, cl[-1:] + [0, 0, 10]])
    use = np.r_[USE_RAPID, USE_PLUNGE, [USE_CUT] * (len(cl) - 1), USE_RETRACT].astype(np.int8)
    kind = np.where(use == USE_RAPID, RAPID, FEED).astype(np.int8)
    tp = Toolpath(xyz, kind, np.full(xyz.shape, np.nan), np.zeros(len(xyz), np.int8), use, tip_offset_mm=R)
    return tp, cl, pts


def _arc_radii(tp: Toolpath) -> np.ndarray:
    arcs = np.flatnonzero(np.isin(tp.kind, (ARC_CW, ARC_CCW)))
    return np.array([arc_sweep_rad(tp.xyz_mm[i - 1], tp.xyz_mm[i], tp.centre_mm[i], int(tp.plane[i]),
                                   bool(tp.kind[i] == ARC_CCW))[2] for i in arcs])


def _deviation(cl: np.ndarray, tp: Toolpath) -> float:
    """Largest distance of the CL points from the straight cutting moves of ``tp`` (no arcs)."""
    best = np.full(len(cl), np.inf)
    for i in np.flatnonzero((tp.kind == FEED) & (tp.use == USE_CUT)):
        s, d = tp.xyz_mm[i - 1], tp.xyz_mm[i] - tp.xyz_mm[i - 1]
        u = np.clip((cl - s) @ d / (d @ d), 0, 1)
        best = np.minimum(best, np.linalg.norm(cl - (s + u[:, None] * d), axis=1))
    return float(best.max())


def test_fit_arcs_fits_no_arc_beyond_the_radius_limit():
    R, tol = 3.0, 0.005
    tp, cl, pts = cylinder_path(2000.0, R)
    wide = fit_arcs(tp, pts, R, tol_mm=tol, max_radius_mm=1e4)
    assert _arc_radii(wide).size and _arc_radii(wide).max() > 1000.0      # what the old 10 m limit let through
    for new in (fit_arcs(tp, pts, R, tol_mm=tol), fit_arcs(tp, pts, R, tol_mm=tol, max_radius_mm=500.0)):
        assert not np.isin(new.kind, (ARC_CW, ARC_CCW)).any()
        assert new.n_moves < tp.n_moves                   # the stretch is reduced to fewer straight moves
        assert _deviation(cl, new) <= tol + 1e-9
    # an arc within the limit is still fitted by default, and the limit is what decides
    tp2, _, pts2 = cylinder_path(100.0, R)
    r2 = _arc_radii(fit_arcs(tp2, pts2, R, tol_mm=tol))
    assert r2.size and np.all(r2 <= 500.0) and r2.max() == pytest.approx(103.0, abs=0.05)
    assert not _arc_radii(fit_arcs(tp2, pts2, R, tol_mm=tol, max_radius_mm=50.0)).size


@pytest.mark.parametrize("dialect", ["iso", "linuxcnc"])
def test_posts_write_arcs_beyond_the_limit_as_chords(dialect):
    """A G18 arc of radius 2 m over 40 mm becomes G1 chords within the chord tolerance; one of
    4 mm (sagitta 0.001 mm) a single G1; an arc of 20 mm stays G2/G3; with a limit of 10 m the big
    arcs stay arcs."""
    y = 2.0
    s1, e1 = np.array([-20.0, y, -5.0]), np.array([20.0, y, -5.0])
    c1, ccw1 = arc_between(PLANE_ZX, s1, e1, 2000.0, -1)
    e2 = e1 + [4.0, 0, 0]
    c2, ccw2 = arc_between(PLANE_ZX, e1, e2, 2000.0, -1)
    e3 = e2 + [10.0, 0, 0]
    c3, ccw3 = arc_between(PLANE_ZX, e2, e3, 20.0, -1)
    k = [RAPID, FEED] + [ARC_CCW if w else ARC_CW for w in (ccw1, ccw2, ccw3)] + [FEED]
    tp = path([s1 + [0, 0, 5], s1, e1, e2, e3, e3 + [0, 0, 5]], k, {2: c1, 3: c2, 4: c3}, {2: 18, 3: 18, 4: 18},
              [USE_RAPID, USE_PLUNGE, USE_CUT, USE_CUT, USE_CUT, USE_RETRACT])
    op = op_of(tp)
    tol = 0.002
    _, sw, r = arc_sweep_rad(s1, e1, c1, PLANE_ZX, ccw1)
    m_want = math.ceil(abs(sw) / (2 * math.acos(1 - tol / r)) - 1e-12)
    assert m_want > 1

    def post(o):
        if dialect == "iso":
            return iso_program([op], IDENT, tool_axis=[0, 0, 1], options=o)
        return linuxcnc_program([op], IDENT, tool_axis=[0, 0, 1], rotary_deg=[0.0, 0.0], profile="compact_trunnion_bc",
                                placement_mm=[0, 0, 0], options=o)

    for o in (PostOptions(), PostOptions(line_numbers=True, decimals=5)):
        text = post(o)
        assert text == reference_text(post, o)
        got = gcode_read(text, None if dialect == "iso" else _machine_bc())
        arcs = [m for m in got.moves if m.kind == "arc"]
        assert len(arcs) == 1 and arcs[0].radius_start == pytest.approx(20.0, abs=1e-3)
        feeds = [m for m in got.moves if m.kind == "feed"]
        # plunge, the chords of arc 1 (m_want), one G1 for arc 2, the retract
        assert len(feeds) == 1 + m_want + 1 + 1
        chords = np.array([m.end for m in feeds[1:1 + m_want]])
        a, b, _ = PLANE_AXES[PLANE_ZX]
        rad = np.hypot(chords[:, a] - c1[a], chords[:, b] - c1[b])
        assert np.abs(rad - 2000.0).max() < 10.0 ** -o.decimals                 # every chord point on the arc
        prev = np.vstack([s1, chords[:-1]])
        half = np.linalg.norm(chords - prev, axis=1) / 2
        assert np.all(2000.0 - np.sqrt(2000.0 ** 2 - half ** 2) <= tol + 1e-6)  # sagitta of each chord
        assert np.allclose(feeds[1 + m_want].end, e2, atol=10.0 ** -o.decimals)
        assert np.allclose(chords[-1], e1, atol=10.0 ** -o.decimals)
    text = post(PostOptions(max_arc_radius_mm=1e4))
    got = gcode_read(text, None if dialect == "iso" else _machine_bc())
    assert sum(m.kind == "arc" for m in got.moves) == 3


def _machine_bc():
    from gcode_reader import Machine

    p = load_profile("compact_trunnion_bc")
    return Machine(kinematics=p.kinematics, placement_mm=(0.0, 0.0, 0.0), pivot_mm=tuple(p.pivot_mm),
                   head_pivot_length_mm=p.pivot_length_mm, gauge_length_mm={1: 101.0, 2: 102.0})


@pytest.mark.parametrize("limit", [0.5, 3.0, 40.0, 500.0])
def test_whole_array_posts_match_the_reference_with_the_radius_limit(limit):
    """Random arcs of 0.1 mm to 10 m radius (and arcs exactly at the limit): the whole-array posts
    linearise the same arcs as the per-move reference, byte for byte."""
    tp = random_arc_path(int(limit * 10), 120)
    # an arc whose radius is exactly the limit stays an arc
    s = tp.xyz_mm[-1]
    c = s - [limit, 0.0, 0.0]
    e = c + [0.0, limit, 0.0]
    tp = path(np.vstack([tp.xyz_mm, e]), list(tp.kind) + [ARC_CCW],
              {**{i: tp.centre_mm[i] for i in range(tp.n_moves)}, tp.n_moves: c},
              {**{i: int(tp.plane[i]) for i in range(tp.n_moves)}, tp.n_moves: 17},
              list(tp.use) + [USE_CUT], tip_offset=tp.tip_offset_mm)
    ops = [op_of(tp), op_of(random_arc_path(99, 60), 2, "roughing")]
    axis = np.array([0.3, 0.4, 0.866]) / np.linalg.norm([0.3, 0.4, 0.866])
    frame = area_frame(axis, np.random.default_rng(0).normal(size=(50, 3)) * 20)
    for o in (PostOptions(max_arc_radius_mm=limit), PostOptions(max_arc_radius_mm=limit, decimals=3,
                                                                  chord_tol_mm=0.01, line_numbers=True)):
        text = iso_program(ops, frame, tool_axis=axis, options=o)
        assert text == reference_text(iso_program, ops, frame, tool_axis=axis, options=o)
        got = gcode_read(text)
        radii = [m.radius_start for m in got.moves if m.kind == "arc"]
        assert max(radii) <= limit * (1 + 1e-6) + 10.0 ** -o.decimals
        for name in available_profiles():
            mv = machine_visibility(axis, name)
            if not mv.feasible[0]:
                continue
            kw = {"tool_axis": axis, "rotary_deg": mv.angles_deg[0], "profile": name, "placement_mm": [1.0, -2.0, 60.0],
                  "options": o, "gauge_length_mm": 100.0}
            assert linuxcnc_program(ops, frame, **kw) == reference_text(linuxcnc_program, ops, frame, **kw)


# ----------------------------------------------------------------------------------------------
# the order of the ISO blocks and the end of the programs


def machining_ops(seed: int) -> list[Operation]:
    """Roughing and finishing of small paths: rapids, plunges, lines, G18 / G19 / G17 arcs."""
    out = []
    for k, (name, number) in enumerate((("roughing", 2), ("finishing", 1))):
        rng = np.random.default_rng(seed * 10 + k)
        pts, kinds, uses, cen, pl = [], [], [], {}, {}
        cur = np.array([rng.uniform(-10, 10), rng.uniform(-10, 10), 3.0])
        pts.append(cur.copy()); kinds.append(RAPID); uses.append(USE_RAPID)
        cur[2] = -2.0
        pts.append(cur.copy()); kinds.append(FEED); uses.append(USE_PLUNGE)
        for p in (18, 19, 17):
            a, b, _ = PLANE_AXES[p]
            r = rng.uniform(3, 10)
            phi0 = rng.uniform(-math.pi, math.pi)
            sw = rng.choice([-1, 1]) * rng.uniform(0.3, 2.5)
            c = cur.copy()
            c[a] -= r * math.cos(phi0)
            c[b] -= r * math.sin(phi0)
            e = cur.copy()
            e[a] = c[a] + r * math.cos(phi0 + sw)
            e[b] = c[b] + r * math.sin(phi0 + sw)
            cen[len(pts)], pl[len(pts)] = c, p
            pts.append(e); kinds.append(ARC_CCW if sw > 0 else ARC_CW); uses.append(USE_CUT)
            cur = e.copy()
            cur[:2] += rng.uniform(-3, 3, 2)
            pts.append(cur.copy()); kinds.append(FEED); uses.append(USE_CUT)
        cur[2] = 3.0
        pts.append(cur.copy()); kinds.append(FEED); uses.append(USE_RETRACT)
        out.append(op_of(path(pts, kinds, cen, pl, uses, tip_offset=0.0 if k == 0 else 3.0), number, name))
    return out


def ending_cases():
    axes = [np.array(v) / np.linalg.norm(v) for v in ((0, 0, 1.0), (0.3, 0.4, 0.866), (0.6, -0.7, 0.38))]
    out = []
    for name in available_profiles():
        for t in axes:
            mv = machine_visibility(t, name)
            if mv.feasible[0]:
                out.append((name, t, mv.angles_deg[0]))
    return out


CASES = ending_cases()
TOOLS = {1: ToolShape(1, "ball", 3.0, 3.0, 12.0, (), 101.0), 2: ToolShape(2, "flat", 5.0, 0.0, 20.0, (), 102.0)}
PLACE = np.array([2.0, -3.0, 60.0])


def posted(case: int, **opts):
    name, t, ang = CASES[case]
    pts = np.random.default_rng(case).normal(size=(200, 3)) * [20.0, 15.0, 8.0] + [0.0, 0.0, 15.0]
    frame = area_frame(t, pts)
    ops = machining_ops(case)
    o = PostOptions(**opts)
    kw = {"tool_axis": t, "rotary_deg": ang, "profile": name, "placement_mm": PLACE, "options": o}
    return name, ang, {"iso": iso_program(ops, frame, **kw), "linuxcnc": linuxcnc_program(ops, frame, **kw)}, ops


@pytest.mark.parametrize("case", range(len(CASES)))
def test_iso_tilts_the_plane_before_the_spindle_starts_and_homes_the_rotary_axes_last(case):
    name, _, texts, ops = posted(case, line_numbers=case % 2 == 1)
    tilt, rot = load_profile(name).axis_names
    bl = blocks_of(texts["iso"])
    m6 = index_of(bl, lambda w: "M6" in w)
    g682 = index_of(bl, lambda w: "G68.2" in w)
    g531 = index_of(bl, lambda w: "G53.1" in w)
    m3 = index_of(bl, lambda w: "M3" in w)
    m8 = index_of(bl, lambda w: "M8" in w)
    g43 = index_of(bl, lambda w: "G43" in w)
    assert len(m6) == len(g682) == len(g531) == len(m3) == len(m8) == len(g43) == len(ops)
    for k in range(len(ops)):
        nxt = m6[k + 1] if k + 1 < len(ops) else len(bl)
        # tool change, the tilted plane (the table or head tilts, spindle stopped), spindle, coolant, approach
        assert m6[k] < g682[k] < g531[k] < m3[k] < m8[k] < g43[k] < nxt
        assert not any("M3" in bl[i].split() for i in range(m6[k], g531[k]))
    # the end: the last G69, Z home, M5, the rotary axes to their reference position (0), G90, M30
    g69 = index_of(bl, lambda w: "G69" in w)
    home = index_of(bl, lambda w: "G28" in w and f"{tilt}0." in w and f"{rot}0." in w)
    assert len(home) == 1 and bl[home[0]].split() == ["G91", "G28", f"{tilt}0.", f"{rot}0."]
    z_home = index_of(bl, lambda w: "G28" in w and "Z0." in w)
    m5 = index_of(bl, lambda w: "M5" in w)
    assert g69[-1] < z_home[-1] < m5[-1] < home[0]
    assert bl[home[0] + 1:] == ["G90", "M30"]
    assert "THE PROGRAM ENDS AT HOME" in texts["iso"] and "MACHINE ZERO WITH THE ROTARY AXES AT 0" in texts["iso"]
    assert texts["iso"].rstrip().splitlines()[-1] == "%"


@pytest.mark.parametrize("case", range(len(CASES)))
def test_both_dialects_end_with_z_at_the_top_and_the_rotary_axes_at_0(case):
    """The simulation's reader (and rs274 for LinuxCNC) read the new ending: the last moves turn
    the rotary axes to 0 with the controlled point standing at the top of the Z travel, no travel
    excursion; the test reader reads both programs too."""
    assert rs274_available(), INSTALL_HINT
    name, ang, texts, _ = posted(case, rotary_sign=(-1, 1) if case % 2 else (1, 1))
    prof = load_profile(name)
    tilt, rot = prof.axis_names
    lb = blocks_of(texts["linuxcnc"])
    assert lb[-2:] == [f"G53 G0 {tilt}0 {rot}0", "M30"]
    assert lb[-3] == "M5" and lb[-5] == "G53 G0 Z0"
    assert f"the program ends at home: G53 Z0, then G53 {tilt}0 {rot}0" in texts["linuxcnc"]
    got = {d: sim_read_program(x, dialect=d, program=d, area=0, profile=prof, placement_mm=PLACE, tools=TOOLS)
           for d, x in texts.items()}
    got["rs274"] = run_rs274(texts["linuxcnc"], program="rs274", area=0, profile=prof, placement_mm=PLACE,
                             tools=TOOLS)
    lines = {"iso": texts["iso"], "linuxcnc": texts["linuxcnc"], "rs274": texts["linuxcnc"]}
    z_top = prof.linear_limits_mm[2][1]
    for d, m in got.items():
        assert np.abs(m.rotary_deg[-1]).max() < 1e-9, d
        last = m.line[-1]
        ret = np.flatnonzero(m.line == last)
        assert lines[d].splitlines()[last - 1].split("(")[0].split()[-1] == f"{rot}0" + ("." if d == "iso" else "")
        before = ret[0] - 1
        # the controlled point stands at the top of the Z travel while the rotary axes turn home
        assert np.allclose(m.machine_mm[ret], m.machine_mm[before], atol=1e-6)
        assert m.machine_mm[ret, 2] == pytest.approx(z_top, abs=1e-6)
        assert np.abs(m.rotary_deg[before] - ang).max() < 1e-3
        assert not [t for t in check_travel(m, prof) if t["line"] == last]
        # the cutting moves are at the planned angles
        cut = m.kind == 1
        assert np.abs(m.rotary_deg[cut] - ang).max() < 1e-3
    io, it = np.flatnonzero(np.r_[got["linuxcnc"].line[1:] != got["linuxcnc"].line[:-1], True]), \
        np.flatnonzero(np.r_[got["rs274"].line[1:] != got["rs274"].line[:-1], True])
    assert np.array_equal(got["linuxcnc"].line[io], got["rs274"].line[it])
    diff = np.abs(got["linuxcnc"].machine_mm[io] - got["rs274"].machine_mm[it]).max(axis=1)
    # (an order-dependent failure of this comparison was seen in CI, machine Z 13-14 mm apart on some
    # lines, never alone: the message says where, to find its cause)
    bad = np.flatnonzero(diff >= 1e-3)
    assert bad.size == 0, (case, name, [(int(got["rs274"].line[it][b]),
                                        texts["linuxcnc"].splitlines()[int(got["rs274"].line[it][b]) - 1],
                                        got["linuxcnc"].machine_mm[io][b].round(4).tolist(),
                                        got["rs274"].machine_mm[it][b].round(4).tolist()) for b in bad[:5]],
                           f"{bad.size} of {diff.size} lines")
    assert np.abs(got["linuxcnc"].rotary_deg[io] - got["rs274"].rotary_deg[it]).max() < 1e-4
    # the independent test reader reads both
    assert gcode_read(texts["iso"]).ended
    from gcode_reader import Machine

    mach = Machine(kinematics=prof.kinematics, placement_mm=tuple(PLACE), pivot_mm=tuple(prof.pivot_mm),
                   head_pivot_length_mm=prof.pivot_length_mm, gauge_length_mm={1: 101.0, 2: 102.0},
                   flip_tilt=case % 2 == 1)
    assert gcode_read(texts["linuxcnc"], mach).ended


def test_iso_without_a_profile_says_the_rotary_axes_are_not_returned():
    ops = machining_ops(0)
    text = iso_program(ops, IDENT, tool_axis=[0, 0, 1])
    bl = blocks_of(text)
    assert bl[-1] == "M30" and not any(w[0] in "ABC" for b in bl for w in b.split())
    assert "(NO MACHINE PROFILE: RETURN THE ROTARY AXES TO 0 BEFORE THE NEXT PROGRAM)" in text
    assert gcode_read(text).ended


def test_the_readers_refuse_other_rotary_words_in_g28_and_g53():
    from planning.simulate.program import ProgramError

    prof = load_profile("compact_trunnion_bc")
    base = ["G21 G90 G94 G17 G40 G49 G80", "G91 G28 Z0.", "G90", "G54"]
    for bad, dialect in ((["G91 G28 A0. C0."], "iso"), (["G91 G28 B10. C0."], "iso"),
                         (["G0", "G53 A0 C0"], "linuxcnc")):
        with pytest.raises(ProgramError):
            sim_read_program("\n".join((base if dialect == "iso" else ["G21", "G54"]) + bad + ["M30"]),
                             dialect=dialect, program="x", area=0, profile=prof, placement_mm=PLACE, tools=TOOLS)
    m = sim_read_program("G21\nG54\nG53 G0 Z0\nT1 M6\nG0 B30. C45.\nG53 G0 B0 C0\nM30",
                         dialect="linuxcnc", program="x", area=0, profile=prof, placement_mm=PLACE, tools=TOOLS)
    assert np.abs(m.rotary_deg[-1]).max() == 0.0 and np.abs(m.rotary_deg).max() == pytest.approx(45.0)
