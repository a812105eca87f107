"""One plan, one story (issue 34): the plan's figures (plan.json ``figures``, planning/report/figures.py) are
computed once, and the CLI summary, plan.json's message and status, the service's result headline and the
pictures say the same. Each test names the contradiction it guards against (the issue's list):

- "unfinished pts" held only the unmachined count: the classes now partition every input point;
- two machining times (an estimate beside the simulated one): one time, the programs as the control runs them;
- pictures against numbers: the deviation PLY/PNG show the reported deviation, whose deepest cut is the plan's;
- a PASSED plan that finishes less than setups.coverage: status 'unfinished', exit status 5.
"""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from plyfile import PlyData

from planning.inputs import samples
from planning.inputs.cloud import Cloud
from planning.pipeline import run_plan
from planning.report.figures import (
    FINISHED,
    LEFT,
    NOT_COVERED,
    UNREACHED,
    apply_figures,
    point_classes,
)
from planning.report.plan_files import write_plan
from scanmill.cli import EXIT_OK, EXIT_UNFINISHED, exit_status
from scanmill.summary import summary_lines
from schemas.params import parse_config
from service.workers import plan_summary

CFG = {"normals": {"method": "input"}, "setups": {"max_setups": 2}, "tool": {"diameter_mm": 10},
       "paths": {"finishing": {"scallop_mm": 1.0}, "roughing": {"step_down_mm": 10}},
       "simulate": {"resolution_mm": 2.0}, "post": {"dialects": ["linuxcnc"]}}


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    s = samples.half_sphere(n_points=400)
    cloud = Cloud(points=s.points, normals=s.normals, source_format="generated")
    config = parse_config(CFG)
    outcome = run_plan(cloud, config, name="hs")
    out = tmp_path_factory.mktemp("plan")
    write_plan(outcome, out)
    return outcome, config, out


def test_point_classes_partition_in_the_documented_order():
    dev = np.array([0.0, 0.5, 0.5, 0.5, 0.05, np.nan])
    nc = np.array([False, False, True, True, True, False])
    cls = point_classes(6, deviation_mm=dev, limit_mm=0.1, not_covered=nc, unreached=np.array([1, 2, 4]))
    # finished first (even when not covered), then not covered, then unreached, the rest left
    assert cls.tolist() == [FINISHED, UNREACHED, NOT_COVERED, NOT_COVERED, FINISHED, LEFT]
    none = point_classes(6, deviation_mm=None, limit_mm=None, not_covered=nc, unreached=np.array([1]))
    assert FINISHED not in none.tolist()


def test_classes_partition_every_input_point_per_area(planned):
    outcome, _, _ = planned
    r = outcome.result
    f = r.figures
    assert f is not None and f.measured and f.counted_on == "input points"
    assert f.n_points == r.input.n_points
    assert f.finished + f.left + f.unreached + f.not_covered == f.n_points
    for a in f.areas:
        assert a.finished + a.left + a.unreached + a.not_covered == a.n_points
        assert a.n_points == int((outcome.input_labels == a.area).sum())
    assert sum(a.n_points for a in f.areas) == f.n_points
    for k in ("finished", "left", "unreached", "not_covered"):
        assert sum(getattr(a, k) for a in f.areas) == getattr(f, k)
    # the verification's own share is the same reading of the same points
    assert f.finished_share == pytest.approx(r.verification.deviation.finished_share, abs=1e-6)
    # a point unreached in the classes is one of the plan's unmachined points
    assert f.unreached <= (r.unmachined.n_points if r.unmachined is not None else 0)
    assert [a.area for a in f.areas] == list(r.machining_order)


def test_one_machining_time_everywhere(planned):
    outcome, _, out = planned
    r = outcome.result
    f, v = r.figures, r.verification
    assert f.time_source == "simulated"
    assert f.machining_time_s == pytest.approx(v.machining_time_s, abs=0.05)
    assert f.machining_time_s == pytest.approx(sum(a.machining_time_s for a in f.areas), abs=0.5)
    sim = {a.area: a for a in v.areas}
    for a in f.areas:
        assert a.machining_time_s == pytest.approx(sim[a.area].machining_time_s, abs=0.05)
    doc = json.loads((out / "plan.json").read_text())
    text = "\n".join(summary_lines(doc))
    minutes = f.machining_time_s / 60.0
    assert f"({minutes:.1f} min, simulated)" in text and text.count("machining time") == 1
    head = plan_summary(r)                                       # the service's result headline
    assert head["machining_time_s"] == f.machining_time_s and head["finished_share"] == f.finished_share
    assert head["message"] == r.message and head["status"] == r.status


