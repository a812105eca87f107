"""The verification stage (issue 15) in the plan: the posted programs run on the simulated machine and
stock, the verdict in plan.json, the CLI's exit status and the artifacts; it finds today's defects
(it must be able to fail: the unguarded programs, paths.carry_stock=false) and passes the guarded
programs of a default plan (issue 16)."""

import json
import math

import numpy as np
import pytest
from plyfile import PlyData

from planning.inputs.cloud import read_cloud
from planning.inputs.samples import make_sample
from planning.pipeline import run_plan
from planning.report.files import write_ply
from planning.report.plan_files import write_plan
from planning.simulate.verify import deviation_figures, verification_status
from schemas.params import apply_overrides, parse_config
from schemas.plan import DeviationFigures, Verification

FAST = ["paths.finishing.scallop_mm=0.2", "paths.roughing.step_down_mm=5", "simulate.resolution_mm=1.0"]


def _write_sample(name, path):
    s = make_sample(name)
    write_ply(path, s.points, normals=s.normals)


@pytest.fixture(scope="module")
def slot_plan(tmp_path_factory):
    out = tmp_path_factory.mktemp("slot")
    cloud_path = out / "slot.ply"
    _write_sample("slot", cloud_path)
    cloud = read_cloud(cloud_path)
    outcome = run_plan(cloud, parse_config(apply_overrides({}, FAST)), name="slot.ply")
    paths = write_plan(outcome, out / "plan")
    return outcome, paths


@pytest.fixture(scope="module")
def unguarded_slot_plan(tmp_path_factory):
    """The slot planned as before issue 16: every set-up roughs its full stock box and nothing is
    guarded (paths.carry_stock=false): the programs have real defects for the verification to find."""
    out = tmp_path_factory.mktemp("slot_unguarded")
    cloud_path = out / "slot.ply"
    _write_sample("slot", cloud_path)
    outcome = run_plan(read_cloud(cloud_path), parse_config(apply_overrides({}, FAST + ["paths.carry_stock=false"])),
                       name="slot.ply")
    return outcome, write_plan(outcome, out / "plan")


def test_the_guarded_slot_programs_pass_verification(slot_plan):
    """Issue 16 acceptance on the slot: the programs of a default plan run clean on the simulated
    machine and stock (no rapid into material, no shank, holder or fixture contact, nothing beyond
    the travel, no gouge), every set-up cuts, and the verdict reaches plan.json as written."""
    outcome, paths = slot_plan
    v = outcome.result.verification
    assert v is not None and v.status == "passed", v.message
    assert v.dialect == "linuxcnc" and v.resolution_mm == 1.0
    assert (v.travel_excursions, v.rapids_into_material, v.holder_collisions, v.fixture_collisions,
            v.unreadable_programs, v.deviation.n_gouged) == (0, 0, 0, 0, 0, 0)
    assert len(v.areas) == len(outcome.result.setups)
    assert [a.area for a in v.areas] == outcome.result.machining_order
    assert all(a.removed_mm3 > 0 for a in v.areas)
    assert v.deviation is not None and 0 < v.deviation.n_points == outcome.points.shape[0]
    assert v.deviation.finished_share > 0.7
    doc = json.loads(paths["plan_json"].read_text())
    assert doc["verification"]["status"] == "passed"
    assert doc["artifacts"]["deviation_png"] == "deviation.png"


def test_the_unguarded_slot_programs_fail_verification_with_the_defects_on_their_lines(unguarded_slot_plan):
    outcome, paths = unguarded_slot_plan
    v = outcome.result.verification
    assert v is not None and v.status == "failed"
    assert v.rapids_into_material + v.holder_collisions + v.fixture_collisions > 0
    worst = [o for o in v.worst if o.kind in ("rapid_into_material", "holder_collision", "fixture_collision")]
    assert worst
    text = outcome.extra["programs"][worst[0].program].splitlines()
    assert text[worst[0].line - 1].lstrip().startswith(("G0", "G1", "G2", "G3", "X", "Y", "Z"))
    assert json.loads(paths["plan_json"].read_text())["verification"]["status"] == "failed"


