"""Tool paths and NC programs from the whole pipeline on the paper's half sphere (issue 5 acceptance):
finishing paths and G-code for every area, gouge free (minimal clearance >= R - 0.01 mm, measured
again here independently), plan.npz cl_i, and the programs read back onto the CL points."""

from __future__ import annotations

import json

import numpy as np
import pytest
from gcode_reader import Machine, read_program
from scipy.spatial import cKDTree

from planning.inputs.cloud import Cloud
from planning.orientations.kinematics import load_profile
from planning.pipeline import run_plan
from planning.report.plan_files import write_plan
from planning.inputs.samples import half_sphere
from planning.toolpath.moves import ARC_CCW, ARC_CW, FEED, densify
from schemas.params import parse_config
from schemas.plan import PlanResult

CONFIG = {
    "normals": {"method": "input"},
    "orientations": {"sampling": "phi_theta", "phi_step_deg": 10, "theta_step_deg": 30},
    "tool": {"diameter_mm": 10},
    "visibility": {"cone_deg": [10, 80]},
    "setups": {"coverage": 0.95, "max_setups": 2, "min_points": 1},
    "paths": {"finishing": {"scallop_mm": 0.1}},
    # these tests are about the paths and the posts; tests/test_verification.py runs the simulation
    "simulate": {"enabled": False},
}
R = 5.0


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    s = half_sphere()
    cloud = Cloud(points=s.points, normals=s.normals, source_format="generated")
    out = run_plan(cloud, parse_config(CONFIG), name="half_sphere")
    d = tmp_path_factory.mktemp("plan")
    write_plan(out, d)
    return out, d


def test_every_area_has_gouge_free_finishing_and_programs(plan):
    out, d = plan
    res = PlanResult.model_validate(json.loads((d / "plan.json").read_text()))
    assert res.selection.k == 2 and len(res.setups) == 2
    npz = np.load(d / "plan.npz")
    for st in res.setups:
        p = st.path
        assert p is not None and p.finishing is not None
        f = p.finishing
        assert f.gouge_free and f.min_clearance_mm >= R - 0.01
        assert f.n_passes > 10 and f.n_cl == npz[f"cl_{st.id}"].shape[0] > 0
        assert f.n_cl < f.n_cl_before_reduction and f.n_arcs > 0
        assert set(p.programs) == {"iso", "linuxcnc"}
        for name in list(p.programs.values()) + [p.moves]:
            assert (d / name).is_file() and (d / name).stat().st_size > 1000
        text = (d / p.programs["iso"]).read_text()
        assert "G68.2" in text and "M30" in text


def test_clearance_measured_again_by_sampling_the_final_path(plan):
    """The reported minimal clearance against an independent measure: the final moves (arcs
    included) sampled every 0.02 mm, nearest cloud point by KD-tree. Sampling can only over-estimate
    the true minimum, by at most half the spacing."""
    out, _ = plan
    pts = out.points
    for ap in out.extra["area_paths"]:
        tp = ap.finishing
        cut = np.isin(tp.kind, [FEED, ARC_CW, ARC_CCW])
        q, mv = densify(tp, 0.02)
        keep = cut[mv] & (mv > 0)
        # a sample is on move mv; the move's start point belongs to it as well
        d, _ = cKDTree(ap.frame.to_frame(pts)).query(q[keep])
        sampled = float(d.min())
        assert sampled >= R - 0.01 - 1e-9
        assert ap.min_clearance_mm <= sampled + 1e-9
        if ap.min_clearance_mm < R:
            assert sampled <= ap.min_clearance_mm + 0.011


def test_cl_arrays_are_ball_centres_in_the_part_frame(plan):
    out, _ = plan
    for ap in out.extra["area_paths"]:
        cl = out.arrays[f"cl_{ap.area}"]
        assert np.allclose(cl, ap.frame.to_part(ap.finishing.xyz_mm))
        # every cutting CL point is at least R - tol from every cloud point: never inside the ball
        cut = np.isin(ap.finishing.kind, [FEED, ARC_CW, ARC_CCW])
        d, _ = cKDTree(out.points).query(cl[cut])
        assert d.min() >= R - 0.01


def _finishing_moves(prog, tool_number):
    return [m for m in prog.moves if m.tool == tool_number]


def test_programs_read_back_onto_the_cl_points(plan):
    """Both posts parsed back (tests/gcode_reader.py), rotations undone: the finishing tool's tip
    positions, in order, are the CL points less R along the tool axis (within the 4 decimals)."""
    out, d = plan
    cfg = out.result.parameters
    profile = load_profile(cfg.machine.profile)
    placement = out.result.visibility.placement_mm
    by_id = {st.id: st for st in out.result.setups}
    for ap in out.extra["area_paths"]:                    # in the machining order
        st = by_id[ap.area]
        axis = np.asarray(st.tool_axis)
        tips = out.arrays[f"cl_{ap.area}"] - R * axis
        machine = Machine(kinematics=profile.kinematics, placement_mm=tuple(placement),
                          pivot_mm=tuple(profile.pivot_mm))
        for dialect, reader_machine in (("iso", None), ("linuxcnc", machine)):
            prog = read_program((d / st.path.programs[dialect]).read_text(), reader_machine)
            got = np.array([m.end for m in _finishing_moves(prog, cfg.post.finishing_tool_number)])
            assert got.shape[0] >= tips.shape[0]
            # every CL point appears, in order, among the programmed ends (LinuxCNC may add chord
            # points where it linearises an arc)
            j = _subsequence(got, tips, 2e-4)
            assert j == tips.shape[0], f"{dialect}: CL point {j} not found in order"


def _subsequence(got, want, tol):
    """How many of ``want`` occur in order in ``got`` (each within ``tol``)."""
    j = 0
    for p in got:
        if j < want.shape[0] and np.all(np.abs(p - want[j]) <= tol):
            j += 1
    return j
