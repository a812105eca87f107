"""Post-processors (planning.post): the G-code is read back by an independent interpreter
(tests/gcode_reader.py, no import from planning) and compared with the toolpaths' tool tips in the
part frame; the neutral JSON is compared with an independent machine-frame computation."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from gcode_reader import Machine, ReaderError, read_program, rx, ry, rz
from scipy.spatial.transform import Rotation

from planning.errors import ParameterError
from planning.orientations.kinematics import available_profiles, load_profile, machine_visibility
from planning.orientations.positions import default_placement
from planning.post import Operation, PostOptions, iso_program, linuxcnc_program, neutral_moves
from planning.toolpath.frames import AreaFrame, area_frame
from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    FEED,
    PLANE_AXES,
    RAPID,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
    Toolpath,
)

PROFILES = available_profiles()
AXES = [
    (0.0, 0.0, 1.0),
    (0.3, 0.4, 0.866),
    (-0.5, 0.2, 0.84),
    (0.6, -0.7, 0.38),
    (1.0, 0.0, 0.0),
]
GAUGE = {1: 95.0, 2: 110.0}


# ----------------------------------------------------------------------------------------------
# fixtures: random-ish toolpaths, frames, operations


def make_toolpath(seed: int, tip_offset: float = 0.0) -> Toolpath:
    """Rapids, plunges, lines, retracts and arcs in all three planes (some helical), area frame."""
    rng = np.random.default_rng(seed)
    xyz, kind, cen, plane, use = [], [], [], [], []

    def add(k, p, u, c=(np.nan,) * 3, pl=0):
        xyz.append(np.array(p, dtype=float))
        kind.append(k)
        cen.append(np.array(c, dtype=float))
        plane.append(pl)
        use.append(u)

    cur = np.array([rng.uniform(-30, 30), rng.uniform(-30, 30), 5.0])
    add(RAPID, cur, USE_RAPID)
    planes = [17, 18, 19] * 3
    rng.shuffle(planes)
    for block in range(3):
        cur = cur.copy()
        cur[2] = -rng.uniform(0.5, 4.0)
        add(FEED, cur, USE_PLUNGE)
        for p in planes[3 * block:3 * block + 3]:
            cur = cur + [rng.uniform(-8, 8), rng.uniform(-8, 8), rng.uniform(-0.5, 0.5)]
            add(FEED, cur, USE_CUT)
            a, b, n = PLANE_AXES[p]
            r = rng.uniform(2.0, 12.0)
            phi0 = rng.uniform(-math.pi, math.pi)
            sweep = rng.choice([-1, 1]) * rng.uniform(0.3, 5.5)
            c = cur.copy()
            c[a] -= r * math.cos(phi0)
            c[b] -= r * math.sin(phi0)
            end = cur.copy()
            end[a] = c[a] + r * math.cos(phi0 + sweep)
            end[b] = c[b] + r * math.sin(phi0 + sweep)
            if rng.uniform() < 0.3:
                end[n] += rng.uniform(-1.0, 1.0)              # helix
            add(ARC_CCW if sweep > 0 else ARC_CW, end, USE_CUT, c, p)
            cur = end
        cur = cur.copy()
        cur[2] = 3.0
        add(FEED, cur, USE_RETRACT)
        cur = np.array([rng.uniform(-30, 30), rng.uniform(-30, 30), 3.0])
        add(RAPID, cur, USE_RAPID)
        cur = cur.copy()
        cur[2] = 1.0
        add(RAPID, cur, USE_RAPID)
    return Toolpath(np.array(xyz), np.array(kind, np.int8), np.array(cen), np.array(plane, np.int8),
                    np.array(use, np.int8), float(tip_offset))


def make_ops(seed: int = 0) -> list[Operation]:
    return [
        Operation("roughing", make_toolpath(seed, 0.0), 1, 10.0, "flat", 8000, 1200.0, 300.0, gauge_length_mm=GAUGE[1]),
        Operation("finishing (ball)", make_toolpath(seed + 1, 3.0), 2, 6.0, "ball", 12000, 1500.0, 400.0,
                  gauge_length_mm=GAUGE[2]),
    ]


def cloud(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(100 + seed)
    return rng.normal(size=(300, 3)) * [30.0, 20.0, 10.0] + [5.0, -3.0, 20.0]


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def cases():
    """(profile, tool axis, angles) for every bundled profile and every feasible test axis."""
    out = []
    for name in PROFILES:
        for ax in AXES:
            t = unit(ax)
            mv = machine_visibility(t, name)
            if mv.feasible[0]:
                out.append((name, tuple(t), tuple(mv.angles_deg[0])))
    return out


CASES = cases()


def test_every_profile_has_tilted_cases():
    for name in PROFILES:
        assert sum(1 for c in CASES if c[0] == name and abs(c[1][2]) < 0.99) >= 3


# ----------------------------------------------------------------------------------------------
# independent references


def machine_map(profile_name: str, angles) -> tuple[np.ndarray, np.ndarray]:
    """(L, f): machine-frame tip = L @ (p + placement) + f, from the documented conventions."""
    p = load_profile(profile_name)
    tilt, rot = angles
    if p.kinematics.startswith("table_table"):
        Rt = rx(tilt) if p.kinematics.endswith("_ac") else ry(tilt)
        M = Rt @ rz(rot)
        P = np.array(p.pivot_mm)
        return M, (np.eye(3) - Rt) @ P
    return np.eye(3), np.zeros(3)


def reader_machine(profile_name: str, placement, options: PostOptions | None = None) -> Machine:
    options = options or PostOptions()
    p = load_profile(profile_name)
    return Machine(kinematics=p.kinematics, placement_mm=tuple(placement), pivot_mm=tuple(p.pivot_mm),
                   head_pivot_length_mm=p.pivot_length_mm, gauge_length_mm=GAUGE,
                   flip_tilt=options.rotary_sign[0] < 0, flip_rotary=options.rotary_sign[1] < 0)


def principal(n: np.ndarray, tol: float = 1e-9):
    for idx, code in ((2, 17), (1, 18), (0, 19)):
        for sign in (1, -1):
            e = np.zeros(3)
            e[idx] = sign
            if np.abs(n - e).max() <= tol:
                return code, sign
    return None


def expected_moves(op: Operation, frame: AreaFrame):
    """Per source move: (index, kind, part tip, part centre, part normal, ccw), consecutive duplicate
    straight moves dropped (the posts print nothing for them)."""
    tp = op.toolpath
    tip = frame.to_part(tp.tip_mm())
    cen = frame.to_part(tp.centre_mm - [0, 0, tp.tip_offset_mm])
    out = []
    prev = None
    for i in range(tp.n_moves):
        k = int(tp.kind[i])
        if k in (RAPID, FEED) and prev is not None and np.linalg.norm(tip[i] - prev) < 1e-7:
            continue
        if k in (ARC_CW, ARC_CCW):
            n = frame.rotation[PLANE_AXES[int(tp.plane[i])][2]]
            out.append((i, "arc", tip[i], cen[i], n, k == ARC_CCW))
        else:
            out.append((i, "rapid" if k == RAPID else "feed", tip[i], None, None, None))
        prev = tip[i]
    return out


def feed_of(op: Operation, i: int) -> float:
    return op.plunge_mm_min if op.toolpath.use[i] == USE_PLUNGE else op.feed_mm_min


def check_chords(points_part, start_part, exp, frame: AreaFrame, op: Operation, tol: float, chord_tol: float):
    """Linearised arc: every point on the true arc, every chord within chord_tol of it."""
    i = exp[0]
    tp = op.toolpath
    a, b, n = PLANE_AXES[int(tp.plane[i])]
    c = tp.centre_mm[i] - [0, 0, tp.tip_offset_mm]
    s = tp.tip_mm()[i - 1]
    e = tp.tip_mm()[i]
    r = math.hypot(s[a] - c[a], s[b] - c[b])
    q = frame.to_frame(np.vstack([start_part, points_part]))
    rad = np.hypot(q[:, a] - c[a], q[:, b] - c[b])
    assert np.abs(rad - r).max() <= tol
    lo, hi = min(s[n], e[n]), max(s[n], e[n])
    assert np.all(q[:, n] >= lo - tol) and np.all(q[:, n] <= hi + tol)
    # angles advance monotonically in the arc's direction and cover the sweep
    ang = np.unwrap(np.arctan2(q[:, b] - c[b], q[:, a] - c[a]))
    step = np.diff(ang) * (1 if exp[5] else -1)
    assert np.all(step > 0)
    mid = 0.5 * (q[1:] + q[:-1])
    sag = r - np.hypot(mid[:, a] - c[a], mid[:, b] - c[b])
    assert sag.max() <= chord_tol + tol
    assert sag.max() >= 0.2 * chord_tol or len(q) <= 5       # not absurdly over-refined


def check_program(prog, ops, frame: AreaFrame, *, decimals: int, prog_map=None, chord_tol: float = 0.002,
                  safe_z: float = 10.0):
    """Tips, arcs, feeds, approach and retract of every operation of a read program.

    ``prog_map``: None for the tilted plane (arcs stay in their area plane); else the (3,3) map of
    part-frame vectors into the program frame (arcs must stay G2/G3 exactly when their normal
    maps onto a principal axis within 1e-9, and be linearised otherwise).
    Returns (number of arcs kept, number linearised)."""
    tol = 10.0 ** (-decimals)
    kept = linearised = 0
    for k, op in enumerate(ops):
        got = [m for m in prog.moves if m.segment == k + 1]
        assert got, f"no moves for operation {k}"
        assert all(m.tool == op.tool_number for m in got)
        tip_area = op.toolpath.tip_mm()
        # approach: the first move is a rapid above the first point at a height clearing every tip
        first = frame.to_frame(got[0].end[None])[0]
        assert got[0].kind == "rapid"
        assert np.allclose(first[:2], tip_area[0, :2], atol=tol)
        assert first[2] >= max(safe_z, tip_area[:, 2].max()) - tol
        # retract: the last move goes straight up along the tool axis to that height
        last = frame.to_frame(got[-1].end[None])[0]
        assert got[-1].kind == "rapid"
        assert np.allclose(last[:2], tip_area[-1, :2], atol=tol) and last[2] == pytest.approx(first[2], abs=tol)
        # no rapid below the first cut's height before the first plunge
        j0 = next(j for j, m in enumerate(got) if m.kind != "rapid")
        h = frame.to_frame(got[j0].end[None])[0, 2]
        for m in got[:j0]:
            assert frame.to_frame(m.end[None])[0, 2] >= h - tol
        # every source move, in order
        j = 1
        for exp in expected_moves(op, frame):
            i, kind, tip, cen, nrm, ccw = exp
            if kind != "arc":
                m = got[j]
                assert m.kind == kind, (k, i, m.line)
                assert np.linalg.norm(m.end - tip) <= tol, (k, i, m.line, m.end, tip)
                if kind == "feed":
                    assert m.feed == pytest.approx(feed_of(op, i))
                j += 1
                continue
            keep = True
            out_dir = ccw
            if prog_map is not None:
                pp = principal(prog_map @ nrm)
                keep = pp is not None
            if keep:
                m = got[j]
                assert m.kind == "arc", (k, i, m.line)
                kept += 1
                assert np.linalg.norm(m.end - tip) <= tol
                d = m.centre - cen
                assert np.linalg.norm(d - (d @ nrm) * nrm) <= tol, (k, i, m.line)
                s_read = (1 if m.direction == "ccw" else -1) * m.normal
                # the ISO tilted plane is built from angles rounded to `decimals` places
                atol = max(1e-9, 3 * math.radians(0.5 * 10.0 ** (-decimals)))
                assert np.allclose(s_read, (1 if out_dir else -1) * nrm, atol=atol), (k, i, m.line)
                if prog_map is None:
                    assert m.plane == int(op.toolpath.plane[i])
                else:
                    assert m.plane == pp[0]
                    assert (m.direction == "ccw") == (ccw if pp[1] > 0 else not ccw)
                assert abs(m.radius_start - m.radius_end) <= 3 * tol
                assert m.feed == pytest.approx(feed_of(op, i))
                j += 1
            else:
                linearised += 1
                pts = []
                start = got[j - 1].end
                while True:
                    m = got[j]
                    assert m.kind == "feed", (k, i, m.line)
                    assert m.feed == pytest.approx(feed_of(op, i))
                    pts.append(m.end)
                    j += 1
                    if np.linalg.norm(m.end - tip) <= tol:
                        break
                check_chords(np.array(pts), start, exp, frame, op, 2 * tol, chord_tol)
        assert j == len(got) - 1, f"operation {k}: {len(got) - 1 - j} unexpected moves"
    return kept, linearised


def code_blocks(prog):
    return [c for _, c in prog.blocks]


def check_layout(text: str, prog, iso: bool):
    blocks = code_blocks(prog)
    first = blocks[0].split()
    if iso:
        assert text.splitlines()[0] == "%" and text.rstrip().splitlines()[-1] == "%"
        assert first[0].startswith("O")
        first = blocks[1].split()
    first = [w for w in first if not w.startswith("N")]
    for g in ("G21", "G90", "G17", "G40", "G49", "G80"):
        assert g in first
    i54 = next(i for i, b in enumerate(blocks) if "G54" in b.split())
    i_motion = next(i for i, b in enumerate(blocks) if any(w in ("G0", "G1") for w in b.split()))
    assert i54 < i_motion
    assert blocks[-1].split()[-1] == "M30"
    assert prog.ended


# ----------------------------------------------------------------------------------------------
# ISO / Fanuc tilted plane


ISO_FRAMES = [unit(a) for a in AXES] + [unit((0.0, 0.0, -1.0)), unit((-0.2, -0.9, -0.3))]


@pytest.mark.parametrize("axis", ISO_FRAMES, ids=lambda a: "t=" + ",".join(f"{v:.2f}" for v in a))
def test_iso_round_trip(axis):
    frame = area_frame(axis, cloud(1))
    ops = make_ops(3)
    text = iso_program(ops, frame, tool_axis=axis, setup_id=2, area_id=1)
    prog = read_program(text)
    check_layout(text, prog, iso=True)
    kept, lin = check_program(prog, ops, frame, decimals=4)
    assert kept == sum(int(np.isin(op.toolpath.kind, (ARC_CW, ARC_CCW)).sum()) for op in ops) and lin == 0
    # one G68.2 per operation, each followed by G53.1 before motion, cancelled by G69 afterwards
    assert len(prog.g68) == len(ops)
    blocks = code_blocks(prog)
    assert sum("G53.1" in b.split() for b in blocks) == len(ops)
    assert sum("G69" in b.split() for b in blocks) == len(ops) + 1
    assert "G49" in blocks[-3].split() or "G49" in blocks[-4].split()


@pytest.mark.parametrize("axis", ISO_FRAMES, ids=lambda a: "t=" + ",".join(f"{v:.2f}" for v in a))
def test_g68_2_euler_angles_are_fanuc_intrinsic_zxz(axis):
    """Fanuc G68.2: rotate about Z by I, then about the NEW X by J, then the NEW Z by K, i.e.
    R = Rz(I) Rx(J) Rz(K) with the feature axes as columns. SciPy's upper-case 'ZXZ' is that
    intrinsic sequence; the lower-case 'zxz' (extrinsic, fixed axes) is the reverse product."""
    frame = area_frame(axis, cloud(2))
    for ad, tol in ((4, 5e-6), (9, 1e-10)):
        text = iso_program(make_ops(0)[:1], frame, tool_axis=axis, options=PostOptions(angle_decimals=ad))
        (_, origin, ijk), = read_program(text).g68
        R = Rotation.from_euler("ZXZ", ijk, degrees=True).as_matrix()
        assert np.allclose(R, frame.rotation.T, atol=tol)
        assert np.allclose(R[:, 2], axis, atol=tol)               # G53.1 turns the tool onto the frame's +Z
        assert np.allclose(origin, frame.origin_mm, atol=1e-4)
        assert 0.0 <= ijk[1] <= 180.0 and -180.0 < ijk[0] <= 180.0 and -180.0 < ijk[2] <= 180.0
        ext = Rotation.from_euler("zxz", ijk, degrees=True).as_matrix()
        if abs(ijk[0]) > 1 and abs(ijk[2]) > 1 and 1 < ijk[1] < 179:
            assert not np.allclose(ext, frame.rotation.T, atol=1e-3)


def test_iso_hand_checked_plane():
    """A frame tilted 90 deg about part X: x = X, y = Z, z = -Y  ->  I0 J90 K0."""
    frame = AreaFrame(rotation=np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]), origin_mm=np.array([1.0, 2, 3]))
    text = iso_program(make_ops(0)[:1], frame, tool_axis=[0, -1, 0])
    assert "G68.2 X1. Y2. Z3. I0. J90. K0." in text
    frame = AreaFrame(rotation=rz(30).T, origin_mm=np.zeros(3))         # +Z axis, x turned 30 deg
    text = iso_program(make_ops(0)[:1], frame, tool_axis=[0, 0, 1])
    assert "G68.2 X0. Y0. Z0. I0. J0. K30." in text


def test_iso_options_line_numbers_decimals_coolant_program_number():
    axis = unit(AXES[2])
    frame = area_frame(axis, cloud(3))
    ops = make_ops(5)
    opts = PostOptions(program_number=4321, decimals=3, line_numbers=True, line_number_step=5, coolant=False,
                       safe_z_mm=25.0)
    text = iso_program(ops, frame, tool_axis=axis, options=opts)
    prog = read_program(text)
    assert prog.program_number == 4321
    check_program(prog, ops, frame, decimals=3, safe_z=25.0)
    lines = [l for l in text.splitlines() if l and not l.startswith("(") and l != "%" and not l.startswith("O")]
    numbers = [int(l.split()[0][1:]) for l in lines]
    assert all(l.startswith("N") for l in lines) and numbers == list(range(5, 5 * len(lines) + 1, 5))
    assert "M8" not in text and "M9" not in text
    assert not any(re_decimals(l, 4) for l in lines)
    text4 = iso_program(ops, frame, tool_axis=axis)
    assert text4.count("M8") == len(ops) and text4.count("M9") == len(ops)
    assert text4.count("T1 M6") == 1 and text4.count("T2 M6") == 1 and "S12000 M3" in text4


def re_decimals(line: str, n: int) -> bool:
    """True when a word of the line has n or more decimals."""
    import re

    return re.search(r"[A-Z]-?\d*\.\d{" + str(n) + ",}", line) is not None


def test_iso_header_names_version_area_setup_axis_angles():
    import scanmill

    axis = unit(AXES[1])
    mv = machine_visibility(axis, "compact_trunnion_bc")
    frame = area_frame(axis, cloud(0))
    text = iso_program(make_ops(0), frame, tool_axis=axis, setup_id=7, area_id=3,
                       rotary_deg=mv.angles_deg[0], profile="compact_trunnion_bc")
    head = "\n".join(l for l in text.splitlines()[:12] if l.startswith(("(", "O")))
    assert f"SCANMILL {scanmill.__version__}" in head
    assert "AREA 3 SETUP 7" in head and "TOOL AXIS" in head
    assert f"B{mv.angles_deg[0][0]:.6f}".rstrip("0") in head and " C" in head
    assert "ROTATING Z-X-Z" in head and "RZ[I] * RX[J] * RZ[K]" in head


def test_numbers_have_a_decimal_point_and_no_negative_zero():
    frame = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
    tp = Toolpath(np.array([[0.0, 0, 5], [0, 0, -0.00001], [10, 0, 0]]), np.array([RAPID, FEED, FEED], np.int8),
                  np.full((3, 3), np.nan), np.zeros(3, np.int8), np.array([USE_RAPID, USE_PLUNGE, USE_CUT], np.int8))
    text = iso_program([Operation("x", tp, 1, 6, "flat", 1000, 100, 50)], frame, tool_axis=[0, 0, 1])
    assert "-0." not in text.replace("-0.0", "")        # "-0." alone never
    assert "Z0. F50." in text and "X10. F100." in text


# ----------------------------------------------------------------------------------------------
# LinuxCNC explicit rotary positioning


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"{c[0]}-t={c[1][0]:.2f},{c[1][1]:.2f},{c[1][2]:.2f}")
def test_linuxcnc_round_trip(case):
    name, axis, angles = case
    axis = np.array(axis)
    pts = cloud(4)
    frame = area_frame(axis, pts)
    placement = default_placement(pts) + [3.0, -7.0, 10.0]
    ops = make_ops(7)
    text = linuxcnc_program(ops, frame, tool_axis=axis, rotary_deg=angles, profile=name, placement_mm=placement,
                            setup_id=1, area_id=0)
    prog = read_program(text, reader_machine(name, placement))
    check_layout(text, prog, iso=False)
    L, _ = machine_map(name, angles)
    kept, lin = check_program(prog, ops, frame, decimals=4, prog_map=L)
    p = load_profile(name)
    n_arcs = sum(int(np.isin(op.toolpath.kind, (ARC_CW, ARC_CCW)).sum()) for op in ops)
    assert kept + lin == n_arcs
    if p.is_table_table:
        # area G17 arcs always stay machine G17 arcs (the tool axis is machine +Z)
        n17 = sum(int((np.isin(op.toolpath.kind, (ARC_CW, ARC_CCW)) & (op.toolpath.plane == 17)).sum()) for op in ops)
        assert kept >= n17
        assert " G43 H1" in "\n" + text.replace("\n", "\n ") and "G43 H2" in text
    else:
        assert "G43" not in " ".join(code_blocks(prog))
    # the rotary words: the plan's angles with the profile's names
    (_, words), *_ = prog.rotary
    tilt_name, rot_name = p.axis_names
    assert set(words) == {tilt_name, rot_name}
    assert words[tilt_name] == pytest.approx(angles[0], abs=1e-7)
    assert words[rot_name] == pytest.approx(angles[1], abs=1e-7)
    # rotary axes move only with Z at machine home (the preceding block is G53 G0 Z0 or T M6)
    for ln, _ in prog.rotary:
        i = next(k for k, (l, _) in enumerate(prog.blocks) if l == ln)
        assert "M6" in prog.blocks[i - 1][1] and "G53" in prog.blocks[i - 2][1]


def test_linuxcnc_principal_planes_keep_every_arc_and_flip_directions():
    """Frames whose axes map onto machine axes: every arc stays G2/G3, and an area plane whose normal
    maps onto a negative machine axis reverses its direction."""
    ops = make_ops(11)
    # head-head A90 C90: tool axis +X; frame x = +Z, y = z cross x = -Y
    t = np.array([1.0, 0, 0])
    frame = AreaFrame(rotation=np.array([[0.0, 0, 1], [0, -1, 0], [1, 0, 0]]), origin_mm=np.array([5.0, 1, 2]))
    mv = machine_visibility(t, "fork_head_ac")
    text = linuxcnc_program(ops, frame, tool_axis=t, rotary_deg=mv.angles_deg[0], profile="fork_head_ac",
                            placement_mm=[0, 0, 60])
    prog = read_program(text, reader_machine("fork_head_ac", [0, 0, 60]))
    kept, lin = check_program(prog, ops, frame, decimals=4, prog_map=np.eye(3))
    assert lin == 0 and kept == sum(int(np.isin(op.toolpath.kind, (ARC_CW, ARC_CCW)).sum()) for op in ops)
    # area G18 (normal y = part -Y) arcs came out as G18 with the opposite direction
    arcs18 = [m for m in prog.moves if m.kind == "arc" and m.plane == 18]
    assert arcs18 and all(m.normal @ [0, -1, 0] < -0.999 for m in arcs18)
    # table-table A-90: tool axis -Y presented along +Z; frame x = -X so y = z cross x = -Z
    t = np.array([0.0, -1, 0])
    frame = AreaFrame(rotation=np.array([[-1.0, 0, 0], [0, 0, -1], [0, -1, 0]]), origin_mm=np.array([0.0, -4, 7]))
    angles = (-90.0, 0.0)
    text = linuxcnc_program(ops, frame, tool_axis=t, rotary_deg=angles, profile="compact_trunnion_ac",
                            placement_mm=[0, 0, 40])
    prog = read_program(text, reader_machine("compact_trunnion_ac", [0, 0, 40]))
    L, _ = machine_map("compact_trunnion_ac", angles)
    kept, lin = check_program(prog, ops, frame, decimals=4, prog_map=L)
    assert lin == 0


@pytest.mark.parametrize("flip", [(True, False), (False, True), (True, True)])
def test_linuxcnc_flipped_rotary_signs(flip):
    name = "compact_trunnion_bc"
    axis = unit(AXES[3])
    mv = machine_visibility(axis, name)
    angles = mv.angles_deg[0]
    frame = area_frame(axis, cloud(5))
    opts = PostOptions(rotary_sign=(-1 if flip[0] else 1, -1 if flip[1] else 1))
    ops = make_ops(2)[:1]
    text = linuxcnc_program(ops, frame, tool_axis=axis, rotary_deg=angles, profile=name, placement_mm=[0, 0, 50],
                            options=opts)
    prog = read_program(text, reader_machine(name, [0, 0, 50], opts))
    (_, words), = prog.rotary
    assert words["B"] == pytest.approx((-1 if flip[0] else 1) * angles[0], abs=1e-7)
    assert words["C"] == pytest.approx((-1 if flip[1] else 1) * angles[1], abs=1e-7)
    check_program(prog, ops, frame, decimals=4, prog_map=machine_map(name, angles)[0])
    # read without the flips, the tips land elsewhere: the flip really changes the output
    with pytest.raises(AssertionError):
        check_program(read_program(text, reader_machine(name, [0, 0, 50])), ops, frame, decimals=4,
                      prog_map=machine_map(name, angles)[0])


def test_linuxcnc_chord_tolerance_is_honoured():
    name = "fork_head_ac"
    axis = unit(AXES[1])
    mv = machine_visibility(axis, name)
    frame = area_frame(axis, cloud(6))
    ops = make_ops(4)
    for tol in (0.01, 0.0005):
        opts = PostOptions(chord_tol_mm=tol)
        text = linuxcnc_program(ops, frame, tool_axis=axis, rotary_deg=mv.angles_deg[0], profile=name,
                                placement_mm=[0, 0, 50], options=opts)
        prog = read_program(text, reader_machine(name, [0, 0, 50]))
        _, lin = check_program(prog, ops, frame, decimals=4, prog_map=np.eye(3), chord_tol=tol)
        assert lin > 0
        assert f"G64 P{tol:g}" in text


def test_degenerate_arcs_never_become_full_circles():
    """An arc whose start and end coincide after rounding is a chord (tiny sweep) or a polyline
    (sweep near 360 degrees), never a G2/G3 that a control would run as a full circle."""
    frame = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
    r = 5.0
    xyz = [[r, 0, 5], [r, 0, -1]]
    cen = [[np.nan] * 3, [np.nan] * 3]
    for sweep in (1e-6, 2 * math.pi - 1e-6):
        xyz.append([r * math.cos(sweep), r * math.sin(sweep), -1])
        cen.append([0, 0, -1])
    tp = Toolpath(np.array(xyz), np.array([RAPID, FEED, ARC_CCW, ARC_CCW], np.int8), np.array(cen),
                  np.array([0, 0, 17, 17], np.int8), np.array([USE_RAPID, USE_PLUNGE, USE_CUT, USE_CUT], np.int8))
    op = Operation("x", tp, 1, 6, "flat", 1000, 100, 50)
    for text, machine in ((iso_program([op], frame, tool_axis=[0, 0, 1]), None),
                          (linuxcnc_program([op], frame, tool_axis=[0, 0, 1], rotary_deg=(0, 0),
                                            profile="compact_trunnion_ac", placement_mm=[0, 0, 80]),
                           reader_machine("compact_trunnion_ac", [0, 0, 80]))):
        prog = read_program(text, machine)
        assert not any(m.kind == "arc" for m in prog.moves)
        pts = np.array([m.end for m in prog.moves if m.kind == "feed"])
        ang = np.unwrap(np.arctan2(pts[:, 1], pts[:, 0]))     # from the plunge point at angle 0 on
        assert ang[-1] - ang[0] > 2 * math.pi - 0.01          # the near-full circle is traced
        assert np.all(np.diff(ang) > 0)
        assert np.abs(np.hypot(pts[:, 0], pts[:, 1]) - r).max() < 1e-4


# ----------------------------------------------------------------------------------------------
# neutral JSON


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"{c[0]}-t={c[1][0]:.2f},{c[1][1]:.2f},{c[1][2]:.2f}")
def test_neutral_round_trips_and_matches_the_machine_frame(case):
    name, axis, angles = case
    axis = np.array(axis)
    pts = cloud(7)
    frame = area_frame(axis, pts)
    placement = default_placement(pts)
    ops = make_ops(9)
    doc = neutral_moves(ops, frame, tool_axis=axis, rotary_deg=angles, profile=name, placement_mm=placement,
                        setup_id=4, area_id=2)
    text = json.dumps(doc)
    assert json.loads(text) == doc
    p = load_profile(name)
    L, f = machine_map(name, angles)
    tilt_name, rot_name = p.axis_names
    assert doc["setup"]["rotary_deg"] == {tilt_name: pytest.approx(angles[0]), rot_name: pytest.approx(angles[1])}
    t_m = np.array(doc["setup"]["tool_axis_machine"])
    assert np.allclose(t_m, [0, 0, 1] if p.is_table_table else axis, atol=1e-9)
    for op, d in zip(ops, doc["operations"]):
        tp = op.toolpath
        mv = d["moves"]
        assert mv["count"] == tp.n_moves == len(mv["type"]) == len(mv["tip_part_mm"]) == len(mv["tip_machine_mm"])
        tip = frame.to_part(tp.xyz_mm - [0, 0, tp.tip_offset_mm])
        assert np.abs(np.array(mv["tip_part_mm"]) - tip).max() <= 0.5e-4 + 1e-12
        mach = (tip + placement) @ L.T + f
        assert np.abs(np.array(mv["tip_machine_mm"]) - mach).max() <= 0.5e-4 + 1e-9
        assert [x for x in mv["type"]] == [{RAPID: "rapid", FEED: "feed"}.get(int(k), "arc") for k in tp.kind]
        for i, fd in enumerate(mv["feed_mm_min"]):
            assert fd is None if tp.kind[i] == RAPID else fd == feed_of(op, i)
        arcs = d["arcs"]
        idx = np.flatnonzero(np.isin(tp.kind, (ARC_CW, ARC_CCW)))
        assert arcs["move"] == idx.tolist()
        cen = frame.to_part(tp.centre_mm[idx] - [0, 0, tp.tip_offset_mm])
        assert np.abs(np.array(arcs["centre_part_mm"]) - cen).max() <= 0.5e-4 + 1e-9
        assert np.abs(np.array(arcs["centre_machine_mm"]) - ((cen + placement) @ L.T + f)).max() <= 0.5e-4 + 1e-9
        for j, i in enumerate(idx):
            n = frame.rotation[PLANE_AXES[int(tp.plane[i])][2]]
            assert np.allclose(arcs["normal_part"][j], n, atol=1e-9)
            assert np.allclose(arcs["normal_machine"][j], L @ n, atol=1e-9)
            assert arcs["direction"][j] == ("ccw" if tp.kind[i] == ARC_CCW else "cw")
            assert arcs["plane"][j] == int(tp.plane[i])
        # controlled point: gauge point (table-table) / head rotation centre (head-head)
        ctrl = np.array(d["controlled_machine_mm"])
        if p.is_table_table:
            assert np.abs(ctrl - (mach + [0, 0, op.gauge_length_mm])).max() <= 1e-4
        else:
            assert np.abs(ctrl - (mach + (op.gauge_length_mm + p.pivot_length_mm) * axis)).max() <= 1e-4


# ----------------------------------------------------------------------------------------------
# errors


def test_bad_input_raises_parameter_error():
    axis = unit(AXES[1])
    frame = area_frame(axis, cloud(0))
    ops = make_ops(0)
    angles = machine_visibility(axis, "compact_trunnion_bc").angles_deg[0]
    with pytest.raises(ParameterError, match="tool axis"):
        iso_program(ops, frame, tool_axis=[0, 0, 1])
    with pytest.raises(ParameterError, match="rotary_deg"):
        linuxcnc_program(ops, frame, tool_axis=axis, rotary_deg=(angles[0] + 1, angles[1]),
                         profile="compact_trunnion_bc", placement_mm=[0, 0, 0])
    with pytest.raises(ParameterError, match="decimals"):
        iso_program(ops, frame, tool_axis=axis, options=PostOptions(decimals=9))
    with pytest.raises(ParameterError, match="chord_tol_mm"):
        iso_program(ops, frame, tool_axis=axis, options=PostOptions(chord_tol_mm=0.0))
    with pytest.raises(ParameterError, match="operation"):
        iso_program([], frame, tool_axis=axis)
    bad = Operation("x", ops[0].toolpath, 0, 6, "flat", 1000, 100, 50)
    with pytest.raises(ParameterError, match="tool_number"):
        iso_program([bad], frame, tool_axis=axis)
    bad = Operation("x", ops[0].toolpath, 1, 6, "flat", 1000, -100, 50)
    with pytest.raises(ParameterError, match="feed_mm_min"):
        iso_program([bad], frame, tool_axis=axis)
    with pytest.raises(ParameterError, match="placement_mm"):
        neutral_moves(ops, frame, tool_axis=axis, rotary_deg=angles, profile="compact_trunnion_bc",
                      placement_mm=[0, 0])
    # head-head needs the gauge length: the post outputs the head rotation centre
    angles_h = machine_visibility(axis, "fork_head_ac").angles_deg[0]
    no_gauge = [Operation("x", ops[0].toolpath, 1, 6, "flat", 1000, 100, 50)]
    with pytest.raises(ParameterError, match="gauge_length_mm"):
        linuxcnc_program(no_gauge, frame, tool_axis=axis, rotary_deg=angles_h, profile="fork_head_ac",
                         placement_mm=[0, 0, 0])
    with pytest.raises(ParameterError, match="rotary_sign"):
        linuxcnc_program(ops, frame, tool_axis=axis, rotary_deg=angles, profile="compact_trunnion_bc",
                         placement_mm=[0, 0, 0], options=PostOptions(rotary_sign=(1, 0)))
    with pytest.raises(ParameterError, match="gauge_length_mm"):
        linuxcnc_program(no_gauge, frame, tool_axis=axis, rotary_deg=angles_h, profile="fork_head_ac",
                         placement_mm=[0, 0, 0], gauge_length_mm=-5.0)
    tp = ops[0].toolpath
    arc_first = Toolpath(tp.xyz_mm[3:], tp.kind[3:], tp.centre_mm[3:], tp.plane[3:], tp.use[3:], 0.0)
    assert arc_first.kind[0] in (ARC_CW, ARC_CCW)
    with pytest.raises(ParameterError, match="move 0"):
        iso_program([Operation("x", arc_first, 1, 6, "flat", 1000, 100, 50)], frame, tool_axis=axis)


def test_comments_are_sanitised_for_the_reader():
    frame = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
    ops = [Operation("weird (name) ;x", make_toolpath(0), 1, 6, "flat", 1000, 100, 50)]
    text = iso_program(ops, frame, tool_axis=[0, 0, 1])
    read_program(text)                  # balanced parentheses, no stray semicolon comment
    with pytest.raises(ReaderError):
        read_program("G0 X1 (oops")


def test_nearly_principal_planes_are_linearised():
    """1e-5 rad off a machine principal plane is not within 1e-9: those arcs become chords, while the
    area G17 arcs (normal = tool axis = machine +X here) stay arcs."""
    ops = make_ops(13)
    t = np.array([1.0, 0, 0])
    rows = np.array([[0.0, 0, 1], [0, -1, 0], [1, 0, 0]])
    twist = Rotation.from_rotvec(1e-5 * t).as_matrix()           # about the tool axis
    frame = AreaFrame(rotation=rows @ twist.T, origin_mm=np.array([5.0, 1, 2]))
    assert np.allclose(frame.rotation[2], t)
    mv = machine_visibility(t, "fork_head_ac")
    text = linuxcnc_program(ops, frame, tool_axis=t, rotary_deg=mv.angles_deg[0], profile="fork_head_ac",
                            placement_mm=[0, 0, 60])
    prog = read_program(text, reader_machine("fork_head_ac", [0, 0, 60]))
    kept, lin = check_program(prog, ops, frame, decimals=4, prog_map=np.eye(3))
    n17 = sum(int((np.isin(op.toolpath.kind, (ARC_CW, ARC_CCW)) & (op.toolpath.plane == 17)).sum()) for op in ops)
    assert kept == n17 and lin > 0


def test_safe_height_clears_arcs_that_bulge_above_their_end_points():
    """A G19 half circle rising 20 mm above its end points (top at z 25): the approach and retract height clears
    its top, not only the end points."""
    frame = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
    xyz = np.array([[0.0, -20, 7], [0, -20, 5], [0, 20, 5], [0, 20, 7]])
    cen = np.full((4, 3), np.nan)
    cen[2] = [0, 0, 5]
    tp = Toolpath(xyz, np.array([RAPID, FEED, ARC_CW, FEED], np.int8), cen, np.array([0, 0, 19, 0], np.int8),
                  np.array([USE_RAPID, USE_PLUNGE, USE_CUT, USE_RETRACT], np.int8))
    op = Operation("bulge", tp, 1, 6, "flat", 1000, 100, 50)
    # G19 (Y, Z) plane, clockwise seen from +X: from -Y over the top (+Z) to +Y
    prog = read_program(iso_program([op], frame, tool_axis=[0, 0, 1]))
    arc = next(m for m in prog.moves if m.kind == "arc")
    assert arc.plane == 19 and arc.direction == "cw"
    assert prog.moves[0].end[2] >= 25.0 - 1e-4 and prog.moves[-1].end[2] >= 25.0 - 1e-4


def test_every_post_takes_the_same_arguments_and_a_program_level_gauge_length():
    """The posts accept one argument set (what a caller looping over dialects passes); operations
    without their own gauge length take the program-level one (head-head rotation centre)."""
    name = "fork_head_ac"
    axis = unit(AXES[2])
    frame = area_frame(axis, cloud(8))
    angles = machine_visibility(axis, name).angles_deg[0]
    ops = [Operation(o.name, o.toolpath, o.tool_number, o.tool_diameter_mm, o.tool_type, o.spindle_rpm,
                     o.feed_mm_min, o.plunge_mm_min) for o in make_ops(21)]
    kw = {"setup_id": 0, "tool_axis": axis, "rotary_deg": angles, "profile": name, "placement_mm": [0, 0, 70],
          "gauge_length_mm": 123.0, "options": PostOptions(rotary_sign=(1, 1))}
    iso = iso_program(ops, frame, **kw)
    check_program(read_program(iso), ops, frame, decimals=4)
    lcnc = linuxcnc_program(ops, frame, **kw)
    m = reader_machine(name, [0, 0, 70])
    m.gauge_length_mm = {1: 123.0, 2: 123.0}
    check_program(read_program(lcnc, m), ops, frame, decimals=4, prog_map=np.eye(3))
    doc = neutral_moves(ops, frame, **{k: v for k, v in kw.items() if k != "options"})
    p = load_profile(name)
    for op, d in zip(ops, doc["operations"]):
        tip = np.array(d["moves"]["tip_machine_mm"])
        assert d["tool"]["gauge_length_mm"] == 123.0
        assert np.abs(np.array(d["controlled_machine_mm"]) - (tip + (123.0 + p.pivot_length_mm) * axis)).max() <= 2e-4


# ----------------------------------------------------------------------------------------------
# the whole-array posts against the per-move reference (byte for byte)


def random_toolpath(seed: int, n: int, *, tip_offset: float = 0.0, scale: float = 50.0, quant=None) -> Toolpath:
    """``n`` random moves of every kind and use: rapids, lines (tiny to long), repeated points, arcs
    in the three planes (helices, 90-degree and longer sweeps, and the degenerate ones: sweeps of
    1e-6 rad or 360 - 1e-6 degrees, radii at the output resolution, end = start). ``quant``: snap
    every coordinate to multiples of 1/quant (binary fractions: exact rounding ties)."""
    rng = np.random.default_rng(seed)
    xyz = np.zeros((n, 3))
    kind = np.zeros(n, np.int8)
    cen = np.full((n, 3), np.nan)
    plane = np.zeros(n, np.int8)
    use = np.zeros(n, np.int8)
    cur = rng.uniform(-scale, scale, 3)
    xyz[0] = cur
    for i in range(1, n):
        r = rng.uniform()
        if r < 0.08:
            kind[i], use[i] = RAPID, USE_RAPID
            cur = cur + rng.uniform(-scale / 5, scale / 5, 3)
        elif r < 0.12:                                              # the same point again
            kind[i], use[i] = rng.choice([RAPID, FEED]), rng.integers(0, 4)
        elif r < 0.5:
            kind[i], use[i] = FEED, rng.choice([USE_CUT, USE_PLUNGE, USE_RETRACT, USE_RAPID])
            cur = cur + rng.normal(scale=rng.choice([1e-5, 1e-3, 0.5, 5.0]), size=3)
        else:
            p = int(rng.choice([17, 18, 19]))
            a, b, nn = PLANE_AXES[p]
            typ = rng.uniform()
            if typ < 0.05:
                rad, sweep = rng.uniform(1, 10), rng.choice([-1, 1]) * 1e-6
            elif typ < 0.10:
                rad, sweep = rng.uniform(1, 10), rng.choice([-1, 1]) * (2 * math.pi - 1e-6)
            elif typ < 0.13:
                rad, sweep = rng.uniform(1e-6, 3e-4), rng.uniform(-6, 6)
            elif typ < 0.15:
                rad, sweep = rng.uniform(1, 10), 0.0
            else:
                rad = 10 ** rng.uniform(-2, 1.3)
                sweep = rng.uniform(-6.2, 6.2) if rng.uniform() < 0.2 else rng.uniform(-0.6, 0.6)
            phi0 = rng.uniform(-math.pi, math.pi)
            c = cur.copy()
            c[a] -= rad * math.cos(phi0)
            c[b] -= rad * math.sin(phi0)
            e = cur.copy()
            e[a] = c[a] + rad * math.cos(phi0 + sweep)
            e[b] = c[b] + rad * math.sin(phi0 + sweep)
            if typ >= 0.15 and rng.uniform() < 0.3:
                e[nn] += rng.uniform(-2, 2)                         # helix
            if typ < 0.15 and sweep != 0.0 and rng.uniform() < 0.5:
                e[a], e[b] = cur[a], cur[b]                         # end exactly on the start
            kind[i] = ARC_CCW if sweep > 0 or (sweep == 0 and rng.uniform() < 0.5) else ARC_CW
            use[i] = rng.choice([USE_CUT, USE_PLUNGE])
            plane[i], cen[i], cur = p, c, e
        if quant is not None:
            cur = np.round(cur * quant) / quant
            if kind[i] in (ARC_CW, ARC_CCW):
                cen[i] = np.round(cen[i] * quant) / quant
        xyz[i] = cur
    return Toolpath(xyz, kind, cen, plane, use, float(tip_offset))


def random_ops(seed: int, n: int = 200, **kw) -> list[Operation]:
    return [Operation("roughing", random_toolpath(seed, n, **kw), 1, 10.0, "flat", 8000, 1200.0, 300.0,
                      gauge_length_mm=GAUGE[1]),
            Operation("finishing", random_toolpath(seed + 1, n, tip_offset=3.0, **kw), 2, 6.0, "ball", 12000,
                      1500.0, 1500.0, gauge_length_mm=GAUGE[2])]


def reference_text(post, *args, **kw) -> str:
    """The post's text with every operation printed by the per-move MotionEmitter."""
    from planning.post import motion

    motion._REFERENCE_MOTION = True
    try:
        return post(*args, **kw)
    finally:
        motion._REFERENCE_MOTION = False