def test_pictures_show_the_plans_numbers(planned):
    outcome, config, out = planned
    r = outcome.result
    v, f = r.verification, r.figures
    ply = PlyData.read(str(out / "deviation.ply"))["vertex"]
    d = np.asarray(ply["deviation_mm"], dtype=np.float64)
    assert d.size == f.n_points
    # the deepest cut the picture shows is the plan's deepest cut (no suspected reading painted as a cut)
    assert max(0.0, -float(d.min())) == pytest.approx(v.deviation.gouge_max_mm, abs=1e-4)
    fp = config.paths.finishing
    limit = fp.tolerance_mm + fp.scallop_mm + v.measuring_bound_mm
    assert np.mean(np.abs(d) <= limit) == pytest.approx(f.finished_share, abs=2.0 / f.n_points)
    # one colour convention: green within the limit, blue where material is left, red where cut
    from planning.report.deviation import DEVIATION_COLORS, deviation_colors
    rgb = np.stack([ply["red"], ply["green"], ply["blue"]], 1)
    assert np.array_equal(rgb, deviation_colors(d, limit))
    c = deviation_colors(np.array([0.0, 10 * limit, -10 * limit]), limit)
    assert tuple(c[0]) == DEVIATION_COLORS["within"] and tuple(c[1]) == DEVIATION_COLORS["left"]
    assert tuple(c[2]) == DEVIATION_COLORS["cut"]


def test_a_plan_finishing_less_than_the_coverage_says_so(planned):
    outcome, config, _ = planned
    r = outcome.result
    assert r.message.startswith(f"{r.figures.finished_share:.1%} of the scan finished within tolerance") or \
        r.message.startswith("only ")
    # the same plan, had its programs left material everywhere: a safe plan that does not finish the part
    worse = copy.deepcopy(r)
    worse.status, worse.message = "planned", "2 set-ups cover 96 %"
    n = outcome.input_labels.shape[0]
    apply_figures(worse, input_labels=outcome.input_labels, not_covered=np.zeros(n, bool),
                  unreached=np.zeros(0, np.int64), deviation_mm=np.full(n, 5.0), config=config)
    assert worse.figures.finished == 0 and worse.figures.left == n
    assert worse.status == "unfinished" and exit_status(worse) == EXIT_UNFINISHED
    assert worse.message.startswith("only 0.0% of the scan finished within tolerance (target")
    assert worse.verification.status == "passed"                 # safe, and still not PASSED alone
    better = copy.deepcopy(r)
    better.status = "planned"
    apply_figures(better, input_labels=outcome.input_labels, not_covered=np.zeros(n, bool),
                  unreached=np.zeros(0, np.int64), deviation_mm=np.zeros(n), config=config)
    assert better.status == "planned" and exit_status(better) == EXIT_OK


def test_the_unmachined_picture_and_the_preview_count_the_plans_classes(planned, tmp_path, monkeypatch):
    """unmachined.png said 2.4 % 'no kept finishing move reaches' beside figures.unreached 0.7 % (the rest
    of those points end finished or seen by no set-up); the preview's legend counted every point attached
    by distance beside figures.not_covered. Both now say the plan's class and its count."""
    from planning.report import deviation, plan_files

    outcome, _, _ = planned
    f = outcome.result.figures
    seen = {}
    monkeypatch.setattr(deviation, "render_unmachined_png",
                        lambda path, pts, idx, title="": seen.update(idx=np.asarray(idx), title=title))
    real = plan_files.render_preview
    monkeypatch.setattr(plan_files, "render_preview",
                        lambda *a, **k: (seen.update(label=k.get("integrated_label")), real(*a, **k))[1])
    outcome.result.artifacts.unmachined_png = "unmachined.png"
    assert outcome.result.unmachined is not None and outcome.result.unmachined.n_points > 0   # some to draw
    write_plan(outcome, tmp_path / "again")
    assert seen["idx"].size == f.unreached
    assert np.all(outcome.extra["point_classes"][seen["idx"]] == UNREACHED)
    assert f"unreached (red): {f.unreached:,} input points ({f.unreached_share:.1%})" in seen["title"]
    assert seen["label"] is not None and f"{f.not_covered:,} of them not finished" in seen["label"]


def test_the_deepest_cut_of_the_scan_is_the_deepest_of_its_areas(planned):
    """The femur-like plan said per area gouge_max_mm 0.058-0.089 mm while its total said 0.0: the areas
    without a point read as gouged took the rays' reading, the total only the exact depths."""
    outcome, _, _ = planned
    v = outcome.result.verification
    per_area = [a.deviation.gouge_max_mm for a in v.areas]
    assert v.deviation.gouge_max_mm == pytest.approx(max(per_area), abs=1e-4)
    dev = outcome.extra["simulation"].deviation_mm
    for a in v.areas:
        mine = outcome.input_labels == a.area
        assert a.deviation.gouge_max_mm == pytest.approx(max(0.0, -float(dev[mine].min())), abs=1e-4)
