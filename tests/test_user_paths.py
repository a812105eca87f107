"""Issue 29: the planner as its users drive it. ``scanmill plan --set paths.finishing.mode=5axis`` crashed
with ``KeyError: 'five_axis'`` in the paths stage's progress (its step had no share in
``_PathsProgress.STEPS``) while every test passed: the tests planned without a progress listener, and
the CLI and the service always have one.

So here the real CLI runs in a subprocess with its progress on (no ``--quiet``; that ``--quiet`` too
installs the listener is checked on its own) and the real service plans ``POST /jobs`` (progress always
on there), in every finishing mode (``3+2``, ``5axis``), with roughing on and off, on every input kind (a
PLY point cloud, STL and OBJ meshes, a PNG relief, an XYZ text cloud): tiny parts
(tests/user_paths_inputs.py). The default run covers each mode, roughing setting and input kind at
least once through the CLI, and 5axis plus one 3+2 case through ``POST /jobs``; the whole cross product
is ``slow``. Each plan must end as documented (exit 0, 3, 4 or 5, never 1; a job that succeeds), with no
traceback, a plan.json naming the finishing mode it used, and progress that reached the paths stage.

Besides: every ``step("...")`` name the toolpath code announces has its share in ``STEPS`` (read from
the source), a name without one is reported and never stops a plan, and an area's steps come in the
order of their shares.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from itertools import pairwise
from pathlib import Path

import pytest
from service_fixtures import ServerProcess
from user_paths_inputs import KINDS, MODES, ROUGHING, parameters, write_part

from planning.toolpath.area_paths import _PathsProgress

ROOT = Path(__file__).resolve().parents[1]
TOOLPATH = ROOT / "planning" / "toolpath"
STAGES_LINE = re.compile(r"^\[\s*[\d.]+ s\] (\S+)\s+\d+%  (.*)$")

#: (kind, mode, roughing) planned through the CLI by default: every mode, roughing setting and kind
DEFAULT_CLI = [("ply", "5axis", True), ("stl", "3+2", False), ("png", "5axis", False), ("xyz", "3+2", True)]
#: ... and through POST /jobs
DEFAULT_SERVICE = [("ply", "5axis", True), ("stl", "3+2", False)]
ALL = [(k, m, r) for k in KINDS for m in MODES for r in ROUGHING]


def _case_id(case) -> str:
    kind, mode, rough = case
    return f"{kind}-{mode}-{'rough' if rough else 'norough'}"


def _matrix(default: list) -> list:
    """The whole cross product: the ``default`` cases as they are, the others marked slow."""
    return [pytest.param(c, id=_case_id(c), marks=() if c in default else pytest.mark.slow) for c in ALL]


# --- the step names and their shares -------------------------------------------------------------------

STEP_CALL = re.compile(r"""\bstep\(\s*["']([A-Za-z0-9_]+)["']\s*\)""")


def _announced_steps() -> dict[str, list[str]]:
    """Every literal ``step("name")`` in planning/toolpath, with the files that announce it."""
    found: dict[str, list[str]] = {}
    for path in sorted(TOOLPATH.rglob("*.py")):
        for name in STEP_CALL.findall(path.read_text()):
            found.setdefault(name, []).append(str(path.relative_to(ROOT)))
    return found


def test_every_step_the_toolpath_code_announces_has_its_share():
    found = _announced_steps()
    # the scan itself works: the steps of both finishing modes are found
    assert {"frame", "roughing", "finishing", "cut_blocked", "five_axis", "reduce_arcs", "verify",
            "guard_finishing"} <= set(found), sorted(found)
    missing = {n: files for n, files in found.items() if n not in _PathsProgress.STEPS}
    assert not missing, f"step names with no share in _PathsProgress.STEPS: {missing}"
    for name, (lo, hi) in _PathsProgress.STEPS.items():
        assert 0.0 <= lo <= hi <= 1.0, name


def test_a_step_without_a_share_is_reported_and_never_goes_back():
    got: list[tuple[float, str]] = []
    p = _PathsProgress(lambda f, m: got.append((f, m)), k=2, min_interval_s=0.0)
    p.start_area(0, 3)
    p.step("frame")
    p.step("finishing")(0.5, "pass 1/2")
    inner = p.step("no_such_step")                  # must not raise
    assert callable(inner)
    inner(0.7, "half way")
    p.step("verify")
    p.area_done()
    p.start_area(1, 5)
    p.step("no_such_step")(1.0, "")
    p.area_done()
    fr = [f for f, _ in got]
    assert all(b >= a for a, b in pairwise(fr)), got
    assert any(m == "area 3 (1/2): no such step" for _, m in got), got
    assert any(m == "area 3 (1/2): no such step, half way" for _, m in got), got
    # within the area the unknown step sits where the area had got to, not before
    at = [f for f, m in got if m.startswith("area 3 (1/2): no such step")]
    lo_fin = _PathsProgress.STEPS["finishing"][0] / 2
    assert all(f >= lo_fin for f in at), (at, lo_fin)
    assert fr[-1] == 1.0


def test_the_share_mapping_alone_keeps_an_area_s_fractions_monotonic():
    """The mapping itself keeps an area's fractions monotonic (not only the throttle behind it)."""
    p = _PathsProgress(lambda f, m: None, k=1)
    p.start_area(0, 0)
    seen = []
    orig = p._emit

    def spy(f, m, force=False):
        seen.append(f)
        orig(f, m, force=force)
    p._emit = spy
    p.step("verify")
    p.step("finishing")(0.0, "late")                # announced after a later step: kept where it got to
    assert seen == sorted(seen), seen


@pytest.mark.parametrize("mode", MODES)
def test_an_area_s_steps_come_in_the_order_of_their_shares(mode, tmp_path):
    """A whole plan in this process with a recording listener (the simulation off): per area, every
    announced step has a share, in the order of the shares, the fractions never go back, and a 5-axis
    area runs its five_axis step (3+2: cut_blocked)."""
    from planning.inputs.cloud import read_input
    from planning.pipeline import run_plan
    from schemas.params import parse_config

    params = parameters("png", mode, True)            # the relief: the lightest 5-axis plan
    params["simulate"] = {"enabled": False}
    config = parse_config(params)
    cloud = read_input(write_part("png", tmp_path), config.input)
    calls: list[tuple[float, str]] = []
    out = run_plan(cloud, config, name="bump.png", progress=lambda st, f, m: st == "paths" and calls.append((f, m)))
    fr = [f for f, _ in calls]
    assert fr and all(b >= a for a, b in pairwise(fr))
    order = out.result.machining_order
    names = {k.replace("_", " "): k for k in _PathsProgress.STEPS}
    for n, area in enumerate(order):
        head = f"area {area} ({n + 1}/{len(order)}): "
        steps = []
        for _, m in calls:
            if m.startswith(head):
                s = m[len(head):].split(",")[0]
                if not steps or steps[-1] != s:
                    steps.append(s)
        assert set(steps) <= set(names), steps
        los = [_PathsProgress.STEPS[names[s]][0] for s in steps]
        assert los == sorted(los), steps
        assert ("five axis" if mode == "5axis" else "cut blocked") in steps, steps
        assert ("cut blocked" if mode == "5axis" else "five axis") not in steps, steps


def test_quiet_still_installs_the_progress_listener(tmp_path, monkeypatch):
    """``--quiet`` prints no progress lines, but the plan still runs with a listener (the code path the
    users' plans take)."""
    import planning.pipeline
    from scanmill.cli import main

    seen = {}

    class Stop(Exception):
        pass

    def fake_run_plan(cloud, config, *, progress=None, **kw):
        seen["progress"] = progress
        raise Stop

    monkeypatch.setattr(planning.pipeline, "run_plan", fake_run_plan)
    src = write_part("ply", tmp_path)
    with pytest.raises(Stop):
        main(["plan", str(src), "--out", str(tmp_path / "out"), "--quiet"])
    assert callable(seen["progress"])


# --- scanmill plan, as a user runs it ------------------------------------------------------------------

def _scanmill() -> list[str]:
    exe = Path(sys.executable).with_name("scanmill")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "scanmill.cli"]


def _check_plan_json(plan: dict, mode: str, roughing: bool, where: str) -> None:
    assert plan["parameters"]["paths"]["finishing"]["mode"] == mode, where
    assert plan["parameters"]["paths"]["roughing"]["enabled"] is roughing, where
    fin = [s["path"]["finishing"] for s in plan["setups"] if s.get("path") and s["path"].get("finishing")]
    assert fin, (where, "no area has a finishing path")
    assert {f["mode"] for f in fin} == {mode}, where
    if not roughing:
        assert all(s["path"].get("roughing") is None for s in plan["setups"] if s.get("path")), where
    assert "paths" in {t["stage"] for t in plan["timings"]}, where


@pytest.mark.parametrize("case", _matrix(DEFAULT_CLI))
def test_scanmill_plan_as_a_user_runs_it(case, tmp_path):
    kind, mode, roughing = case
    src = write_part(kind, tmp_path / "in")
    cfg = tmp_path / "params.json"
    cfg.write_text(json.dumps(parameters(kind, mode, roughing)))
    out = tmp_path / "plan"
    # the documented way: --config for the light parameters, --set for what the user changes
    cmd = _scanmill() + ["plan", str(src), "--out", str(out), "--config", str(cfg),
                         "--set", f"paths.finishing.mode={mode}",
                         "--set", f"paths.roughing.enabled={'true' if roughing else 'false'}"]
    r = subprocess.run(cmd, check=False, cwd=tmp_path, capture_output=True, text=True)
    where = f"{_case_id(case)}: exit {r.returncode}\n--- stderr\n{r.stderr[-4000:]}\n--- stdout\n{r.stdout[-2000:]}"
    assert r.returncode in (0, 3, 4, 5), where
    assert "Traceback" not in r.stderr and "Traceback" not in r.stdout, where
    # the listener was exercised: the progress lines went through the paths stage to its end
    lines = [m.groups() for m in map(STAGES_LINE.match, r.stderr.splitlines()) if m]
    stages = [st for st, _ in lines]
    assert "paths" in stages and ("paths", "done in") in {(st, msg[:7]) for st, msg in lines}, where
    assert stages.index("paths") < len(stages) - 1, where          # and on after it (post, simulate, write)
    assert any(st == "paths" and msg.startswith("area ") for st, msg in lines), where
    plan = json.loads((out / "plan.json").read_text())
    _check_plan_json(plan, mode, roughing, where)
    # the exit status says what plan.json says
    v = plan.get("verification") or {}
    if r.returncode == 0:
        assert plan["status"] == "planned" and v.get("status") in ("passed", "skipped", None), where
    elif r.returncode == 4:
        assert v["status"] == "failed", where
        assert "verification: FAILED" in r.stdout, where
    elif r.returncode == 5:
        assert plan["status"] == "unfinished" and v["status"] == "passed", where
        assert plan["figures"]["finished_share"] < plan["parameters"]["setups"]["coverage"], where
    else:
        assert plan["status"] != "planned", where
    assert any(p.name.endswith(".linuxcnc.nc") for p in out.iterdir()), where


# --- POST /jobs ----------------------------------------------------------------------------------------

#: most GET /jobs/{id} polls of one job, 0.05 s apart
POLLS = 24_000

@pytest.fixture(scope="module")
def server(tmp_path_factory):
    root = tmp_path_factory.mktemp("user_paths_service")
    srv = ServerProcess(root / "data", workers=1, job_time_limit_s=1800).start()
    try:
        yield srv
    finally:
        srv.stop()


@pytest.mark.parametrize("case", _matrix(DEFAULT_SERVICE))
def test_post_jobs_plans_as_a_client_asks(case, server, tmp_path):
    kind, mode, roughing = case
    src = write_part(kind, tmp_path)
    params = parameters(kind, mode, roughing)
    with server.client() as c, open(src, "rb") as fh:
        r = c.post("/jobs", files={"cloud": (src.name, fh, "application/octet-stream")},
                   data={"parameters": json.dumps(params), "name": _case_id(case)})
        assert r.status_code == 202, r.text
        job_id = r.json()["id"]
        # follow it as a client does; the stages it shows are what the worker's listener reported
        seen: list[str] = []
        job = None
        for _ in range(POLLS):                          # bounded in count, not in time
            job = c.get(f"/jobs/{job_id}").json()
            if job.get("stage") and (not seen or seen[-1] != job["stage"]):
                seen.append(job["stage"])
            if job["status"] not in ("queued", "running"):
                break
            time.sleep(0.05)
        where = f"{_case_id(case)}: {job}\n--- server log\n{server.log_text()[-3000:]}"
        assert job["status"] == "succeeded", where
        assert "Traceback" not in server.log_text(), where
        assert "paths" in seen, (seen, where)
        assert job["progress"] == 1.0, where
        plan = c.get(f"/jobs/{job_id}/result")
        assert plan.status_code == 200, plan.text
        _check_plan_json(plan.json(), mode, roughing, where)
        names = {a["name"] for a in c.get(f"/jobs/{job_id}/artifacts").json()["items"]}
        areas = [s["id"] for s in plan.json()["setups"] if s.get("path")]
        for a in areas:
            assert {f"area_{a}.linuxcnc.nc", f"area_{a}.iso.nc"} <= names, (names, where)
        prog = c.get(f"/jobs/{job_id}/artifacts/area_{areas[0]}.linuxcnc.nc")
        assert prog.status_code == 200 and "G21" in prog.text, where
