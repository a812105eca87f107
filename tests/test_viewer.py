"""Issue 20: the plan viewer. Its data (viewer.json + the two binary files) decodes back to the plan
(positions within the quantisation step, labels, flags, deviation, tool-tip paths with arcs on their
circles), and the page, driven in a real headless Chromium, loads a finished half-sphere job with the
job's key and refuses it without, draws a canvas holding every area's colour, shows the set-up table
with the plan's machine angles, draws paths and the deviation map on request, and logs no JavaScript
error; ``scanmill view`` serves the same page for a plan directory.

Issue 34: the page opens with every area's finishing paths shown and the roughing paths off (a
translucent toggle); its tables list the set-ups in plan.json's machining_order, with plan.json's
``figures`` (times and input-point counts) formatted as the CLI summary formats them, equal to
plan.json's; its deviation colours are planning/report/deviation.py's ``deviation_colors``.
Until the pipeline fills ``figures``, the module's plan gets hand-made ones (:func:`hand_made_figures`)."""

from __future__ import annotations

import contextlib
import json
import re
import subprocess
import sys
import time

import httpx
import numpy as np
import pytest
from browser import canvas_pixels, chromium, console_entries, js_errors, wait_viewer
from scipy.spatial import cKDTree
from service_fixtures import (
    HALF_SPHERE_PARAMS,
    KEY_A,
    KEY_B,
    ROOT,
    submit,
    wait_status,
    write_half_sphere,
)

from planning.inputs import Cloud, samples
from planning.pipeline import run_plan
from planning.report.deviation import (
    DEVIATION_COLORS,
    DEVIATION_SATURATION,
    deviation_colors,
)
from planning.report.plan_files import write_plan
from planning.report.viewer_data import (
    DEV_UNMEASURED,
    FLAG_INTEGRATED,
    FLAG_UNMACHINED,
    UNLABELLED,
    VIEWER_FILES,
    chords,
    dequantise,
    viewer_index,
)
from planning.toolpath.moves import ARC_CCW, ARC_CW, densify
from scanmill.summary import (  # the CLI summary's own formats: the page's must equal them
    _count,
    _hmm,
    _minutes,
)
from schemas.params import apply_overrides, parse_config

LIGHT = ["normals.method=input", "setups.max_setups=2", "tool.diameter_mm=10", "paths.finishing.scallop_mm=0.2",
         "paths.roughing.step_down_mm=5"]


def _deviation_limit(out) -> float:
    fp = out.result.parameters.paths.finishing
    return fp.tolerance_mm + fp.scallop_mm + (out.result.verification.measuring_bound_mm or 0.0)


