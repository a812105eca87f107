"""Issue 34 acceptance: the femur-like demo (`make run`: scripts/demo_service.py, the service over HTTP on the
1,000,000-point reference scan) tells one story: the summary it prints, plan.json, the service's result
headline (job.json, GET /jobs/{id}) and the viewer's data (viewer.json) carry the same figures. Slow: the
whole demo runs (a few minutes on 2 cores)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from scanmill.summary import summary_lines

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_make_run_summary_plan_json_service_result_and_viewer_agree(tmp_path):
    p = subprocess.run([sys.executable, str(ROOT / "scripts" / "demo_service.py"), "--sample", "femur_like",
                        "--data-dir", str(tmp_path / "data"), "--out", str(tmp_path / "out")],
                       capture_output=True, text=True, timeout=3600, check=False, cwd=ROOT)
    out = tmp_path / "out" / "femur_like-service"
    plan = json.loads((out / "plan.json").read_text())
    job = json.loads((out / "job.json").read_text())
    viewer = json.loads((out / "viewer.json").read_text())
    f = plan["figures"]
    # the demo's exit status is the plan's (scanmill plan's): 0 planned, 5 unfinished
    assert p.returncode == {"planned": 0, "unfinished": 5}[plan["status"]], p.stdout[-3000:] + p.stderr[-3000:]
    # the summary it printed is plan.json's, line for line
    for line in summary_lines(plan):
        assert line in p.stdout, line
    head = job["result"]
    assert head["status"] == plan["status"] and head["message"] == plan["message"]
    assert head["finished_share"] == f["finished_share"] and head["machining_time_s"] == f["machining_time_s"]
    assert viewer["figures"] == f
    assert f["n_points"] == plan["input"]["n_points"] == 1_000_000
    assert f["finished"] + f["left"] + f["unreached"] + f["not_covered"] == f["n_points"]
    assert f["finished_share"] == pytest.approx(plan["verification"]["deviation"]["finished_share"], abs=1e-6)
    assert f["machining_time_s"] == pytest.approx(plan["verification"]["machining_time_s"], abs=0.05)
    assert plan["message"].split(";")[0].endswith(f"{f['finished_share']:.1%} of the scan finished within tolerance "
                                                  f"(target {f['target_coverage']:.0%})")
    # one time in the summary, simulated
    assert p.stdout.count("machining time ") == 1 and "min, simulated)" in p.stdout
