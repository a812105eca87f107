"""Advice that was tried (issue 34 item 3, planning/advice.py): an infeasible plan tries the cheap changes on its
visibility and set-up stages, in a fixed order, and names the first that reaches setups.coverage with the command
to use. Checked here: the order and its values; the chosen change against a selection run independently (and a
plan run with it), every earlier change short of the coverage; the message and plan.json; the budget; the
command line kept as given; and (slow) the suggested command, run as printed, plans feasibly on three samples."""

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from planning import advice as adv
from planning.inputs.cloud import Cloud
from planning.inputs.samples import make_sample
from planning.orientations import load_profile
from planning.pipeline import run_plan
from planning.setups import select_setups
from planning.visibility import cone_visibility, global_visibility
from schemas.params import apply_overrides, parse_config
from schemas.plan import plan_json_schema

_OFF = ["paths.finishing.enabled=false", "paths.roughing.enabled=false", "simulate.enabled=false"]
_FEASIBLE = ("optimal", "feasible")


def _cfg(*sets):
    return parse_config(apply_overrides({}, [*_OFF, *sets]))


# -- the order ----------------------------------------------------------------------------------------------------

def _assignments(config):
    changes, left = adv.candidate_changes(config)
    return [c.assignment for c in changes], left


def test_the_order_with_defaults():
    got, left = _assignments(parse_config({}))
    assert got == ["fixtures.fixture_height_mm=100", "fixtures.fixture_height_mm=150", "fixtures.placement=auto",
                   "setups.max_setups=6", "setups.max_setups=7", "visibility.cone_deg=[5,85]",
                   "tool.stickout_mm=45", "tool.stickout_mm=60"]
    assert left == []


def test_only_values_beyond_the_current_ones_and_parameters_that_apply():
    got, left = _assignments(parse_config({
        "fixtures": {"fixture_height_mm": 120}, "setups": {"max_setups": 11},
        "visibility": {"cone_deg": [10, 60]}, "tool": {"stickout_mm": 50}}))
    assert got == ["fixtures.fixture_height_mm=150", "fixtures.placement=auto", "setups.max_setups=12",
                   "visibility.cone_deg=[10,80]", "visibility.cone_deg=[5,85]", "tool.stickout_mm=60"]
    got, left = _assignments(parse_config({"fixtures": {"placement_mm": [0, 0, 80], "fixture_height_mm": 200},
                                           "setups": {"max_setups": 12}, "visibility": {"cone_deg": [0, 90]},
                                           "tool": {"stickout_mm": 80}}))
    assert got == [] and left == ["fixtures.placement=auto (fixtures.placement_mm is set)"]
    # already "auto": the placement is not suggested again
    got, _ = _assignments(parse_config({"fixtures": {"placement": "auto"}}))
    assert "fixtures.placement=auto" not in got and got[0] == "fixtures.fixture_height_mm=100"


def test_every_change_is_a_valid_set_override():
    cfg = parse_config({})
    for ch in adv.candidate_changes(cfg)[0]:
        new = adv.changed_config(cfg, ch)
        group, name = ch.parameter.split(".")
        got = getattr(getattr(new, group), name)
        assert (list(got) if isinstance(got, tuple) else got) == ch.value


# -- the command line ---------------------------------------------------------------------------------------------

def test_the_command_keeps_what_was_given_and_replaces_the_same_parameter():
    argv = ["/opt/x/bin/scanmill", "plan", "my scan.ply", "--out", "out dir/", "--set", "setups.max_setups=6",
            "--set", "visibility.cone_deg=[10,60]", "--quiet"]
    cmd = adv.command_with(argv, adv.Change("setups.max_setups", 7))
    assert cmd == ["/opt/x/bin/scanmill", "plan", "my scan.ply", "--out", "out dir/", "--set",
                   "visibility.cone_deg=[10,60]", "--quiet", "--set", "setups.max_setups=7"]
    assert shlex.split(shlex.join(cmd)) == cmd
    # the --set=form is replaced too
    cmd = adv.command_with(["scanmill", "plan", "a.ply", "--set=setups.max_setups=6"], adv.Change("setups.max_setups", 7))
    assert cmd == ["scanmill", "plan", "a.ply", "--set", "setups.max_setups=7"]