def hand_made_figures(out):
    """plan.json ``figures`` (schemas.plan.PlanFigures) made here from the plan's own arrays, for a pipeline
    that does not fill them yet: finished within the deviation limit, not covered (integrated), unreached
    (no kept finishing move), left the rest; the set-ups' path times as an estimate; areas in machining
    order. Plausible, not planning/report/figures.py's exact measure: the viewer shows what it is given."""
    from schemas.plan import AreaFigures, PlanFigures

    n = out.points.shape[0]
    labels = np.asarray(out.input_labels)
    dev = np.asarray(out.extra["simulation"].deviation_mm, float)
    finished = np.abs(np.nan_to_num(dev, nan=np.inf)) <= _deviation_limit(out)
    areas = out.extra["areas"]
    not_covered = np.asarray(out.arrays["integrated"], bool)[areas.nearest_sample] & ~finished
    unreached = np.zeros(n, bool)
    for ap in out.extra["area_paths"]:
        if ap.unmachined is not None:
            unreached[ap.unmachined] = True
    unreached &= ~finished & ~not_covered
    left = ~(finished | not_covered | unreached)
    by_id = {s.id: s for s in out.result.setups}
    rows, total = [], 0.0
    for a in out.result.machining_order:
        mine, p = labels == a, by_id[a].path
        rough = p.roughing.machining_time_s if p.roughing is not None else None
        fin = p.finishing.machining_time_s if p.finishing is not None else None
        both = (rough or 0.0) + (fin or 0.0)
        total += both
        rows.append(AreaFigures(area=a, n_points=int(mine.sum()), finished=int((finished & mine).sum()),
                                left=int((left & mine).sum()), unreached=int((unreached & mine).sum()),
                                not_covered=int((not_covered & mine).sum()), roughing_time_s=rough,
                                finishing_time_s=fin, machining_time_s=both))
    return PlanFigures(n_points=n, measured=True, finished=int(finished.sum()), finished_share=finished.mean(),
                       left=int(left.sum()), left_share=left.mean(), unreached=int(unreached.sum()),
                       unreached_share=unreached.mean(), not_covered=int(not_covered.sum()),
                       not_covered_share=not_covered.mean(), target_coverage=out.result.parameters.setups.coverage,
                       machining_time_s=total, time_source="estimate", areas=rows)


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    s = samples.half_sphere()
    cloud = Cloud(points=s.points, normals=s.normals, source_format="generated")
    out = run_plan(cloud, parse_config(apply_overrides({}, LIGHT)), name="half_sphere")
    if getattr(out.result, "figures", None) is None:          # until the pipeline fills them (issue 34)
        out.result.figures = hand_made_figures(out)
    d = tmp_path_factory.mktemp("plan")
    write_plan(out, d)
    return out, d


def _arrays(d, index, section):
    files = {name: (d / name).read_bytes() for name in VIEWER_FILES[1:]}
    out = {}
    for key, e in section.items():
        raw = files[e["file"]][e["offset"]:e["offset"] + e["length"]]
        out[key] = np.frombuffer(raw, dtype=np.dtype(e["dtype"])).reshape(e["shape"])
    return out


# ------------------------------------------------------------------------------------------ data

def test_viewer_points_decode_to_the_plan(plan):
    out, d = plan
    index = json.loads((d / "viewer.json").read_text())
    assert index["format"] == "scanmill-viewer" and index["points"]["n_shown"] == out.points.shape[0]
    a = _arrays(d, index, index["points"]["arrays"])
    p = dequantise(a["position"], index["points"]["box_min_mm"], index["points"]["box_max_mm"])
    step = (np.array(index["points"]["box_max_mm"]) - index["points"]["box_min_mm"]) / 65535
    assert np.all(np.abs(p - out.points) <= step / 2 + 1e-9)
    assert np.array_equal(np.where(a["label"] == UNLABELLED, -1, a["label"]), out.input_labels)
    areas = out.extra["areas"]
    integrated = out.arrays["integrated"][areas.nearest_sample]
    assert np.array_equal((a["flags"] & FLAG_INTEGRATED) > 0, integrated)
    unmachined = np.zeros(out.points.shape[0], bool)
    for ap in out.extra["area_paths"]:
        if ap.unmachined is not None:
            unmachined[ap.unmachined] = True
    assert unmachined.any() and np.array_equal((a["flags"] & FLAG_UNMACHINED) > 0, unmachined)
    nrm = out.arrays["normals"][areas.nearest_sample]
    assert np.all(np.abs(a["normal"] / 127.0 - nrm / np.linalg.norm(nrm, axis=1, keepdims=True)) <= 0.5 / 127 + 1e-9)
    dev = out.extra["simulation"].deviation_mm
    measured = np.isfinite(dev)
    assert np.array_equal(a["deviation"] == DEV_UNMEASURED, ~measured)
    assert np.all(np.abs(a["deviation"][measured] / 1000.0 - np.clip(dev[measured], -32.767, 32.767))
                  <= 0.0005 + 1e-9)
    # the set-up rows carry the plan's machine angles
    for row, s in zip(index["setups"], out.result.setups):
        assert row["rotary_deg"] == s.rotary_deg and row["id"] == s.id
    assert index["verification"]["status"] == out.result.verification.status
    # plan.json's figures and machining order, as they are
    plan_json = json.loads((d / "plan.json").read_text())
    assert plan_json["figures"] is not None and index["figures"] == plan_json["figures"]
    assert index["machining_order"] == plan_json["machining_order"]