BULK_OPTIONS = [
    PostOptions(),
    PostOptions(line_numbers=True, line_number_step=997, coolant=False, program_number=7),
    PostOptions(decimals=3, rotary_sign=(-1, 1), safe_z_mm=25.0),
    PostOptions(decimals=0, chord_tol_mm=0.6, rotary_sign=(1, -1)),
    PostOptions(decimals=2, chord_tol_mm=0.01, line_numbers=True),
    PostOptions(decimals=6, angle_decimals=3, rotary_sign=(-1, -1)),
]


@pytest.mark.parametrize("k", range(len(BULK_OPTIONS)))
def test_bulk_posts_match_the_per_move_reference(k):
    """Random moves of every kind (degenerate arcs included) on tilted and principal frames, every
    profile: the whole-array posts print exactly the per-move MotionEmitter's text."""
    o = BULK_OPTIONS[k]
    ops = random_ops(31 + k, quant=64 if k % 2 else None)
    axis = unit(AXES[k % len(AXES)])
    frames = [(area_frame(axis, cloud(k)), axis),
              (AreaFrame(rotation=np.array([[0.0, 0, 1], [0, -1, 0], [1, 0, 0]]), origin_mm=np.zeros(3)),
               np.array([1.0, 0, 0])),
              (AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3)), np.array([0.0, 0, 1]))]
    for frame, t in frames[:2] if k % 2 else frames:
        text = iso_program(ops, frame, tool_axis=t, options=o)
        assert text == reference_text(iso_program, ops, frame, tool_axis=t, options=o)
        for name in PROFILES:
            mv = machine_visibility(t, name)
            if not mv.feasible[0]:
                continue
            kw = {"tool_axis": t, "rotary_deg": mv.angles_deg[0], "profile": name,
                  "placement_mm": [1.0, -2.0, 60.0], "options": o}
            text = linuxcnc_program(ops, frame, **kw)
            assert text == reference_text(linuxcnc_program, ops, frame, **kw), (name, k)


