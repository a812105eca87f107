"""Issue 31 item 3: semi-finishing (planning/toolpath/semi_finishing.py, docs/design.md "Semi-finishing").

* On an analytic surface (a plane with a spherical bump), the pass keeps its cutter ``allowance_mm`` off
  the surface within its tolerance, measured independently of the planner: every sampled ball centre of
  the final moves (lines and arcs) against the exact surface; over the plane the centres run at
  ``r + allowance`` and the tips at ``allowance``.
* On the half sphere's light plan with the pass on: the programs verify clean (no offence, no gouge),
  the pass is its own tool in every program, LinuxCNC's interpreter reads it within the travel, the
  single-pass verdict equals the independent one, and the stock the finishing meets is even: its p95
  over the scan within twice the roughing allowance, where after the roughing alone it is not.
* Its parameters refuse what cannot work, with the parameter named.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from test_safe_programs import LIGHT, _assert_clean, _counts, _plan

from planning.errors import ParameterError
from planning.simulate.program import check_travel
from planning.simulate.rs274 import INSTALL_HINT, rs274_available, run_rs274
from planning.simulate.verify import tool_shapes
from planning.toolpath.moves import USE_CUT
from planning.toolpath.safety import cutting_positions
from planning.toolpath.semi_finishing import plan_semi_finishing, semi_tool
from schemas.params import parse_config

SEMI = ["paths.semi_finishing.enabled=true", "paths.semi_finishing.scallop_mm=0.2"]


# -- the pass on an analytic surface ---------------------------------------------------------------------

BUMP_R = 12.0        # a sphere of this radius, its centre BUMP_DROP below the plane z = 0
BUMP_DROP = 6.0


def _bump_points(spacing: float = 0.4) -> np.ndarray:
    """Points on the plane z = 0 over a 60 x 40 mm square, raised onto the spherical bump where it is above it."""
    x, y = np.meshgrid(np.arange(-30.0, 30.0 + 1e-9, spacing), np.arange(-20.0, 20.0 + 1e-9, spacing), indexing="ij")
    z = np.sqrt(np.maximum(BUMP_R ** 2 - x ** 2 - y ** 2, 0.0)) - BUMP_DROP
    return np.column_stack([x.ravel(), y.ravel(), np.maximum(z, 0.0).ravel()])


def _distance_to_surface(c: np.ndarray) -> np.ndarray:
    """Exact distance from points ``c`` (n,3) above the surface to the union of the plane and the bump
    (both solids below the surface): the smaller of the distance to the half space z <= 0 and to the ball."""
    to_plane = np.maximum(c[:, 2], 0.0)
    to_ball = np.linalg.norm(c - np.array([0.0, 0.0, -BUMP_DROP]), axis=1) - BUMP_R
    return np.minimum(to_plane, np.maximum(to_ball, 0.0))


def test_the_pass_keeps_its_allowance_off_an_analytic_surface():
    cfg = parse_config({"paths": {"semi_finishing": {"enabled": True, "diameter_mm": 8.0, "allowance_mm": 0.3,
                                                     "scallop_mm": 0.05, "tolerance_mm": 0.02}}})
    sp, fp = cfg.paths.semi_finishing, cfg.paths.finishing
    tool = semi_tool(cfg)
    r, a, tol = tool.radius_mm, sp.allowance_mm, sp.tolerance_mm
    assert r == pytest.approx(4.0)
    pts = _bump_points()
    inside = (np.abs(pts[:, 0]) < 22.0) & (np.abs(pts[:, 1]) < 12.0)         # the area; the rest is its margin
    out = plan_semi_finishing(pts, [inside], None, sp=sp, fp=fp, tool=tool, safe_tip_z_mm=20.0,
                              max_slope_deg=80.0)
    tp = out.toolpath
    assert tp is not None and tp.n_moves > 100
    assert tp.tip_offset_mm == pytest.approx(r)                 # the posts drive the real cutter's tip
    assert out.offset_radius_mm == pytest.approx(r + a)
    centres = cutting_positions(tp, 0.1)
    d = _distance_to_surface(centres)
    # no cutting position brings the cutter's ball closer than the allowance (less the tolerance)
    assert d.min() >= r + a - tol - 1e-6, d.min() - r
    assert out.gouge_free and out.min_clearance_mm >= r + a - tol - 1e-9
    # and it is not kept needlessly far: over the flat part the dense CL points of the passes (before the
    # reduction) run at r + a (the ball rests on the plane), over the bump at r + a from the sphere
    dense = out.passes.toolpath
    cl = dense.xyz_mm[dense.use == USE_CUT]
    flat = (np.abs(cl[:, 0]) < 20.0) & (np.abs(cl[:, 1]) < 10.0) \
        & (np.hypot(cl[:, 0], cl[:, 1]) > math.sqrt(BUMP_R ** 2 - BUMP_DROP ** 2) + r + a + 1.0)
    assert flat.sum() > 100
    assert np.abs(cl[flat, 2] - (r + a)).max() <= tol + 1e-6
    bump = np.hypot(cl[:, 0], cl[:, 1]) < 5.0
    assert bump.sum() > 10
    assert np.abs(_distance_to_surface(cl[bump]) - (r + a)).max() <= tol + 1e-6
    # the whole area is passed over: every point of it lies under a sampled centre's ball grown by the allowance
    from scipy.spatial import cKDTree

    near, _ = cKDTree(centres).query(pts[inside & (np.abs(pts[:, 0]) < 20) & (np.abs(pts[:, 1]) < 10)])
    assert near.max() <= r + a + sp.scallop_mm + 0.6       # the side step on a plane is 1.4 mm: within reach


# -- the pass in a plan ----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def semi_plan():
    return _plan("half_sphere", LIGHT + SEMI)


def test_a_plan_with_semi_finishing_verifies_clean(semi_plan):
    _assert_clean(semi_plan, "half_sphere + semi-finishing")
    v = semi_plan.result.verification
    p = semi_plan.result.parameters
    for a in v.areas:
        ops = [o.operation for o in a.operations]
        assert ops == ["roughing", "semi_finishing", "finishing"], (a.program, ops)
        semi = next(o for o in a.operations if o.operation == "semi_finishing")
        assert semi.tool == p.post.semi_finishing_tool_number
        assert semi.removed_mm3 > 1000.0                         # it cuts the roughing's stair, mm^3
        prog = semi_plan.extra["programs"][f"area_{a.area}.linuxcnc.nc"]
        assert f"T{p.post.semi_finishing_tool_number} M6" in prog
    for st in semi_plan.result.setups:
        s = st.path.semi_finishing
        assert s is not None and s.n_cl > 100 and s.guard is not None
        assert s.min_clearance_mm >= s.allowance_mm - p.paths.semi_finishing.tolerance_mm - 1e-6


def test_the_finishing_meets_an_even_stock_after_semi_finishing(semi_plan):
    """Issue 31 item 3's measure, on the stock: the material over the scan points along their normals
    when the finishing starts; its p95 within twice the roughing allowance (1 mm), where the roughing
    alone leaves more (its stair on the sphere's slopes)."""
    rough_allowance = semi_plan.result.parameters.paths.roughing.stock_allowance_mm
    for st in semi_plan.result.setups:
        s = st.path.semi_finishing
        before, after = s.allowance_before_mm, s.allowance_after_mm
        assert before["n"] > 500 and after["n"] == before["n"]
        assert before["p95"] > 2 * rough_allowance, before           # what the stair was
        assert after["p95"] <= 2 * rough_allowance, after
        assert after["p50"] < before["p50"] and after["p50"] == pytest.approx(s.allowance_mm, abs=0.1)
        assert st.path.roughing.allowance_left_mm == after          # what the finishing meets
        # where the pass reaches (most of the set-up), the layer is even: p95 within twice the allowance asked
        assert s.reached_share > 0.8 and s.allowance_reached_mm["n"] <= after["n"]
        assert s.allowance_reached_mm["p95"] <= 2 * rough_allowance, s.allowance_reached_mm


def test_rs274_reads_the_semi_finishing_programs_within_the_travel(semi_plan):
    assert rs274_available(), INSTALL_HINT
    from planning.orientations.kinematics import load_profile

    p = semi_plan.result.parameters
    profile = load_profile(p.machine.profile)
    tools = tool_shapes(p, p.tool.assembly())
    assert p.post.semi_finishing_tool_number in tools                 # the simulation knows the third tool
    place = np.asarray(semi_plan.result.visibility.placement_mm, dtype=float)
    for area in semi_plan.result.machining_order:
        prog = f"area_{area}.linuxcnc.nc"
        motion = run_rs274(semi_plan.extra["programs"][prog], program=prog, area=area, profile=profile,
                           placement_mm=place, tools=tools)
        assert (motion.tool == p.post.semi_finishing_tool_number).sum() > 100
        assert check_travel(motion, profile) == [], prog


def test_semi_finishing_single_pass_equals_the_independent_verification(semi_plan):
    single = semi_plan.result.verification
    assert single.mode == "single_pass" and "proven" in single.mode_note, single.mode_note
    independent = semi_plan.extra["verify_again"]("independent").verification
    assert _counts(single) == _counts(independent)
    for a, b in zip(single.areas, independent.areas, strict=True):
        assert a.removed_mm3 == pytest.approx(b.removed_mm3, rel=1e-3, abs=1.0), a.program
        for oa, ob in zip(a.operations, b.operations, strict=True):
            assert (oa.operation, oa.tool, oa.feed_mm) == (ob.operation, ob.tool, ob.feed_mm)
            # the programs' 1e-4 mm rounding of the semi-finishing moves shifts a few mm^3 of the thin layer
            # between it and the finishing over the ~20,000 mm^2 they cover; the program's total stays put
            assert oa.removed_mm3 == pytest.approx(ob.removed_mm3, rel=1e-3, abs=5.0), (a.program, oa.operation)


# -- parameters ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("doc, said", [
    ({"paths": {"semi_finishing": {"enabled": True, "allowance_mm": 0.5}}}, "semi_finishing.allowance_mm"),
    ({"paths": {"semi_finishing": {"enabled": True}, "finishing": {"enabled": False}}}, "finishing.enabled"),
    ({"paths": {"semi_finishing": {"enabled": True}}, "post": {"semi_finishing_tool_number": 2}},
     "semi_finishing_tool_number"),
])
def test_semi_finishing_parameters_that_cannot_work_are_refused(doc, said):
    with pytest.raises(ParameterError) as e:
        parse_config(doc)
    assert said in str(e.value)