def test_viewer_deviation_colours_are_the_one_convention(plan):
    """viewer.json names deviation.py's colours and saturation, and its table is deviation_colors of
    every micrometre up to the saturation: a point's colour through the table is deviation_colors of its
    (micrometre) deviation, grey where not measured."""
    out, d = plan
    index = json.loads((d / "viewer.json").read_text())
    dv = index["deviation"]
    limit = _deviation_limit(out)
    assert dv["limit_mm"] == pytest.approx(limit)
    assert dv["saturation"] == DEVIATION_SATURATION
    assert dv["colors"] == {k: list(v) for k, v in DEVIATION_COLORS.items()}
    lut = _arrays(d, index, {"lut": dv["lut"]})["lut"]
    first = dv["lut_first_um"]
    assert first <= -DEVIATION_SATURATION * limit * 1000 + 1e-6 and lut.shape == (1 - 2 * first, 3)
    um = np.arange(first, -first + 1)
    assert np.array_equal(lut, deviation_colors(um / 1000.0, limit))
    # each point through the table, as the page reads it (clamped at the ends)
    dev_um = _arrays(d, index, index["points"]["arrays"])["deviation"].astype(int)
    got = lut[np.clip(dev_um, first, -first) - first]
    want = deviation_colors(np.where(dev_um == DEV_UNMEASURED, np.nan, dev_um / 1000.0), limit)
    measured = dev_um != DEV_UNMEASURED
    assert np.array_equal(got[measured], want[measured])
    assert np.all(want[~measured] == DEVIATION_COLORS["unmeasured"])


def test_viewer_paths_are_the_tool_tips_with_arcs_on_their_circles(plan):
    out, d = plan
    index = json.loads((d / "viewer.json").read_text())
    box = index["paths"]["box"]
    step = (np.array(box["max_mm"]) - box["min_mm"]) / 65535
    items = {(i["area"], i["operation"]): i for i in index["paths"]["items"]}
    n_arcs = 0
    for ap in out.extra["area_paths"]:
        for op in ("finishing", "roughing"):
            tp = getattr(ap, op)
            item = items[(ap.area, op)]
            a = _arrays(d, index, {"v": item["vertices"], "u": item["use"]})
            v = dequantise(a["v"], box["min_mm"], box["max_mm"])
            tips = ap.frame.to_part(tp.tip_mm())
            # every move's end point is a vertex, in order
            tree = cKDTree(v)
            dist, _ = tree.query(tips)
            assert dist.max() <= np.linalg.norm(step) / 2 + 1e-6
            # every vertex lies on the path: on a straight move's end or on its arc (dense reference)
            arc = (tp.kind == ARC_CW) | (tp.kind == ARC_CCW)
            n_arcs += int(arc[1:].sum())
            dense, _ = densify(tp, 0.01)
            offset = tp.xyz_mm[0] - tp.tip_mm()[0]
            ref = cKDTree(ap.frame.to_part(dense - offset))
            dv, _ = ref.query(v)
            assert dv.max() <= 0.01 + np.linalg.norm(step), (ap.area, op, dv.max())
            assert set(np.unique(a["u"])) <= {0, 1, 2, 3}
    assert n_arcs > 0                     # the check above covered arcs


def test_viewer_points_are_decimated_to_the_budget_deterministically(plan):
    out, _ = plan
    i1, b1, _ = viewer_index(out, max_points=1000)
    _, b2, _ = viewer_index(out, max_points=1000)
    assert i1["points"]["n_shown"] == 1000 and i1["points"]["n_total"] == out.points.shape[0]
    assert b"".join(b1.parts) == b"".join(b2.parts)


