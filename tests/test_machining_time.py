"""One machining time (issue 34): the simulated time of a program is the time the control takes to run it,
each feed move at the F word in force on its line (G93 inverse time: 1/F minutes per line), rapids at
post.rapid_mm_min. Checked against hand-computed times on a hand-written LinuxCNC program, and against
the tool paths' estimate on a real plan (the program adds only tool changes and moves to the machine's Z0)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planning.inputs import samples
from planning.inputs.cloud import Cloud
from planning.orientations.kinematics import load_profile
from planning.pipeline import run_plan
from planning.simulate.motion import RAPID, ToolShape
from planning.simulate.program import read_program
from planning.simulate.verify import move_minutes
from schemas.params import parse_config

BC = load_profile("compact_trunnion_bc")
PLACE = np.array([1.0, 2.0, 40.0])
TOOLS = {1: ToolShape(1, "ball", 3.0, 3.0, 12.0, (), 100.0), 2: ToolShape(2, "flat", 5.0, 0.0, 30.0, (), 100.0)}


def program(lines):
    return "\n".join(["G21 G90 G94 G17 G40 G49 G80", "G54", "G53 G0 Z0", "T1 M6", "G0 B0 C0", "G43 H1",
                      "G0 X10. Y-5. Z80."] + lines + ["G53 G0 Z0", "G49", "M30"])


def test_feeds_are_the_programs_f_words_and_g93_lines_take_one_over_f():
    cfg = parse_config({"post": {"rapid_mm_min": 6000.0, "feed_mm_min": 1234.0}})
    text = program(["G1 Z60. F100.",                 # 20 mm at 100 mm/min: 0.2 min
                    "X30. F400.",                    # 20 mm at 400: 0.05 min
                    "G18 G3 X34. Z64. I0. K4.",      # three quarters of r 4 at 400
                    "G17",
                    "G93 G1 X44. F2.",               # inverse time: 1/2 min whatever its length
                    "X45. F10.",                     # 0.1 min
                    "G94 G1 X50. F250."])            # 5 mm at 250: 0.02 min
    m = read_program(text, dialect="linuxcnc", program="t.ngc", area=0, profile=BC, placement_mm=PLACE, tools=TOOLS)
    minutes = move_minutes(m, cfg)
    length = np.linalg.norm(m.end_mm - m.start_mm, axis=1)
    by_line = {ln: float(minutes[m.line == ln].sum()) for ln in np.unique(m.line)}
    assert by_line[8] == pytest.approx(0.2, rel=1e-9)
    assert by_line[9] == pytest.approx(0.05, rel=1e-9)
    arc = m.line == 10
    assert by_line[10] == pytest.approx(length[arc].sum() / 400.0, rel=1e-9)
    # G18 G3 turns about +Y from -Z through -X and +Z to +X: three quarters of r 4
    assert by_line[10] == pytest.approx(0.75 * 2 * math.pi * 4 / 400.0, rel=1e-3)     # chords ~ the arc
    assert by_line[12] == pytest.approx(0.5, rel=1e-9)
    assert by_line[13] == pytest.approx(0.1, rel=1e-9)
    assert by_line[14] == pytest.approx(0.02, rel=1e-9)
    rapid = m.kind == RAPID
    assert minutes[rapid].sum() == pytest.approx(length[rapid].sum() / 6000.0, rel=1e-9)
    # the tool's nominal feed (1234) is not what the control runs
    assert not np.isclose(minutes[~rapid].sum(), length[~rapid].sum() / 1234.0, rtol=1e-3)


def test_simulated_time_agrees_with_the_paths_estimate_on_a_plan():
    """The paths' estimate models the same moves (its links and retracts at post.plunge_mm_min, where the
    post writes some as rapids or at other F words; the programs add tool changes and moves to the
    machine's Z0): per operation the two agree within 10 %, and the area's time is its operations'."""
    s = samples.half_sphere()
    cloud = Cloud(points=s.points, normals=s.normals, source_format="generated")
    res = run_plan(cloud, parse_config({"setups": {"max_setups": 2}, "tool": {"diameter_mm": 10},
                                        "normals": {"method": "input"}}), name="hs").result
    v = res.verification
    assert v is not None and v.status == "passed"
    for av in v.areas:
        path = next(s.path for s in res.setups if s.id == av.area)
        ops = {op.operation: op for op in av.operations}
        for name, est in (("roughing", path.roughing), ("finishing", path.finishing)):
            if est is None:
                continue
            sim = ops[name].machining_time_s
            assert 0.9 * est.machining_time_s <= sim <= 1.1 * est.machining_time_s + 30.0, (av.area, name)
        assert av.machining_time_s == pytest.approx(sum(op.machining_time_s for op in av.operations), abs=0.2)