def test_semi_finishing_off_adds_nothing_to_a_plan():
    """Off by default: no third tool in the simulation's tools, no semi-finishing step."""
    cfg = parse_config({})
    assert not cfg.paths.semi_finishing.enabled
    assert cfg.post.semi_finishing_tool_number not in tool_shapes(cfg, cfg.tool.assembly())


def test_the_summary_shows_the_semi_finishing_minutes(semi_plan):
    """plan.json figures carry each area's semi-finishing minutes (the simulated program's), and the CLI
    summary gets a column for them; the area's total is the sum of its three operations."""
    from scanmill.summary import summary_lines

    doc = semi_plan.result.model_dump(mode="json")
    by_area = {a.area: a for a in semi_plan.result.verification.areas}
    for a in doc["figures"]["areas"]:
        ops = {o.operation: o.machining_time_s for o in by_area[a["area"]].operations}
        assert a["semi_finishing_time_s"] == ops["semi_finishing"] > 0
        assert a["roughing_time_s"] + a["semi_finishing_time_s"] + a["finishing_time_s"] == \
            pytest.approx(a["machining_time_s"], abs=1.0)
    lines = summary_lines(doc)
    head = next(ln for ln in lines if "roughing min" in ln)
    assert "semi min" in head


# -- the deepest cut -------------------------------------------------------------------------------------