def test_chords_of_a_full_circle_have_the_requested_step():
    from planning.toolpath.frames import area_frame
    from planning.toolpath.moves import PLANE_XY, USE_CUT, Toolpath

    xyz = np.array([[10.0, 0, 0], [10.0, 0, 0]])          # one full ccw circle of radius 10 about the origin
    tp = Toolpath(xyz_mm=xyz, kind=np.array([0, ARC_CCW], np.int8), centre_mm=np.array([[np.nan] * 3, [0, 0, 0.0]]),
                  plane=np.array([0, PLANE_XY], np.int8), use=np.array([0, USE_CUT], np.int8))
    frame = area_frame([0, 0, 1], np.zeros((1, 3)))
    v, use = chords(tp, frame, 1.0)
    local = (v - frame.origin_mm) @ frame.rotation.T
    r = np.hypot(local[1:, 0], local[1:, 1])
    assert np.allclose(r, 10.0) and v.shape[0] == 1 + 63      # ceil(2 pi 10 / 1) = 63 chords
    assert np.all(np.linalg.norm(np.diff(local, axis=0), axis=1) <= 1.0)
    assert list(use) == [0] + [USE_CUT] * 63


# -------------------------------------------------------------------------------------- service

@pytest.fixture(scope="module")
def server(half_sphere_service):
    return half_sphere_service[0]


@pytest.fixture(scope="module")
def job(half_sphere_service):
    srv, j = half_sphere_service
    with srv.client(KEY_A) as c:
        plan = c.get(f"/jobs/{j['id']}/result").json()
    return j["id"], plan


@pytest.fixture(scope="module")
def browser():
    with chromium() as driver:
        yield driver


def _colour_pixels(px: np.ndarray, rgb) -> int:
    return int(np.count_nonzero(np.all(np.abs(px.astype(int) - np.array(rgb)) <= 2, axis=-1)))


def _shaded_pixels(px: np.ndarray, rgb) -> int:
    """Pixels that are ``rgb`` times a shading factor in [0.3, 1] (the headlight's range is [0.35, 1])."""
    c = np.array(rgb, float)
    p = px.reshape(-1, 3).astype(float)
    f = p @ c / (c @ c)
    ok = (f >= 0.3) & (f <= 1.02) & (np.abs(p - f[:, None] * c).max(axis=1) <= 3.0)
    return int(np.count_nonzero(ok))


def _click_and_draw(browser, selector: str) -> None:
    """Click a control and wait (bounded) until the page has drawn a new frame."""
    frames = browser.execute_script("return window.scanmillViewer.frames")
    browser.find_element("css selector", selector).click()
    for _ in range(100):
        if browser.execute_script("return window.scanmillViewer.frames") > frames:
            return
        time.sleep(0.05)
    raise AssertionError(f"no new frame after clicking {selector}")


