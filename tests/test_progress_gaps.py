"""Issue 34 item 4: progress from inside the long loops of a stage, not only between them. The exact gouge
confirmation (planning/simulate/gouge.py ``penetration_mm``) reports after every batch of points; the placement
search (planning/placement/search.py) passes on the progress of each candidate's fixture check, screening
collision test and set-up search, and of the confirmation's visibility and set-up stages. No clock here: the
counts of reports are fixed by the batch rule, not by the time (bench/bench_progress_gaps.py measures the gaps).
"""

from __future__ import annotations

import itertools
import json
import math
import re

import numpy as np
import pytest

from planning.simulate import gouge
from planning.simulate.gouge import penetration_mm
from planning.simulate.motion import FEED, ProgramMotion, ToolShape

BALL = ToolShape(number=1, kind="ball", radius_mm=3.0, corner_radius_mm=3.0, flute_length_mm=15.0,
                 pieces=((15.0, math.inf, 5.0),), gauge_length_mm=90.0)
FLAT = ToolShape(number=2, kind="flat", radius_mm=5.0, corner_radius_mm=0.0, flute_length_mm=25.0,
                 pieces=((25.0, math.inf, 10.0),), gauge_length_mm=90.0)


def _zigzag(tool: int, z: float) -> ProgramMotion:
    x = np.linspace(-30, 30, 61)
    rows = [np.c_[x if k % 2 == 0 else x[::-1], np.full_like(x, y), z + 0.05 * np.sin(x + y)]
            for k, y in enumerate(np.arange(-30, 30.1, 3.0))]
    path = np.concatenate(rows)
    s, e = path[:-1], path[1:]
    P = s.shape[0]
    return ProgramMotion(program="t", area=0, line=np.arange(1, P + 1), kind=np.full(P, FEED, np.int8),
                         tool=np.full(P, tool), start_mm=s, end_mm=e, axis=np.tile([0.0, 0.0, 1.0], (P, 1)),
                         machine_mm=np.zeros((P, 3)), rotary_deg=np.zeros((P, 2)))


def test_penetration_reports_after_every_batch_with_rising_fractions_and_the_same_depths():
    import numba

    motions = [_zigzag(1, 0.0), _zigzag(2, -4.0)]
    tools = {1: BALL, 2: FLAT}
    rng = np.random.default_rng(34)
    n = 20000
    pts = np.c_[rng.uniform(-32, 32, (n, 2)), rng.uniform(-0.3, 0.3, n)]
    pts[5] = np.nan                                       # a non-finite point is not measured (nor counted)
    got: list[tuple[float, str]] = []
    with_progress = penetration_mm(pts, motions, tools, lambda f, m: got.append((f, m)))
    assert np.array_equal(with_progress, penetration_mm(pts, motions, tools))      # the batches change nothing
    assert (with_progress > 0).sum() > 1000
    fractions = [f for f, _ in got]
    assert fractions[0] == 0.0 and fractions[-1] == 1.0
    assert all(b > a for a, b in itertools.pairwise(fractions))                    # strictly rising
    # at least PROGRESS_BATCHES batches where there are that many blocks per chunk (none timed: each batch
    # holds at most 1/PROGRESS_BATCHES of the points, the time only makes them smaller)
    least = gouge.CHUNKS_PER_THREAD * numba.get_num_threads() * 16
    expect = min(gouge.PROGRESS_BATCHES, math.ceil((n - 1) / least))
    assert len(got) - 1 >= expect >= 4
    assert all("exact gouge depth" in m for _, m in got)
    assert got[-1][1].endswith(f"points {n - 1:,} of {n - 1:,} measured")


def test_penetration_reports_the_end_of_a_call_with_nothing_to_measure():
    got: list[float] = []
    out = penetration_mm(np.array([[0.0, 0.0, 0.0]]), [], {1: BALL}, lambda f, m: got.append(f))
    assert out[0] == -np.inf and got == [1.0]
    got.clear()
    penetration_mm(np.array([[np.nan, 0.0, 0.0]]), [_zigzag(1, 0.0)], {1: BALL}, lambda f, m: got.append(f))
    assert got == [1.0]


# -- the placement search ------------------------------------------------------------------------------------------

_FAST = {"normals": {"method": "input"}, "setups": {"coverage": 0.95, "max_setups": 3},
         "paths": {"finishing": {"enabled": False}, "roughing": {"enabled": False}}, "simulate": {"enabled": False}}


@pytest.fixture(scope="module")
def slot_search():
    """The placement search of the slot block scanned upside down (tests/test_placement.py), with a recorder
    that gets every report (the throttle's interval 0: what is seen does not depend on the clock)."""
    from planning import pipeline as pl
    from planning.inputs.cloud import Cloud
    from planning.inputs.samples import slot
    from planning.orientations import load_profile
    from planning.placement import search
    from schemas.params import parse_config

    s = slot(density_per_mm2=0.5, seed=1)
    flip = np.diag([1.0, -1.0, -1.0])
    cloud = Cloud(points=s.points @ flip.T + [0.0, 0.0, 30.0], normals=s.normals @ flip.T, source_format="generated")
    config = parse_config(json.loads(json.dumps(_FAST)))
    nrm = pl._normals(cloud, config, None)
    got: list[tuple[float, str]] = []
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(search, "PROGRESS_EVERY_S", 0.0)
        res = search.search_placement(cloud.points, nrm.sample_index, nrm.normals, config,
                                      load_profile(config.machine.profile), config.tool.assembly(),
                                      progress=lambda f, m: got.append((f, m)))
    return res, got