def test_bulk_posts_on_a_finishing_path_and_on_huge_coordinates():
    """A zig-zag finishing path with G18 arcs (the benchmark's), and coordinates beyond the
    whole-array formatter's range (printed by MotionEmitter itself): identical to the reference."""
    sys_path_bench()
    from bench_post import finishing_like

    axis = unit(AXES[1])
    frame = area_frame(axis, cloud(2))
    ops = [Operation("finishing", finishing_like(3000), 2, 6.0, "ball", 12000, 1500.0, 400.0, gauge_length_mm=110.0)]
    name = "compact_trunnion_bc"
    kw = {"tool_axis": axis, "rotary_deg": machine_visibility(axis, name).angles_deg[0], "profile": name,
          "placement_mm": [0, 0, 60]}
    for o in (PostOptions(), PostOptions(line_numbers=True, decimals=3)):
        assert iso_program(ops, frame, tool_axis=axis, options=o) == \
            reference_text(iso_program, ops, frame, tool_axis=axis, options=o)
        assert linuxcnc_program(ops, frame, options=o, **kw) == reference_text(linuxcnc_program, ops, frame,
                                                                               options=o, **kw)
    huge = [Operation("x", random_toolpath(5, 60, scale=3e11), 1, 6, "flat", 1000, 100, 50)]
    ident = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
    assert iso_program(huge, ident, tool_axis=[0, 0, 1]) == reference_text(iso_program, huge, ident,
                                                                            tool_axis=[0, 0, 1])


