"""LinuxCNC's rs274 keeps the tool table in $HOME/.tool.mmap: runs at the same time under one HOME
read each other's tool lengths (an order-dependent CI failure: machine Z 13-14 mm off, the gauge
lengths of two tests apart). Each run of planning.simulate.rs274 has its own HOME: many runs at once,
each with its own tool length, all read their own. (With one HOME for all, 3 of 4 runs of this test
failed: the overlap is a race, so it cannot fail every time.)"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from planning.orientations.kinematics import load_profile
from planning.simulate.motion import ToolShape
from planning.simulate.rs274 import INSTALL_HINT, rs274_available, run_rs274

# a long enough program that runs overlap: the tool length is read at every G43 and used on every move
PROGRAM = "\n".join(["G21 G90 G94 G17 G40 G49 G80", "G54", "T1 M6", "G43 H1"]
                    + [f"G1 X{(k % 40) - 20}. Y{(k // 40) % 30 - 15}. Z{5 + k % 7}. F1000." for k in range(3000)]
                    + ["G53 G0 Z0", "M30"]) + "\n"


def _one(gauge: float) -> float:
    prof = load_profile("compact_trunnion_bc")
    tools = {1: ToolShape(1, "ball", 3.0, 3.0, 12.0, (), gauge)}
    m = run_rs274(PROGRAM, program="p", area=0, profile=prof, placement_mm=np.zeros(3), tools=tools)
    feed = m.kind == 1
    # the tool tip in the part frame does not depend on the tool length; the controlled point
    # (machine Z) is the tip plus it
    return float(np.max(np.abs(m.machine_mm[feed, 2] - m.end_mm[feed, 2] - gauge)))


def test_runs_at_the_same_time_keep_their_own_tool_lengths():
    assert rs274_available(), INSTALL_HINT
    gauges = [90.0 + 7.0 * k for k in range(8)] * 10
    with ThreadPoolExecutor(max_workers=8) as pool:
        off = list(pool.map(_one, gauges))
    assert max(off) < 1e-3, off
