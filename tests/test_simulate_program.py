"""The program readers of the simulation (issue 15): planning.simulate.program reads the posted text as a
control would, planning.simulate.rs274 lets LinuxCNC's own interpreter read it.

Checked: both dialects of one area give the same tool tips and axes in the part frame; the reader
agrees with the plan's moves JSON (and with the planned tool paths of posted test operations, arcs
in every plane); rs274 and the reader agree move for move; hand-written programs give known
answers (Fanuc G68.2 Euler angles, a G2 quarter circle, a rotary repositioning on a circle about
the pivot, G53 to the top of the travel, a tip driven below the Z travel reported on its line).
rs274 is required: where it is missing the tests FAIL and say how to install it."""

from __future__ import annotations

import gzip
import json
import math

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from planning.inputs import samples
from planning.inputs.cloud import Cloud
from planning.orientations.kinematics import load_profile, machine_visibility
from planning.pipeline import run_plan
from planning.post import Operation, PostOptions, iso_program, linuxcnc_program
from planning.simulate.motion import FEED, RAPID, ToolShape
from planning.simulate.program import ProgramError, check_travel, read_program
from planning.simulate.rs274 import INSTALL_HINT, Rs274Error, rs274_available, run_rs274
from planning.toolpath.frames import area_frame
from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    PLANE_AXES,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
    Toolpath,
)
from planning.toolpath.moves import FEED as TP_FEED
from planning.toolpath.moves import RAPID as TP_RAPID
from schemas.params import parse_config

CHORD = 0.005                     # the reader's chord tolerance (default), mm
TOL = 1e-3 + CHORD                # dialects / readers agree within this, mm
# coarse roughing (5 mm steps down, as the service tests'): the same kinds of program, fewer blocks to plan and read
BASE = {"paths": {"finishing": {"scallop_mm": 0.2}, "roughing": {"step_down_mm": 5}}, "simulate": {"enabled": False},
        "normals": {"method": "input"}}
PLANS = {
    "slot": (lambda: samples.slot(density_per_mm2=0.5, seed=1), BASE),
    "half_sphere": (samples.half_sphere, {**BASE, "setups": {"max_setups": 2}, "tool": {"diameter_mm": 10}}),
    "post_wall": (lambda: samples.post_wall(density_per_mm2=0.5, seed=2),
                  {**BASE, "machine": {"profile": "fork_head_ac"}}),
}


def require_rs274():
    assert rs274_available(), INSTALL_HINT


def tools_of(gauge: float, finishing: int = 1, roughing: int = 2, R: float = 3.0) -> dict:
    return {finishing: ToolShape(finishing, "ball", R, R, 12.0, (), gauge),
            roughing: ToolShape(roughing, "flat", 5.0, 0.0, 30.0, (), gauge)}


@pytest.fixture(scope="module")
def plans():
    """Small plans of the slot (table-table B/C), the half sphere and the post by a wall (head-head
    A/C), planned once: {name: dict(programs, profile, placement, tools, k)}."""
    out = {}
    for name, (make, cfg) in PLANS.items():
        s = make()
        cloud = Cloud(points=s.points, normals=s.normals, source_format="generated")
        res = run_plan(cloud, parse_config(cfg), name=name)
        p = res.result.parameters
        out[name] = dict(programs=res.extra["programs"], profile=load_profile(p.machine.profile),
                         placement=np.asarray(res.result.visibility.placement_mm, dtype=float),
                         tools=tools_of(p.tool.assembly().gauge_length_mm, p.post.finishing_tool_number,
                                        p.post.roughing_tool_number, p.tool.diameter_mm / 2),
                         k=len(res.result.setups))
    return out


def read(plan, name: str, reader=read_program, **kw):
    dialect = "iso" if ".iso." in name else "linuxcnc"
    area = int(name.split("_")[1].split(".")[0])
    if reader is run_rs274:
        return run_rs274(plan["programs"][name], program=name, area=area, profile=plan["profile"],
                         placement_mm=plan["placement"], tools=plan["tools"], **kw)
    return read_program(plan["programs"][name], dialect=dialect, program=name, area=area, profile=plan["profile"],
                        placement_mm=plan["placement"], tools=plan["tools"], **kw)