def sys_path_bench():
    import os
    import sys

    here = os.path.join(os.path.dirname(__file__), "..", "bench")
    if here not in sys.path:
        sys.path.insert(0, here)


def test_bulk_number_formatting_matches_fmt():
    """The whole-array formatter prints what fmt prints: random magnitudes from 1e-9 to near its
    2^51 limit, both signs, values that round to zero (never '-0.'), and exact rounding ties (binary
    fractions), at every number of decimals."""
    from planning.post.blocks import fmt
    from planning.post.bulk_text import _Q_MAX, _quantise, _Rows

    rng = np.random.default_rng(0)
    for d in range(7):
        top = _Q_MAX / 10 ** d
        v = np.concatenate([
            rng.uniform(-1, 1, 20000) * 10.0 ** rng.uniform(-9, math.log10(top) - 1e-9, 20000),
            rng.integers(-10 ** 6, 10 ** 6, 10000) / 2.0 ** rng.integers(0, 12, 10000),   # ties and near ties
            (rng.integers(-10 ** 5, 10 ** 5, 5000) + 0.5) / 10 ** d,                       # decimal "ties"
            rng.uniform(-0.6, 0.6, 2000) * 10.0 ** -d, [0.0, -0.0, 10.0, -10.0, top * 0.999, -top * 0.999],
        ])
        q = _quantise(v, d)
        rows = _Rows(v.size)
        rows.number("X", q, d, np.ones(v.size, dtype=bool))
        got = rows.text().splitlines()
        want = ["X" + fmt(x, d) for x in v.tolist()]
        assert got == want, next((g, w_) for g, w_ in zip(got, want) if g != w_)
        assert np.array_equal(q / 10.0 ** d if d else q.astype(float), [float(s[1:]) for s in want])
    assert _quantise(np.array([_Q_MAX]), 0) is None


