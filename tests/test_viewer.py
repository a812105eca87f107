"""Issue 20: the plan viewer. Its data (viewer.json + the two binary files) decodes back to the plan
(positions within the quantisation step, labels, flags, deviation, tool-tip paths with arcs on their
circles), and the page, driven in a real headless Chromium, loads a finished half-sphere job with the
job's key and refuses it without, draws a canvas holding every area's colour, shows the set-up table
with the plan's machine angles, draws paths and the deviation map on request, and logs no JavaScript
error; ``scanmill view`` serves the same page for a plan directory."""

from __future__ import annotations

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
    KEY_A,
    KEY_B,
    ROOT,
)

from planning.inputs import Cloud, samples
from planning.pipeline import run_plan
from planning.report.plan_files import write_plan
from planning.report.viewer_data import (
    FLAG_INTEGRATED,
    FLAG_UNMACHINED,
    UNLABELLED,
    VIEWER_FILES,
    chords,
    dequantise,
    viewer_index,
)
from planning.toolpath.moves import ARC_CCW, ARC_CW, densify
from schemas.params import apply_overrides, parse_config

LIGHT = ["normals.method=input", "setups.max_setups=2", "tool.diameter_mm=10", "paths.finishing.scallop_mm=0.2",
         "paths.roughing.step_down_mm=5"]


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    s = samples.half_sphere()
    cloud = Cloud(points=s.points, normals=s.normals, source_format="generated")
    out = run_plan(cloud, parse_config(apply_overrides({}, LIGHT)), name="half_sphere")
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
    assert np.all(np.abs(a["deviation"] / 1000.0 - np.clip(dev, -32.767, 32.767)) <= 0.0005 + 1e-9)
    # the set-up rows carry the plan's machine angles
    for row, s in zip(index["setups"], out.result.setups):
        assert row["rotary_deg"] == s.rotary_deg and row["id"] == s.id
    assert index["verification"]["status"] == out.result.verification.status


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
    # the set-up table: one row per set-up with the plan's machine angles
    rows = browser.find_elements("css selector", "#setups tbody tr")
    assert len(rows) == len(plan["setups"])
    names = plan["orientations"]["rotary_axes"]
    for row, s in zip(rows, plan["setups"]):
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


def test_paths_and_deviation_map_draw_on_request(server, job, browser):
    job_id, _ = job
    browser.get(f"{server.url}/jobs/{job_id}/viewer")         # the key is kept for the tab's session
    state = wait_viewer(browser, paths=True)
    assert state["pathsReady"], state
    _click_and_draw(browser, "#show-axes")             # axes off: only scan and paths
    _click_and_draw(browser, "#shading")               # flat colours: exact bytes below
    before = canvas_pixels(browser)
    _click_and_draw(browser, 'tr[data-setup="0"] .toggle-path[data-op="finishing"]')
    after = canvas_pixels(browser)
    assert np.count_nonzero(np.any(after != before, axis=-1)) > 1000
    _click_and_draw(browser, "#colour-deviation")
    dev = canvas_pixels(browser)
    assert _colour_pixels(dev, (40, 170, 60)) > 200               # within tolerance: green
    assert browser.find_element("id", "colourbar").is_displayed()
    ticks = browser.find_element("id", "colourbar-ticks").text
    limit = browser.execute_script("return window.scanmillViewer.index.deviation.limit_mm")
    assert f"{limit:.3f}" in ticks
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

def test_scanmill_view_serves_a_plan_directory(plan, browser, tmp_path):
    _, d = plan
    proc = subprocess.Popen([sys.executable, "-m", "scanmill.cli", "view", str(d)], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        line = proc.stdout.readline()
        m = re.search(r"(http://127\.0\.0\.1:(\d+))/#key=(\S+)", line)
        assert m, line
        base, key = m.group(1), m.group(3)
        for _ in range(100):
            try:
                if httpx.get(base + "/").status_code == 200:
                    break
            except httpx.TransportError:
                time.sleep(0.1)
        refused = httpx.get(base + "/artifacts/viewer.json")
        assert refused.status_code == 401 and refused.json()["code"] == "unauthenticated"
        assert refused.headers["content-type"].startswith("application/problem+json")
        r = httpx.get(base + "/artifacts/viewer.json", headers={"Authorization": f"Bearer {key}"})
        assert r.status_code == 200 and r.json()["format"] == "scanmill-viewer"
        assert httpx.get(base + "/artifacts/area_0.linuxcnc.nc",
                         headers={"Authorization": f"Bearer {key}"}).status_code == 404      # only the page's data
        browser.execute_script("sessionStorage.clear()")
        browser.get(m.group(0))
        state = wait_viewer(browser, paths=True)
        assert state["ready"] and state["pathsReady"], state
        assert "key=" not in browser.current_url                  # the fragment is dropped once read
        assert js_errors(browser) == []
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def test_scanmill_view_refuses_a_directory_without_a_plan(tmp_path):
    r = subprocess.run([sys.executable, "-m", "scanmill.cli", "view", str(tmp_path)], cwd=ROOT, capture_output=True,
                       check=False, text=True, timeout=120)
    assert r.returncode == 2 and "error [not_a_plan]" in r.stderr and "viewer.json" in r.stderr
