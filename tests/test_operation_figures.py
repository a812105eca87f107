"""What the simulated machine does per operation (issue 30, "Report what the machine will do"): feed length,
the share of it in air, plunges, removed volume and time, per tool of an area's program, and the summary
line that shows them. Checked against answers worked out by hand on a small program."""

from __future__ import annotations

import numpy as np

from planning.simulate.motion import FEED, RAPID, ProgramMotion
from planning.simulate.verify import operation_figures
from schemas.params import parse_config
from scanmill.summary import summary_lines


def _motion(rows):
    """rows: (kind, tool, start, end); tool axis +Z."""
    n = len(rows)
    return ProgramMotion(program="area_0.linuxcnc.nc", area=0, line=np.arange(1, n + 1),
                         kind=np.array([r[0] for r in rows], dtype=np.int8),
                         tool=np.array([r[1] for r in rows]),
                         start_mm=np.array([r[2] for r in rows], float), end_mm=np.array([r[3] for r in rows], float),
                         axis=np.tile([0.0, 0.0, 1.0], (n, 1)), machine_mm=np.zeros((n, 3)),
                         rotary_deg=np.zeros((n, 2)))


def test_feed_in_air_removed_volume_time_and_plunges_per_tool():
    config = parse_config({"post": {"roughing_tool_number": 2, "roughing_feed_mm_min": 1000, "feed_mm_min": 500,
                                    "rapid_mm_min": 10000}})
    rows = [(RAPID, 0, (0, 0, 0), (0, 0, 0)),                  # nothing in the spindle yet
            (RAPID, 2, (0, 0, 50), (0, 0, 10)),                # 40 mm rapid
            (FEED, 2, (0, 0, 10), (0, 0, 5)),                  # 5 mm straight down, cuts: a plunge
            (FEED, 2, (0, 0, 5), (30, 0, 5)),                  # 30 mm, cuts
            (FEED, 2, (30, 0, 5), (30, 20, 5)),                # 20 mm in air
            (FEED, 2, (30, 20, 5), (30, 20, 0)),               # 5 mm straight down in air: not a plunge into material
            (RAPID, 1, (30, 20, 50), (0, 0, 50)),              # the finishing tool: sqrt(30^2+20^2) rapid
            (FEED, 1, (0, 0, 50), (0, 40, 50))]                # 40 mm, cuts
    removed = np.array([0, 0, 12.5, 100.0, 0, 0, 0, 3.0])
    ops = operation_figures(_motion(rows), removed, config)
    assert [(o.tool, o.operation) for o in ops] == [(2, "roughing"), (1, "finishing")]   # T0 left out
    r, f = ops
    assert r.feed_mm == 60.0 and r.air_feed_mm == 25.0 and r.air_share == round(25 / 60, 4)
    assert r.rapid_mm == 40.0 and r.removed_mm3 == 112.5 and r.plunges_into_material == 1
    assert r.machining_time_s == round(60 * (40 / 10000 + 60 / 1000), 1)
    rapid = float(np.hypot(30, 20))
    assert f.feed_mm == 40.0 and f.air_feed_mm == 0.0 and f.removed_mm3 == 3.0 and f.plunges_into_material == 0
    assert f.rapid_mm == round(rapid, 1) and f.machining_time_s == round(60 * (rapid / 10000 + 40 / 500), 1)


def test_the_summary_shows_each_operation_of_each_area_in_machining_order():
    ops = [{"tool": 2, "operation": "roughing", "feed_mm": 12000.0, "air_feed_mm": 1200.0, "air_share": 0.1,
            "rapid_mm": 0.0, "removed_mm3": 150000.0, "machining_time_s": 600.0, "plunges_into_material": 3},
           {"tool": 1, "operation": "finishing", "feed_mm": 50000.0, "air_feed_mm": 0.0, "air_share": 0.0,
            "rapid_mm": 0.0, "removed_mm3": 9000.0, "machining_time_s": 2400.0, "plunges_into_material": 0}]
    plan = {"setups": [{"id": 0}, {"id": 1}], "machining_order": [1, 0],
            "verification": {"status": "passed", "message": "clean", "machining_time_s": 6000.0,
                             "areas": [{"area": 1, "operations": ops}, {"area": 0, "operations": ops[1:]}]}}
    lines = summary_lines(plan)
    at = lines.index("simulated per operation (feed in air: moves that removed no material):")
    assert lines[at + 1] == ("  area 1 roughing  T2: feed 12.0 m, 10% in air, 3 straight plunges into material, "
                             "removed 150.0 cm3, 10.0 min")
    assert lines[at + 2] == "  area 1 finishing T1: feed 50.0 m, 0% in air, removed 9.0 cm3, 40.0 min"
    assert lines[at + 3].startswith("  area 0 finishing T1:")


def test_the_summary_shows_the_roughing_engagement_against_its_bound():
    """Issue 31 item 5: the roughing's line carries the largest engagement, its p95 and the moves over
    ``paths.roughing.max_engagement_deg`` (the plan's own parameter); without a measure, nothing."""
    rough = {"tool": 2, "operation": "roughing", "feed_mm": 12000.0, "air_feed_mm": 1200.0, "air_share": 0.1,
             "rapid_mm": 0.0, "removed_mm3": 150000.0, "machining_time_s": 600.0, "plunges_into_material": 0,
             "engagement_max_deg": 180.0, "engagement_p95_deg": 121.4, "over_engagement_moves": 42,
             "over_engagement_mm": 830.0}
    plan = {"setups": [{"id": 0}], "machining_order": [0], "parameters": {"paths": {"roughing": {"max_engagement_deg": 75.0}}},
            "verification": {"status": "passed", "message": "clean", "machining_time_s": 600.0,
                             "areas": [{"area": 0, "operations": [rough]}]}}
    line = next(x for x in summary_lines(plan) if x.startswith("  area 0 roughing"))
    assert line == ("  area 0 roughing  T2: feed 12.0 m, 10% in air, engagement up to 180 deg (p95 121), "
                    "42 moves over 75 deg, removed 150.0 cm3, 10.0 min")
    rough.pop("engagement_max_deg")
    line = next(x for x in summary_lines(plan) if x.startswith("  area 0 roughing"))
    assert "engagement" not in line