def test_line_numbers_in_bulk_follow_block_by_block_numbering():
    from planning.post.blocks import BlockWriter

    for step, before, count in ((10, 0, 25), (997, 95, 400), (1, 99990, 30), (1000, 99, 1)):
        one, bulk = BlockWriter(PostOptions(line_numbers=True, line_number_step=step)), \
            BlockWriter(PostOptions(line_numbers=True, line_number_step=step))
        for w in (one, bulk):
            for _ in range(before):
                w.block("M0")
        for _ in range(count):
            one.block("G0")
        got = bulk.take_numbers(count)
        assert [f"N{v} G0" for v in got] == one.lines[before:] and bulk.n == one.n


def test_safe_height_matches_the_per_arc_reference():
    from planning.post.arcs import _reference_safe_height_mm, safe_height_mm

    for seed in range(4):
        for op in random_ops(60 + seed, 300):
            for z in (0.01, 10.0, 1e3):
                o = PostOptions(safe_z_mm=z)
                assert safe_height_mm(op, o) == _reference_safe_height_mm(op, o)


def _reference_neutral_operations(operations, frame, *, tool_axis, rotary_deg, profile, placement_mm,
                                  gauge_length_mm=None, decimals: int = 4, **_header) -> list[dict]:
    """The ``operations`` of neutral_moves as first written, one move at a time (the reference of the
    whole-array one; the document's header around them is not per-move work and is not repeated here)."""
    from planning.orientations.kinematics import as_profile, part_to_machine_rotation
    from planning.orientations.positions import machine_position_affine
    from planning.post.neutral import _TYPE, _UNIT_DECIMALS, _USE, _r
    from planning.post.options import (
        check_frame,
        check_gauge,
        check_operations,
        check_placement,
        check_rotary,
        feed_for,
        gauge_of,
    )
    from planning.toolpath.moves import path_length_mm

    d = int(decimals)
    ops = check_operations(operations)
    t = check_frame(frame, tool_axis)
    p = as_profile(profile)
    rot = check_rotary(rotary_deg, t, p)
    place = check_placement(placement_mm)
    gauge = check_gauge(gauge_length_mm)
    Rrows = np.asarray(frame.rotation, dtype=np.float64)
    M = part_to_machine_rotation(rot, p)[0]
    if p.is_table_table:
        A_tip, b_tip = machine_position_affine(rot, p, placement_mm=place, tool_radius_mm=0.0, gauge_length_mm=0.0)
        A_tip, b_tip = A_tip[0], b_tip[0]
    else:
        A_tip, b_tip = np.eye(3), place.copy()
    out_ops = []
    for op in ops:
        tp = op.toolpath
        off = np.array([0.0, 0.0, tp.tip_offset_mm])
        tip_part = frame.to_part(tp.xyz_mm - off)
        tip_mach = tip_part @ A_tip.T + b_tip
        feeds = [None if int(k) == RAPID else feed_for(op, u) for k, u in zip(tp.kind, tp.use)]
        moves = {"count": int(tp.n_moves), "type": [_TYPE[int(k)] for k in tp.kind],
                 "use": [_USE[int(u)] for u in tp.use], "feed_mm_min": feeds, "tip_part_mm": _r(tip_part, d),
                 "tip_machine_mm": _r(tip_mach, d)}
        arc_idx = np.flatnonzero(np.isin(tp.kind, (ARC_CW, ARC_CCW)))
        cen_part = frame.to_part(tp.centre_mm[arc_idx] - off) if arc_idx.size else np.zeros((0, 3))
        normals = np.array([Rrows[PLANE_AXES[int(tp.plane[i])][2]] for i in arc_idx]).reshape(-1, 3)
        arcs = {"count": int(arc_idx.size), "move": [int(i) for i in arc_idx],
                "direction": ["ccw" if int(tp.kind[i]) == ARC_CCW else "cw" for i in arc_idx],
                "plane": [int(tp.plane[i]) for i in arc_idx], "normal_part": _r(normals, _UNIT_DECIMALS),
                "normal_machine": _r(normals @ M.T, _UNIT_DECIMALS), "centre_part_mm": _r(cen_part, d),
                "centre_machine_mm": _r(cen_part @ A_tip.T + b_tip, d)}
        entry = {"name": str(op.name),
                 "tool": {"number": int(op.tool_number), "diameter_mm": float(op.tool_diameter_mm),
                          "type": str(op.tool_type),
                          "gauge_length_mm": None if op.gauge_length_mm is None else float(op.gauge_length_mm)},
                 "spindle_rpm": float(op.spindle_rpm), "feed_mm_min": float(op.feed_mm_min),
                 "plunge_mm_min": float(op.plunge_mm_min), "tip_offset_mm": float(tp.tip_offset_mm),
                 "cut_length_mm": round(path_length_mm(tp), d),
                 "rapid_length_mm": round(path_length_mm(tp, kinds=(RAPID,)), d), "moves": moves, "arcs": arcs}
        G = gauge_of(op, gauge)
        entry["tool"]["gauge_length_mm"] = G
        if G is not None:
            A_c, b_c = machine_position_affine(rot, p, placement_mm=place, tool_radius_mm=0.0, gauge_length_mm=G)
            entry["controlled_machine_mm"] = _r(tip_part @ A_c[0].T + b_c[0], d)
        out_ops.append(entry)
    return out_ops


