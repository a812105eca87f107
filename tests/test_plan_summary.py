"""The machining summary (scanmill/summary.py) that `scanmill plan` and the `make run` demo print: rows per
area in machining order, the machining time, verdict, the scan's shares; from plan.json ``figures`` (issue 34),
and from an older plan.json without them (labelled as estimates)."""

import copy
import json

from scanmill.cli import EXIT_INFEASIBLE, EXIT_OK, EXIT_UNFINISHED, EXIT_UNSAFE, main
from scanmill.summary import format_summary, summary_lines


def _setup(i, rough_s, fin_s, **fin_extra):
    path = {"roughing": None if rough_s is None else {"machining_time_s": rough_s, "n_levels": 3},
            "finishing": None if fin_s is None else {"machining_time_s": fin_s, "n_passes": 9, **fin_extra},
            "programs": {"linuxcnc": f"area_{i}.linuxcnc.nc"}}
    return {"id": i, "tool_axis": [0.0, 0.0, 1.0], "rotary_deg": {"A": 0.0}, "n_points": 100, "path": path}


OLD_PLAN = {                                       # plan.json before machining_order / unmachined
    "status": "planned", "message": "2 set-ups", "warnings": [],
    "setups": [_setup(0, 600.0, 1800.0), _setup(1, None, 930.0)],
    "verification": {"status": "passed", "message": "no collision, rapid into material, travel excursion or gouge",
                     "machining_time_s": 3456.0, "areas": [],
                     "deviation": {"finished_share": 0.9375, "n_points": 1000}},
}


def _rows(lines):
    """The table rows (after the header) as lists of cells."""
    i = next(k for k, s in enumerate(lines) if s.strip().startswith("area"))
    rows = []
    for s in lines[i + 1:]:
        if not s.startswith("  "):
            break
        rows.append(s.split())
    return lines[i].split(), rows


def test_rows_total_verdict_and_share_from_the_simulation():
    lines = summary_lines(OLD_PLAN)
    head, rows = _rows(lines)
    assert head == ["area", "roughing", "min", "finishing", "min", "total", "min"]
    assert rows == [["0", "10.0", "30.0", "40.0"], ["1", "-", "15.5", "15.5"]]     # roughing null: "-"
    text = "\n".join(lines)
    assert "machining time (estimate) 0:56 (55.5 min)" in text
    assert "simulated" not in text                                # one time, labelled: no second figure
    assert "verification: PASSED - no collision, rapid into material, travel excursion or gouge" in text
    assert "finished within tolerance: 93.8% of the scan points (simulation)" in text
    assert format_summary(OLD_PLAN) == text
    assert len(lines) == 7                                        # compact: title, header, 2 rows, 3 lines


def test_machining_order_and_new_unmachined_fields():
    plan = copy.deepcopy(OLD_PLAN)
    plan["setups"] = [_setup(0, 600.0, 1800.0, unmachined_points=12), _setup(1, None, 930.0, unmachined_points=0),
                      _setup(2, 60.0, 4000.0, unmachined_points=1234)]
    plan["machining_order"] = [2, 0, 1]
    plan["unmachined"] = {"n_points": 1246, "share": 0.0123, "per_area": {"0": 12, "2": 1234}}
    head, rows = _rows(summary_lines(plan))
    assert head[-2:] == ["unreached", "pts"]
    assert rows == [["2", "1.0", "66.7", "67.7", "1,234"], ["0", "10.0", "30.0", "40.0", "12"],
                    ["1", "-", "15.5", "15.5", "0"]]
    text = format_summary(plan)
    assert "machining time (estimate) 2:03 (123.2 min)" in text
    assert "unreached: 1.2% of the scan points (1,246) reached by no kept finishing move" in text
    # the per-area counts of the plan-level figure win over the set-ups' own (absent: none)
    plan["unmachined"]["per_area"] = {"0": 5, "1": 7}
    _, rows = _rows(summary_lines(plan))
    assert [r[-1] for r in rows] == ["0", "5", "7"]
    del plan["unmachined"]
    _, rows = _rows(summary_lines(plan))
    assert [r[-1] for r in rows] == ["1,234", "12", "0"]


