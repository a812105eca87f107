"""Page load of the plan viewer (issue 20): time to the first frame and bytes transferred, in headless
Chromium on loopback, for a job of the service (default: the femur-like reference, 1,000,000 points,
planned with `make run`'s parameters) or for a plan directory (``--plan-dir``, through `scanmill view`).

Each load uses a new browser profile (nothing cached). Reported per load: the first frame (ms since
the navigation started: page, scripts, viewer.json and viewer.points.bin fetched, the scan uploaded
to the GPU and drawn once), the paths ready (viewer.paths.bin too), and the bytes the page received
(Resource Timing transferSize: headers and bodies, the page and three.js included). Chromium draws
with SwiftShader (software WebGL, no GPU), as CI would: a desktop with a GPU draws faster.

    python bench/bench_viewer.py --repeat 3 --screenshot docs/images/viewer_femur.png
    python bench/bench_viewer.py --plan-dir scanmill-out/f --repeat 3
"""

from __future__ import annotations

import argparse
import gzip
import json
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "scripts")]

from browser import chromium, js_errors, wait_viewer

KEY = "bench-viewer-key-0123456789"


def _job(args) -> tuple[str, subprocess.Popen, dict]:
    """Start `scanmill serve` with a key, plan the sample through it; (viewer URL, server, job)."""
    import httpx
    from demo_service import CONFIGS
    from service_fixtures import ServerProcess

    from planning.inputs import samples
    from planning.report.files import write_ply

    data = Path(args.data_dir)
    data.mkdir(parents=True, exist_ok=True)
    srv = ServerProcess(data / "data", api_keys=[KEY], workers=1, job_time_limit_s=3600).start()
    cloud = data / f"{args.sample}.ply"
    s = getattr(samples, args.sample)(**({"n_points": args.points} if args.points else {}))
    write_ply(cloud, s.points, normals=s.normals)
    with httpx.Client(base_url=srv.url, headers={"Authorization": f"Bearer {KEY}"}, timeout=120) as c:
        with open(cloud, "rb") as fh:
            r = c.post("/jobs", files={"cloud": (cloud.name, fh, "application/octet-stream")},
                       data={"parameters": json.dumps(CONFIGS[args.sample])})
        r.raise_for_status()
        job_id = r.json()["id"]
        t0 = time.perf_counter()
        last = None
        while time.perf_counter() - t0 < args.max_wait_s:
            job = c.get(f"/jobs/{job_id}").json()
            if job["stage"] != last:
                print(f"  [{time.perf_counter() - t0:7.1f} s] {job['status']} {job['stage'] or ''}", flush=True)
                last = job["stage"]
            if job["status"] in ("succeeded", "failed", "cancelled"):
                break
            time.sleep(2.0)
        if job["status"] != "succeeded":
            raise SystemExit(f"job {job_id} ended {job['status']}: {job.get('error')}")
        sizes = {a["name"]: a["size_bytes"] for a in c.get(f"/jobs/{job_id}/artifacts").json()["items"]}
        # what gzip (level 6, as a web server would) would make of the viewer's binaries
        gz = {name: len(gzip.compress(c.get(f"/jobs/{job_id}/artifacts/{name}").content, 6))
              for name in ("viewer.points.bin", "viewer.paths.bin")}
    return f"{srv.url}/jobs/{job_id}/viewer", srv, {"id": job_id, "sizes": sizes, "gzip": gz}


def _local(plan_dir: str) -> tuple[str, subprocess.Popen]:
    proc = subprocess.Popen([sys.executable, "-m", "scanmill.cli", "view", plan_dir], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    line = proc.stdout.readline()
    m = re.search(r"(http://\S+)", line)
    if not m:
        proc.kill()
        raise SystemExit(f"scanmill view did not start: {line}{proc.stdout.read()}")
    time.sleep(2.0)
    return m.group(1), proc


def _load(url: str, key: str | None, screenshot: str | None) -> dict:
    with chromium(1600, 1000) as d:
        if key:                               # the key as the page takes it, before the first fetch
            d.get(url.split("/jobs/")[0] + "/healthz")
            d.execute_script(f"sessionStorage.setItem('scanmill-key:' + location.origin, {json.dumps(key)})")
        d.get(url)
        state = wait_viewer(d, paths=True, polls=1200)
        if not state.get("pathsReady"):
            raise SystemExit(f"the page did not finish: {state}")
        sent = d.execute_script(
            "const e = performance.getEntriesByType('navigation').concat(performance.getEntriesByType('resource'));"
            "return e.map(x => [x.name, x.transferSize, x.encodedBodySize]);")
        if screenshot:
            Path(screenshot).parent.mkdir(parents=True, exist_ok=True)
            d.save_screenshot(screenshot)
        return {"first_frame_ms": state["firstFrameMs"], "paths_ms": d.execute_script(
                    "return window.scanmillViewer.pathsMs"),
                "bytes": sum(int(x[1]) for x in sent), "by_file": {x[0].rsplit("/", 1)[-1]: int(x[1]) for x in sent},
                "errors": js_errors(d)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plan-dir", help="load this plan directory through `scanmill view` instead of a service job")
    ap.add_argument("--sample", default="femur_like", help="sample planned through the service (default femur_like)")
    ap.add_argument("--points", type=int, help="points of the sample (default: its reference size)")
    ap.add_argument("--data-dir", default="bench/out/viewer", help="service data and the sample (default bench/out/viewer)")
    ap.add_argument("--repeat", type=int, default=3, help="page loads, each in a new browser profile")
    ap.add_argument("--screenshot", help="PNG of the page after the last load")
    ap.add_argument("--max-wait-s", type=float, default=1800.0)
    args = ap.parse_args(argv)

    srv = proc = None
    try:
        if args.plan_dir:
            url, proc = _local(args.plan_dir)
            key, info = None, {}
        else:
            url, srv, info = _job(args)
            key = KEY
        loads = []
        for i in range(args.repeat):
            r = _load(url, key, args.screenshot if i == args.repeat - 1 else None)
            loads.append(r)
            print(f"load {i + 1}: first frame {r['first_frame_ms'] / 1000:.2f} s, paths {r['paths_ms'] / 1000:.2f} s, "
                  f"{r['bytes'] / 1e6:.1f} MB, script errors {len(r['errors'])}", flush=True)
        ff = [r["first_frame_ms"] / 1000 for r in loads]
        pt = [r["paths_ms"] / 1000 for r in loads]
        print(f"\nfirst frame s: min {min(ff):.2f} median {statistics.median(ff):.2f} max {max(ff):.2f}")
        print(f"paths ready s: min {min(pt):.2f} median {statistics.median(pt):.2f} max {max(pt):.2f}")
        print(f"bytes transferred: {loads[-1]['bytes']:,} ({loads[-1]['bytes'] / 1e6:.1f} MB)")
        for name, n in sorted(loads[-1]["by_file"].items(), key=lambda kv: -kv[1]):
            print(f"  {n:>12,}  {name}")
        for name, n in (info.get("gzip") or {}).items():
            print(f"  gzip -6 of {name}: {n:,} bytes ({n / info['sizes'][name]:.0%} of {info['sizes'][name]:,})")
        if info.get("sizes"):
            print("\nartifacts of the job (bytes):")
            for name, n in sorted(info["sizes"].items()):
                print(f"  {n:>12,}  {name}")
    finally:
        if proc is not None:
            proc.terminate()
        if srv is not None:
            srv.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