def test_neutral_matches_the_per_move_reference():
    """neutral_moves gives the same JSON text as the per-move reference, and neutral_json is that
    text: every profile, with and without gauge lengths, every number of decimals, coordinates that
    json prints in exponent form (below 1e-4) or with 16 digits and more."""
    from planning.post.neutral import neutral_json

    for k, name in enumerate(PROFILES):
        axis = unit(AXES[k + 1])
        mv = machine_visibility(axis, name)
        frame = area_frame(axis, cloud(k))
        no_gauge = [Operation(o.name, o.toolpath, o.tool_number, 6.0, "flat", 1000, 100, 50)
                    for o in random_ops(80 + k, quant=1024)]
        for ops, gauge, d in ((random_ops(70 + k), None, 4), (no_gauge, 123.0, 2),
                              (random_ops(75 + k, 60, scale=1e-3), None, 6),
                              (random_ops(76 + k, 60, scale=3e11), None, 5), (random_ops(77 + k, 60), 95.0, 0)):
            kw = {"tool_axis": axis, "rotary_deg": mv.angles_deg[0], "profile": name,
                  "placement_mm": [1.0, -2.0, 60.0], "setup_id": 1, "area_id": 2, "gauge_length_mm": gauge,
                  "decimals": d}
            doc = neutral_moves(ops, frame, **kw)
            reference = dict(doc, operations=_reference_neutral_operations(ops, frame, **kw))
            assert json.dumps(doc) == json.dumps(reference)
            assert neutral_json(ops, frame, **kw) == json.dumps(doc, separators=(",", ":"))