def test_order_missing_areas_come_after_and_unknown_ids_are_ignored():
    plan = copy.deepcopy(OLD_PLAN)
    plan["machining_order"] = [1, 7]
    _, rows = _rows(summary_lines(plan))
    assert [r[0] for r in rows] == ["1", "0"]


def test_skipped_verification_no_paths_and_failed_verdict():
    plan = copy.deepcopy(OLD_PLAN)
    plan["setups"].append({"id": 2, "path": None})
    plan["verification"] = {"status": "skipped", "message": "simulate.enabled is false", "machining_time_s": 0.0,
                            "areas": [], "deviation": None}
    lines = summary_lines(plan)
    _, rows = _rows(lines)
    assert rows[-1] == ["2", "-", "-", "-"]
    text = "\n".join(lines)
    assert "machining time (estimate) 0:56 (55.5 min)" in text and "simulated" not in text
    assert "verification: SKIPPED - simulate.enabled is false" in text
    assert "finished within tolerance" not in text
    plan["verification"] = None
    assert "verification: not run" in format_summary(plan)
    plan["verification"] = dict(OLD_PLAN["verification"], status="failed",
                                message="2 holder collisions; 1 rapid into material")
    text = format_summary(plan)
    assert "verification: FAILED\n  - 2 holder collisions\n  - 1 rapid into material" in text


def test_empty_plan_does_not_break():
    text = format_summary({"setups": []})
    assert "machining time (estimate) 0:00 (0.0 min)" in text and "verification: not run" in text


# A tiny plan through the command line, paths and simulation on: the half sphere with few points.
TINY = ["--quiet", "--set", "normals.method=\"input\"", "--set", "setups.max_setups=2", "--set", "tool.diameter_mm=10",
        "--set", "paths.finishing.scallop_mm=1.0", "--set", "paths.roughing.step_down_mm=10",
        "--set", "simulate.resolution_mm=2.0", "--set", "post.dialects=[\"linuxcnc\"]"]


def test_cli_plan_prints_the_summary(tmp_path, capsys):
    ply = tmp_path / "hs.ply"
    assert main(["sample", "half_sphere", "--out", str(ply), "--points", "400"]) == EXIT_OK
    capsys.readouterr()
    out = tmp_path / "plan"
    code = main(["plan", str(ply), "--out", str(out), *TINY])
    text = capsys.readouterr().out
    doc = json.loads((out / "plan.json").read_text())
    assert code == {"planned": EXIT_OK, "unfinished": EXIT_UNFINISHED}.get(doc["status"], EXIT_INFEASIBLE) or \
        (code == EXIT_UNSAFE and doc["verification"]["status"] == "failed")
    for line in summary_lines(doc):                                # the same lines, from the written plan.json
        assert line in text
    assert "machining summary (areas in machining order; minutes simulated" in text
    f = doc["figures"]
    _, rows = _rows(summary_lines(doc))
    assert len(rows) == len(doc["setups"]) == len(f["areas"])
    sim = {a["area"]: a for a in doc["verification"]["areas"]}
    for row, fa in zip(rows, f["areas"]):
        assert row[0] == str(fa["area"])
        # the simulated minutes of the area's program, not the paths' estimate
        assert row[3] == f"{sim[fa['area']]['machining_time_s'] / 60:.1f}"
        assert [int(c.replace(",", "")) for c in row[4:8]] == [fa["finished"], fa["left"], fa["unreached"],
                                                              fa["not_covered"]]
    assert f"verification: {doc['verification']['status'].upper()}" in text
    assert text.count("machining time") == 1                       # one time, not an estimate beside it


def test_make_run_says_where_its_jobs_are_kept_and_how_to_remove_them(tmp_path, monkeypatch):
    import sys
    from pathlib import Path
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "scripts"))
    from demo_service import _kept_line
    for j in ("a1", "b2"):
        (tmp_path / "jobs" / j).mkdir(parents=True)
        (tmp_path / "jobs" / j / "cloud.ply").write_bytes(b"x" * 1_500_000)
    line = _kept_line("http://127.0.0.1:1", "b2", tmp_path)
    assert f"kept in {tmp_path.resolve()}: 2 jobs, 3 MB" in line
    assert f"rm -rf {tmp_path.resolve()}" in line and "each `make run` adds one" in line
    assert "demo_service" in sys.modules