def test_the_depth_of_cut_is_the_chip_a_ball_takes_off_a_box():
    """On a box of stock whose top is the plane z = 10 (a tri-dexel, read through the frame), a ball of
    radius 4 whose lowest point is 1.5 mm under the top cuts 1.5 mm; one that hangs 0.3 mm above it cuts
    nothing; one beside the box's wall, its centre 1 mm outside the wall at mid height, cuts 3 mm
    (radially, into the wall); the limit blocks what is deeper than it."""
    from planning.simulate.dexel import TriDexel
    from planning.toolpath.frames import AreaFrame
    from planning.toolpath.semi_finishing import DepthLimit

    stock = TriDexel.box([0.0, 0.0, 0.0], [40.0, 40.0, 10.0], 0.5)
    frame = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
    lim = DepthLimit(stock, frame, (-10.0, -10.0), (50.0, 50.0), r=4.0, max_depth_mm=2.0, stop_z_mm=-5.0, cell_mm=0.25)
    c = np.array([[20.0, 20.0, 10.0 + 4.0 - 1.5],     # 1.5 mm into the top
                  [20.0, 20.0, 10.0 + 4.0 + 0.3],     # above it
                  [41.0, 20.0, 5.0],                  # 1 mm outside the wall x = 40: 3 mm into it
                  [20.0, 20.0, 10.0 + 4.0 - 2.5]])    # 2.5 mm into the top
    d = lim.depth_mm(c)
    assert d[0] == pytest.approx(1.5, abs=0.26)        # the ray reading and the 0.25 mm cells
    assert not d[1] > 0.0
    assert d[2] == pytest.approx(3.0, abs=0.26)
    assert d[3] == pytest.approx(2.5, abs=0.26)
    assert lim(c).tolist() == [False, False, True, True]