# ----------------------------------------------------------------------------------------------
# comparing move lists


def line_ends(m, keep=None):
    """Index of the last move of every program line (of the moves in ``keep``, default all)."""
    idx = np.arange(m.n_moves) if keep is None else np.flatnonzero(keep)
    last = np.r_[m.line[idx][1:] != m.line[idx][:-1], True]
    return idx[last]


def moving(m):
    return np.linalg.norm(m.end_mm - m.start_mm, axis=1) > 1e-9


def path_distance(p, a, b, spacing=0.05, k=16):
    """(k,) distance of the points p (k,3) to the polyline of the segments a-b (s,3): the ``k``
    nearest samples every ``spacing`` mm pick segments, the exact distance to the nearest counts."""
    n = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / spacing)).astype(int)
    own = np.repeat(np.arange(n.size), n + 1)
    f = (np.arange(own.size) - (np.cumsum(n + 1) - (n + 1))[own]) / n[own]
    _, near = cKDTree(a[own] + f[:, None] * (b - a)[own]).query(p, k=k)
    j = own[near]                                                    # (len(p), k) segments
    ab = b[j] - a[j]
    t = np.clip(((p[:, None] - a[j]) * ab).sum(2) / np.maximum((ab * ab).sum(2), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p[:, None] - (a[j] + t[..., None] * ab), axis=2).min(1)


def assert_same_path(A, B, tol=TOL):
    """Every line end of A (non-zero moves) appears in order among the line ends of B with the same
    kind and axis; B's other line ends are feed moves on A's path (an arc B linearises)."""
    ia, ib = line_ends(A, moving(A)), line_ends(B, moving(B))
    cands = cKDTree(B.end_mm[ib]).query_ball_point(A.end_mm[ia], r=tol, p=np.inf)
    match, j = np.empty(ia.size, dtype=np.int64), -1
    for n, c in enumerate(cands):
        later = [k for k in c if k > j and B.kind[ib[k]] == A.kind[ia[n]]]
        assert later, f"{A.program} line {A.line[ia[n]]} ({n}th line end) not found in order in {B.program}"
        j = match[n] = min(later)
    assert np.abs(B.axis[ib[match]] - A.axis[ia]).max() < 1e-6
    assert match[-1] == ib.size - 1, f"{B.program} goes on beyond {A.program}'s end"
    extra = np.setdiff1d(np.arange(ib.size), match)
    if extra.size:
        assert np.all(B.kind[ib[extra]] == FEED)
        fa = A.kind == FEED
        d = path_distance(B.end_mm[ib[extra]], A.start_mm[fa], A.end_mm[fa])
        assert d.max() <= tol, f"{B.program} line {B.line[ib[extra[np.argmax(d)]]]}: {d.max():.4g} mm off {A.program}"


def in_order(points, got, tol, kinds=None, got_kinds=None):
    """How many of ``points`` (k,3) appear in order (a point may repeat) among ``got`` (n,3), of the
    same kind where ``kinds`` and ``got_kinds`` are given."""
    j = 0
    for n, p in enumerate(points):
        while j < len(got) and (np.abs(got[j] - p).max() > tol or (kinds is not None and kinds[n] != got_kinds[j])):
            j += 1
        if j == len(got):
            return n
    return len(points)


# ----------------------------------------------------------------------------------------------
# real plans


def test_both_dialects_give_the_same_tips_and_axes(plans):
    for name, plan in plans.items():
        for a in range(plan["k"]):
            iso, lin = read(plan, f"area_{a}.iso.nc"), read(plan, f"area_{a}.linuxcnc.nc")
            assert iso.n_moves > 100 and lin.n_moves > 100, name
            assert_same_path(iso, lin)
            # the rotary repositioning: the same steps (G53.1 against G0 B/C) of at most 1 degree
            turned_i, turned_l = (
                np.flatnonzero(np.abs(np.diff(np.r_[[[0.0, 0.0]], m.rotary_deg], axis=0)).max(1) > 1e-9)
                for m in (iso, lin))
            assert turned_i.size == turned_l.size > 0
            assert np.abs(np.diff(np.r_[[[0.0, 0.0]], lin.rotary_deg], axis=0)).max() <= 1.0 + 1e-9
            assert np.abs(iso.end_mm[turned_i] - lin.end_mm[turned_l]).max() <= TOL
            assert np.abs(iso.rotary_deg[-1] - lin.rotary_deg[-1]).max() < 1e-3
            # the same G53 / G28 top of travel at the ends of the operations
            assert iso.machine_mm[-1, 2] == lin.machine_mm[-1, 2] == plan["profile"].linear_limits_mm[2][1]


def test_reader_agrees_with_the_moves_json(plans):
    """Every planned move of moves.json is read back, in order, from both programs (tips in the part
    frame, rapid / feed); every ISO feed block lies on a planned point; the LinuxCNC machine
    positions are the JSON's machine-frame tips moved to the controlled point."""
    for name, plan in plans.items():
        prof = plan["profile"]
        for a in range(plan["k"]):
            mj = json.loads(gzip.decompress(plan["programs"][f"area_{a}.moves.json.gz"]))
            for dialect in ("iso", "linuxcnc"):
                m = read(plan, f"area_{a}.{dialect}.nc")
                for op in mj["operations"]:
                    T = int(op["tool"]["number"])
                    mv = op["moves"]
                    want = np.asarray(mv["tip_part_mm"], dtype=float)
                    ends = line_ends(m, m.tool == T)
                    kinds = np.where([t == "rapid" for t in mv["type"]], RAPID, FEED)
                    n = in_order(want, m.end_mm[ends], 5e-4, kinds, m.kind[ends])
                    assert n == len(want), (name, a, dialect, op["name"], n)
                    fe = ends[m.kind[ends] == FEED]
                    d, j = cKDTree(want).query(m.end_mm[fe])
                    if dialect == "iso":
                        assert d.max() < 5e-4, (name, a, op["name"])
                    hit = d < 5e-4
                    tipm = np.asarray(mv["tip_machine_mm"], dtype=float)[j[hit]]
                    G = plan["tools"][T].gauge_length_mm
                    ctrl = m.machine_mm[fe[hit]]
                    if prof.is_table_table:
                        back = ctrl - [0.0, 0.0, G]
                    else:
                        back = ctrl - (G + prof.pivot_length_mm) * m.axis[fe[hit]]
                    assert np.abs(back - tipm).max() < 5e-4


def test_rs274_agrees_with_the_reader_on_the_linuxcnc_programs(plans):
    require_rs274()
    for name, plan in plans.items():
        for a in range(plan["k"]):
            ours = read(plan, f"area_{a}.linuxcnc.nc")
            theirs = read(plan, f"area_{a}.linuxcnc.nc", reader=run_rs274)
            io, it = line_ends(ours), line_ends(theirs)
            assert np.array_equal(ours.line[io], theirs.line[it]), name
            assert np.array_equal(ours.kind[io], theirs.kind[it])
            assert np.array_equal(ours.tool[io], theirs.tool[it])
            assert np.abs(ours.end_mm[io] - theirs.end_mm[it]).max() < 1e-3
            assert np.abs(ours.axis[io] - theirs.axis[it]).max() < 1e-6
            assert np.abs(ours.machine_mm[io] - theirs.machine_mm[it]).max() < 1e-3
            assert np.abs(ours.rotary_deg[io] - theirs.rotary_deg[it]).max() < 1e-4


def test_travel_of_the_real_programs_is_reported_on_program_lines(plans):
    plan = plans["slot"]
    m = read(plan, "area_0.linuxcnc.nc")
    tr = check_travel(m, plan["profile"])
    lines = plan["programs"]["area_0.linuxcnc.nc"].splitlines()
    (zlo, zhi) = plan["profile"].linear_limits_mm[2]
    for t in tr:
        assert t["excess"] > 0 and t["unit"] in ("mm", "deg")
        assert t["line"] == m.line[t["move"]] and lines[t["line"] - 1].strip()
        if t["axis"] == "Z":
            assert t["limit"] in (zlo, zhi) and abs(t["value"] - t["limit"]) == pytest.approx(t["excess"])


# ----------------------------------------------------------------------------------------------
# posted test operations: arcs in every plane, helices, every profile, flipped signs


def toolpath(seed: int, tip_offset: float) -> Toolpath:
    """Rapids, lines and arcs in G17 / G18 / G19 (some helical), area frame."""
    rng = np.random.default_rng(seed)
    rows = []

    def add(k, p, u, c=(np.nan,) * 3, pl=0):
        rows.append((np.array(p, float), k, np.array(c, float), pl, u))

    cur = np.array([rng.uniform(-20, 20), rng.uniform(-20, 20), 5.0])
    add(TP_RAPID, cur, USE_RAPID)
    for p in (17, 18, 19, 18, 19, 17):
        cur = cur + [rng.uniform(-5, 5), rng.uniform(-5, 5), 0.0]
        cur[2] = -rng.uniform(0.5, 3.0)
        add(TP_FEED, cur, USE_PLUNGE)
        a, b, n = PLANE_AXES[p]
        r, phi0 = rng.uniform(2.0, 10.0), rng.uniform(-math.pi, math.pi)
        sweep = rng.choice([-1, 1]) * rng.uniform(0.3, 5.5)
        c = cur.copy()
        c[a] -= r * math.cos(phi0)
        c[b] -= r * math.sin(phi0)
        end = cur.copy()
        end[a], end[b] = c[a] + r * math.cos(phi0 + sweep), c[b] + r * math.sin(phi0 + sweep)
        if rng.uniform() < 0.4:
            end[n] += rng.uniform(-1.0, 1.0)
        add(ARC_CCW if sweep > 0 else ARC_CW, end, USE_CUT, c, p)
        cur = end.copy()
        cur[2] = max(cur[2], 0.0) + 3.0
        add(TP_FEED, cur, USE_RETRACT)
    xyz, kind, cen, plane, use = zip(*rows)
    return Toolpath(np.array(xyz), np.array(kind, np.int8), np.array(cen), np.array(plane, np.int8),
                    np.array(use, np.int8), float(tip_offset))


def planned(tp: Toolpath, frame, tol: float):
    """The planned tips (part frame) and, per arc move, dense points on it (for the chord check)."""
    tip = frame.to_part(tp.tip_mm())
    dense = []
    for i in np.flatnonzero(np.isin(tp.kind, (ARC_CW, ARC_CCW))):
        a, b, n = PLANE_AXES[int(tp.plane[i])]
        s, e = tp.tip_mm()[i - 1], tp.tip_mm()[i]
        c = tp.centre_mm[i] - [0.0, 0.0, tp.tip_offset_mm]
        t0 = math.atan2(s[b] - c[b], s[a] - c[a])
        sw = (math.atan2(e[b] - c[b], e[a] - c[a]) - t0) % (2 * math.pi)
        if tp.kind[i] == ARC_CW:
            sw -= 2 * math.pi
        f = np.linspace(0.0, 1.0, 4001)
        r = math.hypot(s[a] - c[a], s[b] - c[b])
        q = np.zeros((f.size, 3))
        q[:, a], q[:, b] = c[a] + r * np.cos(t0 + sw * f), c[b] + r * np.sin(t0 + sw * f)
        q[:, n] = s[n] + (e[n] - s[n]) * f
        dense.append(frame.to_part(q))
    return tip, np.concatenate(dense)


def posted_cases():
    out = []
    for name in ("compact_trunnion_bc", "compact_trunnion_ac", "fork_head_ac"):
        for ax in ((0.3, 0.4, 0.866), (0.6, -0.7, 0.38)):
            t = np.asarray(ax) / np.linalg.norm(ax)
            mv = machine_visibility(t, name)
            if mv.feasible[0]:
                out.append((name, t, mv.angles_deg[0]))
    return out


@pytest.mark.parametrize("case", range(len(posted_cases())))
def test_posted_operations_read_back_onto_the_planned_paths(case):
    require_rs274()
    name, t, ang = posted_cases()[case]
    prof = load_profile(name)
    rng = np.random.default_rng(case)
    pts = rng.normal(size=(200, 3)) * [20.0, 15.0, 8.0] + [0.0, 0.0, 15.0]
    frame = area_frame(t, pts)
    place = np.array([3.0, -4.0, 60.0])
    tools = {1: ToolShape(1, "flat", 5.0, 0.0, 20.0, (), 95.0), 2: ToolShape(2, "ball", 3.0, 3.0, 12.0, (), 110.0)}
    ops = [Operation("roughing", toolpath(case, 0.0), 1, 10.0, "flat", 8000, 1200.0, 300.0, gauge_length_mm=95.0),
           Operation("finishing", toolpath(case + 50, 3.0), 2, 6.0, "ball", 12000, 1500.0, 400.0,
                     gauge_length_mm=110.0)]
    sign = (-1, 1) if case % 2 else (1, -1)
    texts = {"iso": iso_program(ops, frame, tool_axis=t, rotary_deg=ang, profile=prof,
                                options=PostOptions(line_numbers=case % 3 == 0)),
             "linuxcnc": linuxcnc_program(ops, frame, tool_axis=t, rotary_deg=ang, profile=prof, placement_mm=place,
                                          options=PostOptions(rotary_sign=sign, line_numbers=case % 3 == 0))}
    got = {d: read_program(x, dialect=d, program=d, area=0, profile=prof, placement_mm=place, tools=tools)
           for d, x in texts.items()}
    got["rs274"] = run_rs274(texts["linuxcnc"], program="rs274", area=0, profile=prof, placement_mm=place, tools=tools)
    for d, m in got.items():
        for op in ops:
            tip, dense = planned(op.toolpath, frame, CHORD)
            mine = m.tool == op.tool_number
            ends = line_ends(m, mine)
            assert in_order(tip, m.end_mm[ends], 5e-4) == len(tip), (name, d, op.name)
            fe = np.flatnonzero(mine & (m.kind == FEED))
            d_plan = np.minimum(cKDTree(dense).query(m.end_mm[fe])[0], cKDTree(tip).query(m.end_mm[fe])[0])
            assert d_plan.max() < 1e-3 + 0.01, (name, d, op.name)      # dense spacing < 0.01 mm
            assert np.abs(m.axis[fe] - t).max() < 1e-6
    assert_same_path(got["iso"], got["linuxcnc"])
    io, it = line_ends(got["linuxcnc"]), line_ends(got["rs274"])
    assert np.array_equal(got["linuxcnc"].line[io], got["rs274"].line[it])
    assert np.abs(got["linuxcnc"].end_mm[io] - got["rs274"].end_mm[it]).max() < 1e-3
    # every cutting move at the planned angles; the programs end with the rotary axes home (at 0)
    assert np.abs(got["linuxcnc"].rotary_deg[got["linuxcnc"].kind == FEED] - ang).max() < 1e-6
    assert all(np.abs(m.rotary_deg[-1]).max() < 1e-9 for m in got.values())


# ----------------------------------------------------------------------------------------------
# known answers


BC = load_profile("compact_trunnion_bc")          # B -35..120, C continuous, Z 102..610, pivot (0, 0, -50)
AC_HEAD = load_profile("fork_head_ac")            # head-head, pivot length 250, Z 300..1100
PLACE = np.array([1.0, 2.0, 40.0])
TOOLS = {1: ToolShape(1, "ball", 3.0, 3.0, 12.0, (), 100.0)}


def test_iso_g682_is_the_fanuc_euler_rotation_and_g2_a_quarter_circle():
    text = "\n".join(["%", "O0001", "G21 G90 G94 G17 G40 G49 G80", "G54", "T1 M6", "S1000 M3",
                      "G68.2 X10. Y20. Z5. I30. J45. K-60.", "G53.1", "G0 G43 H1 X1. Y2. Z3.",
                      "G1 X5. F100.", "G2 X10. Y-3. I0. J-5.", "G69", "G91 G28 Z0.", "G90 G49", "M30", "%"])
    m = read_program(text, dialect="iso", program="t.nc", area=0, profile=BC, placement_mm=PLACE, tools=TOOLS)
    R = Rotation.from_euler("ZXZ", [30, 45, -60], degrees=True).as_matrix()     # intrinsic Z-X'-Z''
    o = np.array([10.0, 20.0, 5.0])
    at = {ln: np.flatnonzero(m.line == ln) for ln in np.unique(m.line)}
    assert np.allclose(m.end_mm[at[9][-1]], R @ [1, 2, 3] + o, atol=1e-9)
    assert np.allclose(m.axis[at[9][-1]], R[:, 2], atol=1e-9)
    assert np.allclose(m.end_mm[at[10][-1]], R @ [5, 2, 3] + o, atol=1e-9)
    arc = at[11]
    centre = R @ [5, -3, 3] + o
    r = np.linalg.norm(m.end_mm[arc] - centre, axis=1)
    assert np.allclose(r, 5.0, atol=1e-9) and np.allclose(m.end_mm[arc[-1]], R @ [10, -3, 3] + o, atol=1e-9)
    mid = 0.5 * (m.start_mm[arc] + m.end_mm[arc])
    assert np.all(5.0 - np.linalg.norm(mid - centre, axis=1) <= CHORD + 1e-12)       # sagitta
    assert arc.size == math.ceil((math.pi / 2) / (2 * math.acos(1 - CHORD / 5.0)))
    # clockwise seen from the feature +Z: the cross product of successive radii points along -Z
    q = (m.end_mm[arc] - centre) @ R
    assert np.all(np.cross(q[:-1], q[1:])[:, 2] < 0) and np.all(m.kind[arc] == FEED)
    # G53.1 turned the table: the tool axis is the feature +Z, with the planner's rotary solution
    assert np.allclose(m.rotary_deg[at[8][-1]], machine_visibility(R[:, 2], BC).angles_deg[0], atol=1e-9)
    # G91 G28 Z0: the gauge point at the top of the Z travel
    assert m.machine_mm[at[13][-1], 2] == BC.linear_limits_mm[2][1]


def lin_table_text(b=30.0, c=45.0):
    return "\n".join(["(rotary words B30. C45., signs: B as planned, C as planned)", "G21 G90 G94 G17 G40 G49 G80",
                      "G54", "G53 G0 Z0", "T1 M6", f"G0 B{b:g} C{c:g}", "G43 H1", "G0 X10. Y-5. Z80.",
                      "G1 Z60. F100.", "G18 G3 X14. Z64. I0. K4.", "G17", "G53 G0 Z0", "G49", "M30"])


def test_linuxcnc_table_table_maps_machine_xyz_back_to_the_part():
    m = read_program(lin_table_text(), dialect="linuxcnc", program="t.ngc", area=0, profile=BC, placement_mm=PLACE,
                     tools=TOOLS)
    Rt = Rotation.from_rotvec([0, math.radians(30), 0]).as_matrix()
    M = Rt @ Rotation.from_rotvec([0, 0, math.radians(45)]).as_matrix()           # R_y(30) R_z(45)
    P = np.array([0.0, 0.0, -50.0])

    def part(X):
        return M.T @ (np.asarray(X, float) - (P - Rt @ P)) - PLACE

    at = {ln: np.flatnonzero(m.line == ln) for ln in np.unique(m.line)}
    assert np.allclose(m.end_mm[at[8][-1]], part([10, -5, 80]), atol=1e-9)
    assert np.allclose(m.end_mm[at[9][-1]], part([10, -5, 60]), atol=1e-9)
    assert np.allclose(m.axis[at[9][-1]], M.T @ [0, 0, 1], atol=1e-12)
    assert np.allclose(m.machine_mm[at[9][-1]], [10, -5, 160], atol=1e-9)      # gauge point = tip + 100 Z
    arc = at[10]
    assert np.allclose(np.linalg.norm(m.end_mm[arc] - part([10, -5, 64]), axis=1), 4.0, atol=1e-9)
    assert np.allclose(m.end_mm[arc[-1]], part([14, -5, 64]), atol=1e-9)
    # G18 G3 is counter-clockwise about +Y: from (x 10, z 60) around (10, 64) to (14, 64) is a quarter
    q = np.array([M @ (p + PLACE) + (P - Rt @ P) for p in m.end_mm[arc]]) - [10, -5, 64]
    assert np.all(np.cross(q[:-1], q[1:])[:, 1] > 0)
    # G53 G0 Z0: the gauge point at the top of the Z travel, X Y kept
    assert np.allclose(m.machine_mm[at[12][-1]], [14, -5, BC.linear_limits_mm[2][1]])
    assert m.notes and any("TOP of the Z travel" in n for n in m.notes)


def test_rotary_repositioning_is_an_arc_about_the_pivot():
    m = read_program(lin_table_text(60.0, 150.0), dialect="linuxcnc", program="t.ngc", area=0, profile=BC,
                     placement_mm=PLACE, tools=TOOLS, rotary_step_deg=2.0)
    steps = np.flatnonzero(m.line == 6)
    assert steps.size == 75 and np.all(m.kind[steps] == RAPID)
    turn = np.diff(np.r_[[[0.0, 0.0]], m.rotary_deg[steps]], axis=0)
    assert np.abs(turn).max() <= 2.0 + 1e-12 and np.allclose(m.rotary_deg[steps[-1]], [60, 150])
    pivot_part = np.array([0.0, 0.0, -50.0]) - PLACE            # the B axis point on the C axis, in the part frame
    d = np.linalg.norm(np.r_[m.start_mm[steps[:1]], m.end_mm[steps]] - pivot_part, axis=1)
    assert np.ptp(d) < 1e-9 and d[0] > 100
    assert np.all(np.linalg.norm(m.end_mm[steps] - m.start_mm[steps], axis=1) > 1.0)
    assert np.allclose(m.machine_mm[steps], m.machine_mm[steps[0]])         # the linear axes stand still
    ax = Rotation.from_rotvec(np.c_[np.zeros(75), np.radians(m.rotary_deg[steps, 0]), np.zeros(75)])
    want = (Rotation.from_rotvec(np.c_[np.zeros((75, 2)), -np.radians(m.rotary_deg[steps, 1])])
            * ax.inv()).apply([0, 0, 1])
    assert np.allclose(m.axis[steps], want, atol=1e-12)


def test_head_head_positions_the_pivot():
    text = "\n".join(["G21 G90 G94 G17 G40 G49 G80", "G54", "G53 G0 Z0", "T1 M6", "G0 A40. C-150.", "G49",
                      "G0 X10. Y20. Z400.", "G1 Z390. F200.", "M30"])
    m = read_program(text, dialect="linuxcnc", program="h.ngc", area=0, profile=AC_HEAD, placement_mm=PLACE,
                     tools=TOOLS)
    t = Rotation.from_rotvec([0, 0, math.radians(-150)]).apply(
        Rotation.from_rotvec([math.radians(40), 0, 0]).apply([0, 0, 1]))
    last = np.flatnonzero(m.line == 8)[-1]
    assert np.allclose(m.axis[last], t, atol=1e-12)
    assert np.allclose(m.end_mm[last], np.array([10, 20, 390]) - (100 + 250) * t - PLACE, atol=1e-9)
    assert np.allclose(m.machine_mm[last], [10, 20, 390])
    # the head swings about its pivot: the tip on a sphere of radius G + L about the (fixed) pivot
    steps = np.flatnonzero(m.line == 5)
    r = np.linalg.norm(m.end_mm[steps] + PLACE - m.machine_mm[steps], axis=1)
    assert np.allclose(r, 350.0) and steps.size == 150


@pytest.mark.parametrize("dialect", ["iso", "linuxcnc"])
def test_tip_below_the_z_travel_is_reported_on_its_line(dialect):
    # gauge point = tip + 100 mm; Z travel 102..610: the tip 20 mm under the table centre puts it at 80
    if dialect == "iso":
        lines = ["G21 G90 G94 G17 G40 G49 G80", "G91 G28 Z0.", "G90", "G54", "T1 M6", "G0 G43 H1 X-1. Y-2. Z10.",
                 "G1 Z-60. F100.", "G0 Z10.", "M30"]
    else:
        lines = ["G21 G90 G94 G17 G40 G49 G80", "G54", "G53 G0 Z0", "T1 M6", "G43 H1", "G0 X0. Y0. Z50.",
                 "G1 Z-20. F100.", "G0 Z50.", "M30"]
    m = read_program("\n".join(lines), dialect=dialect, program="low.nc", area=3, profile=BC, placement_mm=PLACE,
                     tools=TOOLS)
    tr = check_travel(m, BC)
    assert [(t["line"], t["axis"]) for t in tr] == [(7, "Z")]
    t = tr[0]
    assert t["program"] == "low.nc" and t["limit"] == 102.0 and t["unit"] == "mm"
    assert t["value"] == pytest.approx(80.0, abs=1e-9) and t["excess"] == pytest.approx(22.0, abs=1e-9)
    assert m.end_mm[t["move"]] == pytest.approx([-1.0, -2.0, -60.0], abs=1e-9)


def test_rotary_beyond_its_travel_is_reported():
    m = read_program(lin_table_text(-50.0, 10.0), dialect="linuxcnc", program="t.ngc", area=0, profile=BC,
                     placement_mm=PLACE, tools=TOOLS)
    tr = [t for t in check_travel(m, BC) if t["axis"] == "B"]
    assert tr and all(t["line"] == 6 for t in tr[:1]) and tr[0]["limit"] == -35.0
    assert max(t["excess"] for t in tr) == pytest.approx(15.0)


def test_rs274_reads_the_hand_written_programs_alike():
    require_rs274()
    for text, prof in ((lin_table_text(), BC), (lin_table_text(-20.0, 200.0), BC)):
        ours = read_program(text, dialect="linuxcnc", program="t", area=0, profile=prof, placement_mm=PLACE,
                            tools=TOOLS)
        theirs = run_rs274(text, program="t", area=0, profile=prof, placement_mm=PLACE, tools=TOOLS)
        assert np.array_equal(ours.line, theirs.line) and np.array_equal(ours.kind, theirs.kind)
        assert np.abs(ours.end_mm - theirs.end_mm).max() < 1e-3
        assert np.abs(ours.machine_mm - theirs.machine_mm).max() < 1e-3


@pytest.mark.parametrize("dialect, lines, where, what", [
    ("iso", ["G20", "G0 X1."], 1, "inches"),
    ("linuxcnc", ["G21", "G41 D1", "G0 X1."], 2, "G41"),
    ("linuxcnc", ["G21", "M0"], 2, "M0"),
    ("iso", ["G21", "T1 M6", "G68.2 X0 Y0 Z0 I0 J30 K0", "G0 G43 H1 X1. Y1. Z1."], 4, "before G53.1"),
    ("iso", ["G21", "T1 M6", "G0 X1. Y1. Z1."], 3, "G43"),
    ("linuxcnc", ["G21", "G1 X1. Y1."], 2, "feed"),
    ("linuxcnc", ["G21", "G0 X1. X2."], 2, "twice"),
    ("linuxcnc", ["G21", "G0 X1 (open", "M30"], 2, "parenthes"),
    ("linuxcnc", ["G21", "G0 A10."], 2, "not an axis"),
    ("iso", ["G21", "G0 B10."], 2, "rotary words"),
    ("linuxcnc", ["G21", "G1 F10 X0 Y0", "G2 X10. Y0. I3. J0."], 3, "radius"),
    ("linuxcnc", ["G21", "T7 M6"], 2, "T7"),
])
def test_outside_the_subset_raises_naming_the_line(dialect, lines, where, what):
    with pytest.raises(ProgramError, match=what) as e:
        read_program("\n".join(lines), dialect=dialect, program="bad.nc", area=0, profile=BC, placement_mm=PLACE,
                     tools=TOOLS)
    assert f"line {where}:" in str(e.value) and e.value.details["line"] == where


def test_rs274_missing_says_how_to_install_it(monkeypatch):
    import planning.simulate.rs274 as mod

    monkeypatch.setattr(mod.shutil, "which", lambda name: None)
    assert not mod.rs274_available()
    with pytest.raises(Rs274Error, match="apt-get install linuxcnc-uspace"):
        run_rs274("G21\nM30\n", program="x", area=0, profile=BC, placement_mm=PLACE, tools=TOOLS)


def test_rs274_refusal_is_an_error():
    require_rs274()
    with pytest.raises(Rs274Error, match="refused"):
        run_rs274("G21\nG1 F10 X0 Y0\nG2 X10. Y0. I3. J0.\nM30\n", program="x", area=0, profile=BC,
                  placement_mm=PLACE, tools=TOOLS)