# -- the tries against an independent selection -------------------------------------------------------------------

@pytest.fixture(scope="module")
def narrow_slot():
    """The range-scanned slot with a narrow cone and two set-ups: infeasible; neither riser, nor another
    placement, nor three set-ups reach 95 %; four do."""
    s = make_sample("range_slot")
    cloud = Cloud(points=s.points, normals=s.normals, source_format="generated")
    sets = ["visibility.cone_deg=[10,60]", "setups.max_setups=2"]
    return cloud, sets, run_plan(cloud, _cfg(*sets), name="range_slot.ply")


def _independent(out, config):
    """The set-up selection of the plan's sampled points with ``config``, from the library functions, not
    planning/advice.py nor the pipeline's stage functions."""
    a = out.arrays
    pts, sidx, nrm = out.points, a["sample_index"], a["normals"]
    axes, ang = a["candidate_axes"], a["candidate_rotary_deg"]
    cone = cone_visibility(nrm, axes, config.visibility.cone_deg)
    gv = global_visibility(pts, sidx, nrm, axes, ang, cone, tool=config.tool.assembly(),
                           profile=load_profile(config.machine.profile), fixtures_params=config.fixtures,
                           check_global=config.visibility.global_, check_travel=config.visibility.travel,
                           obstacles=config.visibility.obstacles)
    s = config.setups
    return select_setups(gv.visible, coverage=s.coverage, max_setups=s.max_setups, min_points=s.min_points,
                         time_limit_s=s.time_limit_s)


def test_the_chosen_change_reaches_the_coverage_and_no_earlier_one_did(narrow_slot):
    cloud, sets, out = narrow_slot
    r = out.result
    base = _cfg(*sets)
    assert r.status == "infeasible" and r.advice is not None
    a = r.advice
    assert a.chosen is not None and a.closest is None and not a.budget_spent
    chosen = a.tries[a.chosen]
    assert chosen.assignment == "setups.max_setups=4" and chosen.feasible
    assert a.chosen == len(a.tries) - 1                                # the tries stop at the first success
    order = [c.assignment for c in adv.candidate_changes(base)[0]]
    assert [t.assignment for t in a.tries] == order[:len(a.tries)]     # in the documented order, none skipped
    for t in a.tries:
        cfg = parse_config(apply_overrides(base.to_json_dict(), [t.assignment]))
        if t.parameter == "fixtures.placement":
            # the hint's search, read: a plan with "auto" finds no placement either
            auto = run_plan(cloud, cfg, name="range_slot.ply").result
            assert auto.status == "infeasible" and auto.placement.candidate is None and not t.feasible
            continue
        sel = _independent(out, cfg)
        assert (sel.status in _FEASIBLE) == t.feasible, t
        assert sel.coverage == pytest.approx(t.coverage, abs=1e-12) and sel.k == t.k
    # the change, planned: the plan itself reaches the coverage with it
    again = run_plan(cloud, parse_config(apply_overrides(base.to_json_dict(), [chosen.assignment])),
                     name="range_slot.ply").result
    assert again.status == "planned" and again.coverage >= 0.95 and again.advice is None
    assert again.coverage == pytest.approx(chosen.coverage, abs=1e-12)