def test_the_depth_kernel_agrees_with_sampling_the_ball():
    """The radial depth over a rough random height field, against brute force: points on a fine grid
    inside the ball that lie under the field's top (the field solid below it), the deepest one."""
    from planning.toolpath.semi_finishing import _depth_kernel

    rng = np.random.default_rng(5)
    h, r = 0.5, 3.0
    top = rng.uniform(-2.0, 2.0, size=(30, 30))
    top[rng.random(top.shape) < 0.1] = -np.inf                 # cells with no material at all
    centres = np.column_stack([rng.uniform(4.0, 11.0, 40), rng.uniform(4.0, 11.0, 40), rng.uniform(-1.0, 4.0, 40)])
    out = np.empty(40)
    _depth_kernel(top, 0.0, 0.0, h, centres, r, out)
    for k, c in enumerate(centres):
        best = -np.inf
        i0, i1 = int(np.floor((c[0] - r) / h)), int(np.floor((c[0] + r) / h))
        j0, j1 = int(np.floor((c[1] - r) / h)), int(np.floor((c[1] + r) / h))
        zs = np.linspace(c[2] - r, c[2] + r, 601)
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                x, y = (i + 0.5) * h, (j + 0.5) * h
                q = np.column_stack([np.full_like(zs, x), np.full_like(zs, y), zs])
                dist = np.linalg.norm(q - c, axis=1)
                inside = (dist < r) & (zs <= top[i, j])
                if inside.any():
                    best = max(best, float(r - dist[inside].min()))
        if np.isfinite(best):
            assert out[k] == pytest.approx(best, abs=0.011), k
        else:
            assert not out[k] > -np.inf, k


def test_the_viewer_draws_the_semi_finishing_paths(semi_plan, tmp_path):
    """The viewer's data carries each area's semi-finishing path beside its finishing and roughing paths:
    every move's end point, at the tool tip in the part frame, is a vertex (within the quantisation)."""
    import json

    from scipy.spatial import cKDTree

    from planning.report.plan_files import write_plan
    from planning.report.viewer_data import dequantise
    from test_viewer import _arrays

    write_plan(semi_plan, tmp_path)
    index = json.loads((tmp_path / "viewer.json").read_text())
    box = index["paths"]["box"]
    step = float(np.max((np.array(box["max_mm"]) - box["min_mm"]) / 65535))
    items = {(i["area"], i["operation"]): i for i in index["paths"]["items"]}
    for ap in semi_plan.extra["area_paths"]:
        item = items[(ap.area, "semi_finishing")]
        a = _arrays(tmp_path, index, {"v": item["vertices"]})
        v = dequantise(a["v"], box["min_mm"], box["max_mm"])
        tips = ap.frame.to_part(ap.semi.toolpath.tip_mm())
        dist, _ = cKDTree(v).query(tips)
        assert dist.max() <= 2 * step, ap.area
    html = (Path(__file__).resolve().parents[1] / "scanmill/viewer/static/index.html").read_text()
    assert 'id="show-semi"' in html