def test_the_artifacts_are_the_scan_by_deviation_and_the_stock_mesh(slot_plan):
    outcome, paths = slot_plan
    ply = PlyData.read(str(paths["deviation_ply"]))
    vx = ply["vertex"]
    assert vx.count == outcome.points.shape[0]
    assert "deviation_mm" in vx.data.dtype.names
    dev = np.asarray(vx["deviation_mm"])
    assert np.nanmax(dev) > 0                                # material left somewhere (the slot's floor)
    # the exact finish of every point (a small scan: all of them measured), as the plan's figures count it
    left = np.asarray(vx["finish_left_mm"], dtype=np.float64)
    assert not np.isnan(left).any()
    f, fp = outcome.result.verification.finish, outcome.result.parameters.paths.finishing
    done = np.isfinite(left) & (left <= f.limit_mm) & (left >= -(fp.tolerance_mm + 0.0051))
    assert abs(done.mean() - f.finished_share) < 1e-4       # float32 in the file
    mesh = PlyData.read(str(paths["stock_ply"]))
    assert mesh["face"].count > 100 and mesh["vertex"].count > 100
    assert paths["deviation_png"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_exits_4_when_the_verification_fails_and_0_when_it_is_off(tmp_path, capsys):
    from scanmill.cli import main

    cloud = tmp_path / "slot.ply"
    _write_sample("slot", cloud)
    sets = [a for s in FAST + ["paths.carry_stock=false"] for a in ("--set", s)]
    assert main(["plan", str(cloud), "--out", str(tmp_path / "p"), "--quiet"] + sets) == 4
    printed = capsys.readouterr().out
    assert "verification: FAILED" in printed
    assert main(["plan", str(cloud), "--out", str(tmp_path / "q"), "--quiet", "--set", "simulate.enabled=false"]
                + sets) == 0
    doc = json.loads((tmp_path / "q" / "plan.json").read_text())
    assert doc["verification"]["status"] == "skipped"


def test_deviation_figures_and_the_verdict_rules():
    dev = np.array([0.0, 0.005, -0.005, 0.5, -0.2, np.nan])
    f = deviation_figures(dev, limit_mm=0.02, gouge_mm=0.01)
    assert f.n_points == 5 and f.finished_share == pytest.approx(3 / 5)
    assert f.left_max_mm == pytest.approx(0.5) and f.gouge_max_mm == pytest.approx(0.2) and f.n_gouged == 1
    # the exact depth decides: a reading the tools never cut that deep is an artefact, not a gouge
    exact = np.array([np.nan, np.nan, np.nan, np.nan, 0.005, np.nan])
    g = deviation_figures(dev, limit_mm=0.02, gouge_mm=0.01, exact_depth=exact, exact_limit_mm=0.011)
    assert g.n_suspected == 1 and g.n_gouged == 0 and g.gouge_max_mm == pytest.approx(0.005)
    exact[4] = 0.15
    g = deviation_figures(dev, limit_mm=0.02, gouge_mm=0.01, exact_depth=exact, exact_limit_mm=0.011)
    assert g.n_suspected == 1 and g.n_gouged == 1 and g.gouge_max_mm == pytest.approx(0.15)
    clean = Verification(status="passed", message="", deviation=DeviationFigures(
        n_points=1, finished_share=1.0, left_p50_mm=0, left_p95_mm=0, left_max_mm=0, gouge_max_mm=0, n_gouged=0))
    assert verification_status(clean) == "passed"
    for field in ("travel_excursions", "rapids_into_material", "holder_collisions", "fixture_collisions"):
        bad = clean.model_copy(update={field: 1})
        assert verification_status(bad) == "failed"
    gouged = clean.model_copy(update={"deviation": clean.deviation.model_copy(update={"n_gouged": 1})})
    assert verification_status(gouged) == "failed"
    assert math.isfinite(f.left_p95_mm)


def test_rs274_and_our_reader_cut_the_same_stock_and_find_the_same_offences(unguarded_slot_plan):
    """LinuxCNC's interpreter is the independent reader: its canonical moves, simulated, give the
    same final stock and the same offence counts as our reading of the program text."""
    from planning.orientations.kinematics import load_profile
    from planning.simulate.models import build_models
    from planning.simulate.program import read_program
    from planning.simulate.rs274 import run_rs274
    from planning.simulate.run import run_moves
    from planning.simulate.verify import stock_extent, tool_shapes as _tools

    outcome, _ = unguarded_slot_plan
    p = outcome.result.parameters
    profile = load_profile(p.machine.profile)
    place = np.asarray(outcome.result.visibility.placement_mm, dtype=float)
    tools = _tools(p, p.tool.assembly())
    name = "area_0.linuxcnc.nc"
    text = outcome.extra["programs"][name]
    lo, hi = stock_extent(outcome.points, p.stock)
    figures, volumes = {}, {}
    for reader in ("ours", "rs274"):
        if reader == "ours":
            motion = read_program(text, dialect="linuxcnc", program=name, area=0, profile=profile,
                                  placement_mm=place, tools=tools)
        else:
            motion = run_rs274(text, program=name, area=0, profile=profile, placement_mm=place, tools=tools)
        models = build_models(lo, hi, p, [], tools, resolution_mm=1.0)
        run = run_moves(models.stock, models.obstacles, motion, tools)
        volumes[reader] = models.stock.volume_mm3()
        figures[reader] = ((run.rapid_depth_mm > 0).sum(), (run.holder_depth_mm > 0).sum(), run.removed_mm3.sum())
    assert volumes["ours"] == pytest.approx(volumes["rs274"], rel=1e-4)
    assert figures["ours"][2] == pytest.approx(figures["rs274"][2], rel=1e-3)
    for a, b in zip(figures["ours"][:2], figures["rs274"][:2]):
        assert abs(int(a) - int(b)) <= max(2, 0.01 * max(a, b))
    assert figures["ours"][0] > 0 and figures["ours"][1] > 0          # the offences are there to agree on


def test_a_program_the_reader_refuses_fails_the_verification_without_losing_the_plan(slot_plan):
    from planning.geometry.fixtures import TableFixture
    from planning.orientations.kinematics import load_profile
    from planning.simulate.verify import verify_plan

    outcome, _ = slot_plan
    p = outcome.result.parameters
    programs = dict(outcome.extra["programs"])
    programs["area_0.linuxcnc.nc"] = programs["area_0.linuxcnc.nc"].replace("G21", "G20", 1)   # inches
    sim = verify_plan(programs=programs, order=outcome.result.machining_order or len(outcome.result.setups), config=p,
                      profile=load_profile(p.machine.profile), placement_mm=outcome.result.visibility.placement_mm,
                      tool=p.tool.assembly(), fixtures=[TableFixture(z_mm=-200.0)], points=outcome.points,
                      normals=np.tile([0, 0, 1.0], (outcome.points.shape[0], 1)), input_labels=outcome.input_labels)
    v = sim.verification
    assert v.status == "failed" and v.unreadable_programs == 1
    assert "could not be read" in v.message and any("area_0.linuxcnc.nc" in n for n in v.notes)
    assert [a.area for a in v.areas] == [1]                      # the other area was still run


def test_a_mesh_blank_is_the_stock_and_the_service_refuses_its_path(tmp_path):
    import open3d as o3d

    from planning.errors import InputError, ParameterError
    from planning.simulate.models import build_models, load_blank
    from planning.simulate.motion import ToolShape
    from schemas.params import StockParams
    from service.intake import check_service_parameters

    box = o3d.geometry.TriangleMesh.create_box(40.0, 30.0, 20.0)
    o3d.io.write_triangle_mesh(str(tmp_path / "blank.stl"), box.compute_triangle_normals())
    cfg = parse_config({"stock": {"type": "mesh", "path": "blank.stl"}})
    blank = load_blank(cfg.stock, base_dir=tmp_path)
    tools = {1: ToolShape(1, "ball", 3.0, 3.0, 12.0, (), 100.0)}
    models = build_models(blank.vertices.min(0), blank.vertices.max(0), cfg, [], tools, resolution_mm=0.5,
                          blank=blank)
    assert models.stock.volume_mm3() == pytest.approx(40 * 30 * 20, rel=0.01)
    with pytest.raises(InputError):
        load_blank(StockParams(type="mesh", path="missing.stl"), base_dir=tmp_path)
    with pytest.raises(ParameterError, match="CLI"):
        check_service_parameters(cfg)
    with pytest.raises(ParameterError):
        parse_config({"stock": {"type": "mesh"}})


def test_the_deviation_read_in_chunks_is_the_same_and_reports_each(slot_plan, monkeypatch):
    """Issue 17 item 3: on a large scan the deviation is read in chunks that report progress; per
    point the reading is the same as in one call."""
    import planning.simulate.verify as verify

    outcome, _ = slot_plan
    sim = outcome.extra["simulation"]
    monkeypatch.setattr(verify, "DEVIATION_CHUNK", outcome.points.shape[0] // 3 + 1)
    said = []
    # the same verification (same mode, so the same stock) read in three chunks
    again = outcome.extra["verify_again"](sim.verification.mode, progress=lambda f, m: said.append(m))
    assert again.verification.mode == sim.verification.mode
    assert np.array_equal(again.deviation_mm, sim.deviation_mm, equal_nan=True)
    assert sum("deviation of the scan" in m for m in said) == 3


def test_the_viewer_marks_and_lists_the_offences_of_a_failed_plan(unguarded_slot_plan):
    """Issue 20: the viewer's data carries the verification's worst offences, and the page (real headless
    Chromium through `scanmill view`) lists each with its program line and draws its marker."""
    import re
    import subprocess
    import sys
    import time

    from browser import canvas_pixels, chromium, js_errors, wait_viewer
    from service_fixtures import ROOT

    outcome, paths = unguarded_slot_plan
    worst = outcome.result.verification.worst
    index = json.loads(paths["viewer_json"].read_text())
    assert index["verification"]["status"] == "failed"
    assert [(o["kind"], o["program"], o["line"]) for o in index["offences"]] == \
        [(o.kind, o.program, o.line) for o in worst]
    proc = subprocess.Popen([sys.executable, "-m", "scanmill.cli", "view", str(paths["plan_json"].parent)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        url = re.search(r"(http://\S+)", proc.stdout.readline()).group(1)
        with chromium() as browser:
            for _ in range(50):                       # the server may take a moment to listen
                browser.get(url)
                if "scanmill" in browser.title:
                    break
                time.sleep(0.2)
            state = wait_viewer(browser)
            assert state["ready"], state
            rows = browser.find_elements("css selector", "#offences tbody tr")
            assert len(rows) == len(worst)
            assert f"{worst[0].program}" in rows[0].text and str(worst[0].line) in rows[0].text
            assert browser.find_element("id", "verdict").text.lower() == "verification failed"
            px = canvas_pixels(browser)
            magenta = np.all(np.abs(px.astype(int) - [255, 0, 255]) <= 2, axis=-1)
            assert magenta.sum() >= 50
            assert js_errors(browser) == []
    finally:
        proc.terminate()
        proc.wait(timeout=30)