def test_the_message_names_the_change_and_drops_the_old_advice(narrow_slot):
    _, _, out = narrow_slot
    r = out.result
    assert "the first that reaches 95 % is setups.max_setups = 4 (4 set-ups cover " in r.message
    assert "--set setups.max_setups=4" in r.message              # not the CLI here: the parameter to set
    assert "raise setups.max_setups" not in r.message
    assert r.selection.message in r.message
    assert not any("raise setups.max_setups" in w for w in r.warnings)
    assert [t.stage for t in r.timings].count("setups") == 2        # the tries are timed as set-up work
    from planning.report.plan_files import plan_json_text
    doc = json.loads(plan_json_text(out))
    jsonschema.validate(doc, plan_json_schema())
    assert doc["advice"]["tries"][-1]["assignment"] == "setups.max_setups=4"
    assert doc["advice"]["message"] in doc["message"]


def test_a_spent_budget_is_said_and_nothing_tried_keeps_the_old_words(monkeypatch):
    from planning.placement import stage

    s = make_sample("range_slot")
    cloud = Cloud(points=s.points, normals=s.normals, source_format="generated")
    monkeypatch.setattr(stage, "HINT_MAX_WORK", 0.0)                # the hint does not search: no free placement try
    monkeypatch.setattr(adv, "ADVICE_BUDGET_S", 0.0)
    r = run_plan(cloud, _cfg("setups.max_setups=1"), name="s.ply").result
    assert r.status == "infeasible" and r.advice.tries == [] and r.advice.budget_spent
    assert "change the part set-up or raise setups.max_setups" in r.message
    assert any("budget was spent" in x for x in r.advice.not_tried)
    assert any(x.startswith("fixtures.placement=auto (the placement hint did not search") for x in r.advice.not_tried)


def test_a_visibility_try_does_not_start_when_the_budget_left_is_shorter(narrow_slot, monkeypatch):
    """A try that runs the visibility stage is not started when less of the budget is left than the plan's own
    visibility stage took; the set-up-only tries still run, and the message says what was left out."""
    cloud, sets, _ = narrow_slot
    real = adv.try_changes
    monkeypatch.setattr(adv, "try_changes", lambda *a, **k: real(*a, **{**k, "visibility_s": 1e9}))
    r = run_plan(cloud, _cfg(*sets), name="range_slot.ply").result
    a = r.advice
    assert [t.assignment for t in a.tries] == ["fixtures.placement=auto", "setups.max_setups=3", "setups.max_setups=4"]
    assert a.budget_spent and a.tries[a.chosen].assignment == "setups.max_setups=4"
    assert [x.split(" (")[0] for x in a.not_tried] == ["fixtures.fixture_height_mm=100",
                                                       "fixtures.fixture_height_mm=150"]
    assert ("(the 30 s for trying ran out before fixtures.fixture_height_mm=100, fixtures.fixture_height_mm=150)"
            in r.message)


def test_closest_when_nothing_reaches():
    """One set-up on a slot with a narrow cone: nothing in the order reaches 95 % (max_setups 3 at most); the
    message names the closest try, with its coverage, and the closest is the best of the tries."""
    s = make_sample("range_slot")
    cloud = Cloud(points=s.points, normals=s.normals, source_format="generated")
    r = run_plan(cloud, _cfg("visibility.cone_deg=[10,40]", "setups.max_setups=1", "setups.coverage=0.99"),
                 name="s.ply").result
    a = r.advice
    assert r.status == "infeasible" and a.chosen is None and a.tries
    best = max(t.coverage for t in a.tries if t.coverage is not None)
    c = a.tries[a.closest]
    assert c.coverage == best and not any(t.feasible for t in a.tries)
    assert f"the closest is {c.parameter} = " in r.message and f"{best * 100:.1f} %" in r.message
    assert "raise setups.max_setups" not in r.message


# -- the suggested command, run as printed (slow: whole plans through the CLI) ------------------------------------

_SCANMILL = str(Path(sys.executable).with_name("scanmill"))


def _plan(argv, cwd):
    p = subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=1800, check=False)
    assert p.returncode in (0, 3, 4, 5), p.stderr[-3000:]
    out = Path(cwd) / argv[argv.index("--out") + 1]
    return p, json.loads((out / "plan.json").read_text())