def test_page_loads_the_job_with_its_key(server, job, browser):
    job_id, plan = job
    browser.get(f"{server.url}/jobs/{job_id}/viewer")
    state = wait_viewer(browser)
    assert state["keyform"] and not state["ready"], state          # no key yet: asked for, nothing drawn
    browser.find_element("id", "key").send_keys(KEY_A)
    browser.find_element("css selector", "#keyform button").click()
    state = wait_viewer(browser, paths=True)
    assert state["ready"] and state["pathsReady"] and state["error"] is None, state
    assert KEY_A not in browser.current_url
    colours = browser.execute_script("return window.scanmillViewer.index.colors.areas")
    assert len(colours) == len(plan["setups"]) == 2
    # shaded by default (the light from the eye): every area's colour, darkened by the shading
    px = canvas_pixels(browser)
    for rgb in colours:
        assert _shaded_pixels(px, rgb) >= 500, (rgb, _shaded_pixels(px, rgb))
    # flat: the palette's exact bytes
    _click_and_draw(browser, "#shading")
    px = canvas_pixels(browser)
    for rgb in colours:
        assert _colour_pixels(px, rgb) >= 200, (rgb, _colour_pixels(px, rgb))
    # the set-up table: one row per set-up, in machining order, with the plan's machine angles
    rows = browser.find_elements("css selector", "#setups tbody tr")
    assert len(rows) == len(plan["setups"])
    names = plan["orientations"]["rotary_axes"]
    by_id = {s["id"]: s for s in plan["setups"]}
    assert [int(r.get_attribute("data-setup")) for r in rows] == plan["machining_order"]
    for row, s in zip(rows, [by_id[a] for a in plan["machining_order"]]):
        assert row.find_element("css selector", ".rot0").text == f"{s['rotary_deg'][names[0]]:.3f}"
        assert row.find_element("css selector", ".rot1").text == f"{s['rotary_deg'][names[1]]:.3f}"
    head = browser.find_element("css selector", "#setups thead").text
    assert f"{names[0]} (deg)" in head and f"{names[1]} (deg)" in head
    assert browser.find_element("id", "verdict").text.lower() == f"verification {plan['verification']['status']}"
    entries = console_entries(browser)
    assert js_errors(browser, entries) == []
    # the one failed load is the first try without a key (answered 401, which asked for the key)
    network = [e["message"] for e in entries if e.get("source") == "network"]
    assert len(network) == 1 and "viewer.json" in network[0] and "401" in network[0], network
    assert KEY_A not in server.log_text()


def _checked(browser, selector: str) -> list[bool]:
    return [e.is_selected() for e in browser.find_elements("css selector", selector)]


def test_paths_and_deviation_map_draw_on_request(server, job, browser):
    """Finishing paths shown from the start, roughing off; each switch redraws; the deviation colours are
    deviation.py's (green within the limit, exact bytes when flat) and hide the paths until the area
    colours bring them back."""
    job_id, _ = job
    browser.get(f"{server.url}/jobs/{job_id}/viewer")         # the key is kept for the tab's session
    state = wait_viewer(browser, paths=True)
    assert state["pathsReady"], state
    assert _checked(browser, '.toggle-path[data-op="finishing"]') == [True, True]
    assert _checked(browser, '.toggle-path[data-op="roughing"]') == [False, False]
    assert _checked(browser, "#show-finishing, #show-roughing, #show-rapids") == [True, False, False]
    _click_and_draw(browser, "#show-axes")             # axes off: only scan and paths
    _click_and_draw(browser, "#shading")               # flat colours: exact bytes below
    before = canvas_pixels(browser)
    _click_and_draw(browser, 'tr[data-setup="0"] .toggle-path[data-op="finishing"]')     # off
    after = canvas_pixels(browser)
    assert np.count_nonzero(np.any(after != before, axis=-1)) > 1000
    _click_and_draw(browser, "#show-roughing")                                              # every area's on
    rough = canvas_pixels(browser)
    assert _checked(browser, '.toggle-path[data-op="roughing"]') == [True, True]
    assert np.count_nonzero(np.any(rough != after, axis=-1)) > 1000
    # the scan stays visible through the translucent roughing: most of its area-coloured pixels keep a
    # colour close to their own
    colours = browser.execute_script("return window.scanmillViewer.index.colors.areas")
    near = sum(int(np.count_nonzero(np.all(np.abs(rough.astype(int) - c) <= 60, axis=-1))) for c in colours)
    exact = sum(_colour_pixels(after, c) for c in colours)
    assert near >= 0.8 * exact, (near, exact)
    _click_and_draw(browser, "#show-roughing")
    _click_and_draw(browser, "#colour-deviation")
    assert not any(_checked(browser, ".toggle-path, #show-finishing, #show-roughing"))     # the map uncovered
    dev = canvas_pixels(browser)
    assert _colour_pixels(dev, DEVIATION_COLORS["within"]) > 200          # within tolerance: deviation.py's green
    assert browser.find_element("id", "colourbar").is_displayed()
    limit = browser.execute_script("return window.scanmillViewer.index.deviation.limit_mm")
    legend = browser.find_element("id", "colourbar-legend").text
    assert f"{limit:.3f}" in legend and "blue: material left" in legend and "red: cut below the scan" in legend
    ticks = browser.find_element("id", "colourbar-ticks").text
    assert f"{DEVIATION_SATURATION * limit:.3f}" in ticks
    # the page's colour of a deviation is deviation_colors' (whole micrometres: the data's resolution)
    um = np.array([0, 1, int(limit * 1000), int(limit * 1000) + 1, -int(limit * 1000) - 1, int(3 * limit * 1000),
                   -int(3 * limit * 1000), int(DEVIATION_SATURATION * limit * 1000) + 5000, -40000])
    want = deviation_colors(np.append(um / 1000.0, np.nan), limit)
    got = browser.execute_script("return arguments[0].map((d) => window.scanmillViewer.deviationColour(d))",
                                 [*(um / 1000.0).tolist(), None])
    assert np.array_equal(np.array(got), want), (got, want.tolist())
    # back to the area colours: the path switches as they were
    _click_and_draw(browser, 'input[name=colour][value=area]')
    assert _checked(browser, 'tr[data-setup="0"] .toggle-path[data-op="finishing"]') == [False]
    assert _checked(browser, 'tr[data-setup="1"] .toggle-path[data-op="finishing"]') == [True]
    assert _checked(browser, '.toggle-path[data-op="roughing"], #show-roughing') == [False, False, False]
    assert _checked(browser, "#show-finishing") == [True]
    assert js_errors(browser) == []


