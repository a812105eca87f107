"""Issue 17 item 3: progress that moves. The paths stage's reporter (per area, per step of an area,
and inside the steps); the CLI's lines. The progress of whole plans is checked on the reference
cases' light plans in tests/test_safe_programs.py (no second plan here)."""

from __future__ import annotations

import io

import pytest

from planning.toolpath.area_paths import _PathsProgress
from scanmill.cli import _Progress


def test_paths_progress_maps_steps_into_areas_and_throttles():
    got: list[tuple[float, str]] = []
    p = _PathsProgress(lambda f, m: got.append((f, m)), k=4, min_interval_s=3600.0)
    p.start_area(1, 7)
    cb = p.step("finishing")                       # a step start is always told
    lo, hi = _PathsProgress.STEPS["finishing"]
    assert got[-1][0] == pytest.approx((1 + lo) / 4) and got[-1][1] == "area 7 (2/4): finishing"
    cb(0.5, "pass 3/6")                            # within the interval: dropped
    assert len(got) == 1
    p.min_interval_s = 0.0
    cb(0.5, "pass 3/6")
    assert got[-1][0] == pytest.approx((1 + lo + 0.5 * (hi - lo)) / 4)
    assert got[-1][1] == "area 7 (2/4): finishing, pass 3/6"
    cb(0.2, "late")                                # never backwards
    assert got[-1][0] == pytest.approx((1 + lo + 0.5 * (hi - lo)) / 4)
    p.area_done()
    assert got[-1][0] == pytest.approx(2 / 4) and got[-1][1] == "area 7: paths done"
    assert _PathsProgress(None, k=2).step("roughing") is None


def test_cli_prints_a_stage_line_per_fifth_or_every_two_seconds(monkeypatch):
    out = io.StringIO()
    clock = [0.0]
    monkeypatch.setattr("scanmill.cli.time.perf_counter", lambda: clock[0])
    p = _Progress(stream=out)
    p("paths", 0.0, "start")
    p("paths", 0.05, "a")           # small step, no time passed: silent
    clock[0] = 2.5
    p("paths", 0.06, "b")           # small step, but 2.5 s since the last line: printed
    p("paths", 0.30, "c")           # a fifth further: printed
    p("paths", 1.0, "done")
    lines = out.getvalue().splitlines()
    assert [ln.split()[-1] for ln in lines] == ["start", "b", "c", "done"]


def test_cli_lines_are_never_further_apart_than_the_reports_or_two_seconds(monkeypatch):
    """Issue 34 item 4: with reports every 1.5 s and 'a line 2 s after the last one', every other report
    was held back and the lines came 3 s apart. The next report is expected as far off as the last gap."""
    out = io.StringIO()
    clock = [0.0]
    monkeypatch.setattr("scanmill.cli.time.perf_counter", lambda: clock[0])
    p = _Progress(stream=out)
    p("write", 0.0, "start")
    for k in range(1, 9):                       # small steps 1.5 s apart
        clock[0] = 1.5 * k
        p("write", 0.01 * k, f"s{k}")
    assert [ln.split()[-1] for ln in out.getvalue().splitlines()] == ["start"] + [f"s{k}" for k in range(1, 9)]
    out.truncate(0)
    out.seek(0)
    t: list[float] = []
    for k in range(1, 101):                     # ten reports a second for 10 s: a line about every 2 s
        clock[0] = 20.0 + 0.1 * k
        p("paths", 0.001 * k, f"r{k}")
        if out.getvalue().count("\n") > len(t):
            t.append(clock[0])
    gaps = [b - a for a, b in zip(t, t[1:])]
    assert 4 <= len(t) <= 7 and all(1.5 <= g <= 2.0 + 1e-9 for g in gaps), (t, gaps)


def test_region_finishing_reports_each_region_by_its_share_of_the_points():
    from planning.toolpath.area_paths import _region_finishing
    from planning.toolpath.verify import BinnedCloud
    from schemas.params import parse_config
    from surfaces import wave

    pts = wave(size_mm=20.0, density=2.0).points
    left = pts[:, 0] < 0
    fp = parse_config({"paths": {"finishing": {"scallop_mm": 0.2}}}).paths.finishing
    got: list[tuple[float, str]] = []
    _region_finishing(pts, [left, ~left], BinnedCloud(pts, 0.75), fp, 3.0, 0.01, 20.0, 60.0,
                      progress=lambda f, m: got.append((f, m)))
    heads = [(f, m) for f, m in got if m.startswith("region") and "," not in m]
    assert [m for _, m in heads] == ["region 1/2", "region 2/2"]
    assert heads[0][0] == 0.0 and heads[1][0] == pytest.approx(left.sum() / left.size)
    assert any(m.startswith("region 1/2, pass ") for _, m in got)      # the passes inside each region
    assert any(m.startswith("region 2/2, pass ") for _, m in got)
    fr = [f for f, _ in got]
    assert all(b >= a - 1e-12 for a, b in zip(fr, fr[1:])) and fr[-1] == pytest.approx(1.0)