def _per_move_length_mm(tp, kinds):
    """Reference: the path length move by move with the scalar arc_sweep_rad."""
    from planning.toolpath.moves import PLANE_AXES, arc_sweep_rad
    total = 0.0
    for i in range(1, tp.n_moves):
        if tp.kind[i] not in kinds:
            continue
        s, e = tp.xyz_mm[i - 1], tp.xyz_mm[i]
        if tp.kind[i] in (ARC_CW, ARC_CCW):
            _, sw, r = arc_sweep_rad(s, e, tp.centre_mm[i], tp.plane[i], tp.kind[i] == ARC_CCW)
            n = PLANE_AXES[int(tp.plane[i])][2]
            total += math.hypot(abs(sw) * r, e[n] - s[n])
        else:
            total += float(np.linalg.norm(e - s))
    return total


def test_path_lengths_match_path_length_mm():
    from planning.toolpath.moves import path_length_mm

    for seed in range(4):
        tp = random_toolpath(90 + seed, 1000, quant=None if seed % 2 else 256)
        for kinds in ((FEED, ARC_CW, ARC_CCW), (RAPID,), (ARC_CW,)):
            length = path_length_mm(tp, kinds=kinds)
            assert length == pytest.approx(_per_move_length_mm(tp, kinds), rel=1e-12, abs=1e-9)