def test_page_refuses_without_the_right_key(server, job, browser):
    job_id, _ = job
    # the data itself: 401 without a key, 404 for another key (jobs are per key)
    assert httpx.get(f"{server.url}/jobs/{job_id}/artifacts/viewer.json").status_code == 401
    with server.client(KEY_B) as b:
        assert b.get(f"/jobs/{job_id}/artifacts/viewer.points.bin").status_code == 404
    browser.execute_script("sessionStorage.clear()")
    browser.get(f"{server.url}/jobs/{job_id}/viewer")
    state = wait_viewer(browser)
    assert state["keyform"] and not state["ready"] and state["bytes"] == 0
    browser.find_element("id", "key").send_keys("not-a-key")
    browser.find_element("css selector", "#keyform button").click()
    time.sleep(0.5)
    state = wait_viewer(browser)
    assert state["keyform"] and "refused" in state["status"] and not state["ready"], state
    browser.execute_script("sessionStorage.clear()")
    browser.get(f"{server.url}/jobs/{job_id}/viewer")
    wait_viewer(browser)
    browser.find_element("id", "key").send_keys(KEY_B)
    browser.find_element("css selector", "#keyform button").click()
    state = wait_viewer(browser)
    assert state["error"] and "No such plan or job" in state["error"] and not state["ready"], state
    assert state["bytes"] == 0
    browser.execute_script("sessionStorage.clear()")


def test_viewer_page_headers_and_unknown_ids(server):
    r = httpx.get(f"{server.url}/jobs/not-a-job/viewer")
    assert r.status_code == 404 and r.headers["content-type"].startswith("application/problem+json")
    r = httpx.get(f"{server.url}/viewer/static/vendor/three/LICENSE")
    assert r.status_code == 200 and "MIT" in r.text


# ------------------------------------------------------------------------------------ scanmill view