@pytest.mark.slow
@pytest.mark.parametrize("sample, sample_args, sets", [
    # the range-scan sample with the defaults (simulation off: it does not change the set-ups)
    ("range_femur", [], ["simulate.enabled=false"]),
    # the femur-like sample at 200,000 points, defaults (paths off: they do not change the set-ups)
    ("femur_like", ["--points", "200000"], _OFF),
    # the range-scanned half sphere with two set-ups asked for
    ("range_half_sphere", [], [*_OFF, "setups.max_setups=2"]),
])
def test_the_suggested_command_run_as_printed_plans_feasibly(tmp_path, sample, sample_args, sets):
    subprocess.run([_SCANMILL, "sample", sample, *sample_args, "--out", "scan.ply"], cwd=tmp_path, check=True,
                   capture_output=True)
    _suggested_plans_feasibly(tmp_path, sets)


@pytest.mark.slow
def test_a_suggested_placement_run_as_printed_plans_feasibly(tmp_path):
    """The slot block scanned upside down (tests/test_placement.py): no riser helps, fixtures.placement=auto
    does; the new plan searches the placements itself and must find one that reaches the coverage."""
    from planning.inputs.samples import slot
    from planning.report.files import write_ply

    s = slot(density_per_mm2=0.5, seed=1)
    flip = np.diag([1.0, -1.0, -1.0])
    write_ply(tmp_path / "scan.ply", s.points @ flip.T + [0.0, 0.0, 30.0], normals=s.normals @ flip.T)
    chosen = _suggested_plans_feasibly(tmp_path, [*_OFF, "normals.method=input", "setups.max_setups=3"])
    assert chosen["assignment"] == "fixtures.placement=auto"


def _suggested_plans_feasibly(tmp_path, sets):
    """Plan scan.ply with ``sets`` through the CLI: infeasible; run the command its message suggests, as printed:
    planned, with the coverage the advice's try reached. Returns the chosen try."""
    argv = [_SCANMILL, "plan", "scan.ply", "--out", "first", "--quiet"] + [x for s in sets for x in ("--set", s)]
    p, first = _plan(argv, tmp_path)
    assert first["status"] == "infeasible" and p.returncode == 3
    message = p.stdout.splitlines()[0]
    assert message == first["message"]
    m = re.search(r"run `([^`]+)`", message)
    assert m, message
    suggested = shlex.split(m.group(1))
    assert suggested == shlex.split(first["advice"]["command"])
    # the command as given, the user's overrides kept (one of the same parameter replaced), plus the change
    chosen = first["advice"]["tries"][first["advice"]["chosen"]]
    kept = argv[:6] + [x for s in sets if s.split("=")[0] != chosen["parameter"] for x in ("--set", s)]
    assert suggested == kept + ["--set", chosen["assignment"]]
    p2, second = _plan(suggested, tmp_path)
    assert p2.returncode == 0, p2.stdout[-2000:]
    assert second["status"] == "planned" and second["selection"]["status"] in _FEASIBLE
    assert second["coverage"] >= second["parameters"]["setups"]["coverage"]
    assert second["coverage"] == pytest.approx(chosen["coverage"], abs=1e-12)
    return chosen


def test_a_riser_that_reaches_the_coverage_spares_the_placement_search():
    """The range femur with defaults: the first try (a 100 mm riser) reaches 95 %, so the placement hint's
    search (about 20 s, eight candidate placements) is not run; it is run when the tries come to it."""
    s = make_sample("range_femur")
    cloud = Cloud(points=s.points, normals=None, source_format="generated")
    r = run_plan(cloud, _cfg(), name="rf.ply").result
    assert r.status == "infeasible" and r.advice.tries[r.advice.chosen].assignment == "fixtures.fixture_height_mm=100"
    assert len(r.advice.tries) == 1
    assert "placement" not in [t.stage for t in r.timings] and r.placement.candidates == []
    assert "fixtures.placement = auto reaches it" not in r.message