def test_the_placement_search_reports_from_inside_each_candidate(slot_search):
    res, got = slot_search
    fractions = [f for f, _ in got]
    assert all(b >= a for a, b in itertools.pairwise(fractions))                   # never back
    assert fractions[-1] == 1.0 and got[-1][1] == "placement chosen"
    m = len(res.tried)
    messages = [msg for _, msg in got]
    screened = [t for t in res.tried if t.stage in ("screened", "confirmed")]
    assert screened, "no candidate reached the collision test: nothing to check"
    for t in res.tried:
        j = t.index + 1                                   # no pose was skipped: candidate j is index j - 1
        mine = [msg for msg in messages if msg.startswith(f"candidate {j} of {m}:")]
        assert mine[0] == f"candidate {j} of {m}: {t.pose.label}"
        if t in screened:
            # the set-up search and the screening test reported from inside the candidate, in its share
            assert any(": set-ups: " in msg for msg in mine), mine
            assert any("screening collisions, axis" in msg for msg in mine), mine
            share = [f for f, msg in got if msg.startswith(f"candidate {j} of {m}:")]
            assert 0.8 * (j - 1) / m - 1e-12 <= min(share) and max(share) <= 0.8 * j / m + 1e-12
    # the confirmation: the plan's visibility (cloud collisions per axis) and set-up stages speak too
    w = res.winner
    assert w is not None
    conf = [msg for msg in messages if msg.startswith(f"confirming candidate {w.index}: {w.pose.label}")]
    assert any(re.search(r"cloud collisions, axis \d+/\d+", msg) for msg in conf), conf
    assert any(": set-ups: " in msg for msg in conf), conf


# -- the set-up search ---------------------------------------------------------------------------------------------

def test_the_set_up_search_reports_from_below_the_root_and_never_goes_back(monkeypatch):
    """A root child of the branch and bound can take seconds on a range scan: its children (down to
    _PROGRESS_DEPTH) report too, the fraction of the stage never going back. The interval 0: every report seen."""
    from planning.setups import search as ss
    from planning.setups import select_setups

    rng = np.random.default_rng(1)
    axes = rng.normal(size=(40, 3))
    pts = rng.normal(size=(1000, 3))
    V = (pts / np.linalg.norm(pts, axis=1)[:, None]) @ (axes / np.linalg.norm(axes, axis=1)[:, None]).T > 0.55
    monkeypatch.setattr(ss, "_PROGRESS_EVERY_S", 0.0)
    seen = {}
    for depth in (0, ss._PROGRESS_DEPTH):
        monkeypatch.setattr(ss, "_PROGRESS_DEPTH", depth)
        calls: list[tuple[float, str]] = []
        r = select_setups(V, coverage=0.95, max_setups=6, progress=lambda f, m, calls=calls: calls.append((f, m)))
        assert r.status == "optimal" and r.k == 5
        fractions = [f for f, _ in calls]
        assert all(b >= a for a, b in itertools.pairwise(fractions)) and fractions[-1] == 1.0
        seen[depth] = (sum("least overlap" in m for _, m in calls), sum("enough?" in m for _, m in calls),
                       tuple(r.selected.tolist()))
    (lo0, en0, sel0), (lo2, en2, sel2) = seen[0], seen[ss._PROGRESS_DEPTH]
    assert sel0 == sel2                                   # the reports change nothing
    assert lo2 > 5 * lo0 and en2 > en0                    # the least-overlap and existence searches speak inside


def test_the_post_reports_each_area_and_dialect():
    """Issue 34 item 4: the post stage went from 'start' to 'done' with nothing between (2.3-2.7 s on the
    femur-like plan)."""
    from planning.inputs import samples
    from planning.inputs.cloud import Cloud
    from planning.pipeline import run_plan
    from schemas.params import parse_config

    s = samples.half_sphere(n_points=400)
    calls = []
    run_plan(Cloud(points=s.points, normals=s.normals, source_format="generated"),
             parse_config({"normals": {"method": "input"}, "setups": {"max_setups": 2}, "tool": {"diameter_mm": 10},
                           "paths": {"finishing": {"scallop_mm": 1.0}, "roughing": {"step_down_mm": 10}},
                           "simulate": {"enabled": False}}),
             progress=lambda stage, f, m: calls.append((stage, f, m)))
    post = [(f, m) for st, f, m in calls if st == "post" and m.startswith("area ")]
    fr = [f for f, _ in post]
    assert fr == sorted(fr) and len(set(fr)) == len(fr) and 0.0 <= fr[0] and fr[-1] < 1.0
    for area in (0, 1):
        for what in ("iso.nc", "linuxcnc.nc", "moves files"):
            assert any(m.startswith(f"area {area}: ") and m.endswith(what) for _, m in post), (area, what)