@contextlib.contextmanager
def _scanmill_view(d):
    """``scanmill view d`` running: ``(base URL, key, printed address)``."""
    proc = subprocess.Popen([sys.executable, "-m", "scanmill.cli", "view", str(d)], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        line = proc.stdout.readline()
        m = re.search(r"(http://127\.0\.0\.1:(\d+))/#key=(\S+)", line)
        assert m, line
        base = m.group(1)
        for _ in range(100):
            try:
                if httpx.get(base + "/").status_code == 200:
                    break
            except httpx.TransportError:
                time.sleep(0.1)
        yield base, m.group(3), m.group(0)
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def test_scanmill_view_serves_a_plan_directory(plan, browser, tmp_path):
    _, d = plan
    with _scanmill_view(d) as (base, key, address):
        refused = httpx.get(base + "/artifacts/viewer.json")
        assert refused.status_code == 401 and refused.json()["code"] == "unauthenticated"
        assert refused.headers["content-type"].startswith("application/problem+json")
        r = httpx.get(base + "/artifacts/viewer.json", headers={"Authorization": f"Bearer {key}"})
        assert r.status_code == 200 and r.json()["format"] == "scanmill-viewer"
        assert httpx.get(base + "/artifacts/area_0.linuxcnc.nc",
                         headers={"Authorization": f"Bearer {key}"}).status_code == 404      # only the page's data
        browser.execute_script("sessionStorage.clear()")
        browser.get(address)
        state = wait_viewer(browser, paths=True)
        assert state["ready"] and state["pathsReady"], state
        assert "key=" not in browser.current_url                  # the fragment is dropped once read
        assert js_errors(browser) == []


def _share(x) -> str:
    """As scanmill/summary.py prints shares ('{:.1%}')."""
    return "-" if x is None else f"{x:.1%}"


def test_page_shows_plan_json_figures_in_machining_order(plan, browser):
    """The time and point table is plan.json's ``figures``: a row per area in machining order (roughing,
    finishing, total minutes; finished, left, unreached, not covered input points), the plan's totals and
    shares below, formatted as the CLI summary formats them (Python's rounding, halves to even)."""
    _, d = plan
    pj = json.loads((d / "plan.json").read_text())
    fig = pj["figures"]
    with _scanmill_view(d) as (_, _, address):
        browser.execute_script("sessionStorage.clear()")
        browser.get(address)
        state = wait_viewer(browser, paths=True)
        assert state["pathsReady"], state
        order = [int(r.get_attribute("data-setup")) for r in browser.find_elements("css selector", "#setups tbody tr")]
        assert order == pj["machining_order"] == [a["area"] for a in fig["areas"]]
        assert browser.find_element("id", "figures").is_displayed()
        rows = browser.find_elements("css selector", "#figures tbody tr")
        assert len(rows) == len(fig["areas"])
        for k, (row, a) in enumerate(zip(rows, fig["areas"])):
            cells = [c.text for c in row.find_elements("css selector", "td")]
            assert cells == [str(k + 1), str(a["area"]), _minutes(a["roughing_time_s"]), _minutes(a["finishing_time_s"]),
                             _minutes(a["machining_time_s"]), _count(a["finished"]), _count(a["left"]),
                             _count(a["unreached"]), _count(a["not_covered"])], (cells, a)
        total, shares = ([c.text for c in r.find_elements("css selector", "td")]
                         for r in browser.find_elements("css selector", "#figures tfoot tr"))
        assert total[4:] == [_minutes(fig["machining_time_s"]), _count(fig["finished"]), _count(fig["left"]),
                             _count(fig["unreached"]), _count(fig["not_covered"])], total
        assert shares[4:] == [_hmm(fig["machining_time_s"]), _share(fig["finished_share"]), _share(fig["left_share"]),
                              _share(fig["unreached_share"]), _share(fig["not_covered_share"])], shares
        assert browser.find_element("id", "figures-time").text == fig["time_source"]
        note = browser.find_element("id", "figures-note").text
        assert f"{fig['n_points']:,} input points" in note and fig["time_source"] in note
        # the page's formatting is Python's, exact halves included (JavaScript's toFixed rounds them up)
        seconds = [0.0, 15.0, 45.0, 75.0, 90.0, 150.0, 29.97, 8290.9, 5430.0, 3570.0, 1e6 + 0.3]
        got = browser.execute_script("const f = window.scanmillViewer.format;"
                                     "return arguments[0].map((s) => [f.minutes(s), f.hmm(s)])", seconds)
        assert got == [[_minutes(x), _hmm(x)] for x in seconds]
        shares_in = [0.0, 0.9645, 0.00125, 0.5, 1.0, 0.123456, 0.0005]
        got = browser.execute_script("return arguments[0].map((x) => window.scanmillViewer.format.share(x))", shares_in)
        assert got == [_share(x) for x in shares_in]
        assert js_errors(browser) == []


def test_scanmill_view_refuses_a_directory_without_a_plan(tmp_path):
    r = subprocess.run([sys.executable, "-m", "scanmill.cli", "view", str(tmp_path)], cwd=ROOT, capture_output=True,
                       check=False, text=True, timeout=120)
    assert r.returncode == 2 and "error [not_a_plan]" in r.stderr and "viewer.json" in r.stderr


def test_semi_finishing_paths_are_off_at_first_and_switch_on_together(server, browser, tmp_path):
    """A plan with semi-finishing (paths.semi_finishing): its paths load with the others, every row's
    semi switch enabled and off when the page opens; "semi-finishing paths of every area" turns them all
    on and draws them; the finishing switches are untouched. The figures table has a semi column."""
    import copy

    params = copy.deepcopy(HALF_SPHERE_PARAMS)
    params["paths"]["semi_finishing"] = {"enabled": True, "scallop_mm": 0.2}
    cloud = write_half_sphere(tmp_path / "half_sphere.ply")
    with server.client(KEY_A) as c:
        r = submit(c, cloud, params)
        assert r.status_code == 202, r.text
        job = wait_status(c, r.json()["id"])
    assert job["status"] == "succeeded", job
    browser.get(f"{server.url}/jobs/{job['id']}/viewer")
    state = wait_viewer(browser, paths=True)
    if state.get("keyform"):                      # a test before may have left the tab without the key
        browser.find_element("id", "key").send_keys(KEY_A)
        browser.find_element("css selector", "#keyform button").click()
        state = wait_viewer(browser, paths=True)
    assert state["pathsReady"] and state["error"] is None, state
    semi = browser.find_elements("css selector", '.toggle-path[data-op="semi_finishing"]')
    assert len(semi) == 2 and all(e.is_enabled() for e in semi)
    assert _checked(browser, '.toggle-path[data-op="semi_finishing"], #show-semi') == [False, False, False]
    _click_and_draw(browser, "#show-axes")
    _click_and_draw(browser, "#shading")
    before = canvas_pixels(browser)
    _click_and_draw(browser, "#show-semi")
    assert _checked(browser, '.toggle-path[data-op="semi_finishing"]') == [True, True]
    assert _checked(browser, '.toggle-path[data-op="finishing"]') == [True, True]
    assert np.count_nonzero(np.any(canvas_pixels(browser) != before, axis=-1)) > 1000
    # the figures table has a semi-finishing column, as the CLI summary, so that each row adds up
    fig = browser.execute_script("return window.scanmillViewer.index.figures")
    heads = [th.text for th in browser.find_elements("css selector", "#figures thead tr:nth-child(2) th")]
    assert heads[:4] == ["rough", "semi", "finish", "total"], heads
    assert browser.find_element("id", "figures-minutes").get_attribute("colspan") == "4"
    rows = browser.find_elements("css selector", "#figures tbody tr")
    assert len(rows) == len(fig["areas"]) == 2
    for row, a in zip(rows, fig["areas"], strict=True):
        cells = [c.text for c in row.find_elements("css selector", "td")]
        assert a["semi_finishing_time_s"] > 0
        assert cells[2:6] == [_minutes(a["roughing_time_s"]), _minutes(a["semi_finishing_time_s"]),
                              _minutes(a["finishing_time_s"]), _minutes(a["machining_time_s"])], (cells, a)
        assert len(cells) == 10
    for r in browser.find_elements("css selector", "#figures tfoot tr"):
        assert len(r.find_elements("css selector", "td")) == 10
    assert js_errors(browser, console_entries(browser)) == []
