#!/usr/bin/env python3
"""The main job, through the service: start ``scanmill serve``, plan a sample scan over HTTP, fetch the results.

1. starts ``scanmill serve`` on 127.0.0.1 (a free port) with its embedded defaults: the SQLite job
   store and files in ``--data-dir`` (default ``./scanmill-data``), local worker processes;
2. writes the femur-like reference scan (1,000,000 points, no normals: a raw scan) or the paper's
   half sphere, and submits it with its plan configuration (``POST /jobs``, multipart);
3. polls ``GET /jobs/{id}`` and prints a line per stage and progress step;
4. downloads plan.json and every artifact to ``--out/<sample>-service/`` and prints where they are;
5. stops the server (SIGTERM: it finishes cleanly).

Exit status: 0 planned, 3 planned but infeasible or incomplete, 1 the job failed or the service did not start.
Only the standard library and httpx are used on the client side, as any HTTP client could.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import time
import uuid
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]

# docs/design.md reference cases: the configuration each is planned with. Collisions (global visibility)
# and the machine's X/Y/Z travel are checked, the femur standing on a 150 mm riser (at the default 50 mm
# the table blocks its underside: 93.9 % at k = 5). On the default compact trunnion the 400 mm part
# tilted past 90 deg puts its ends below what the spindle can reach, so its underside is out of reach
# from one clamping: 85.8 % is the best 5 set-ups reach within the travel, and the coverage asked for
# is 85 % (with travel unchecked 95 % would be "covered" by set-ups whose programs leave the travel,
# and the guard would cut all their moves out).
CONFIGS = {
    "femur_like": {"normals": {"method": "sphere_throwing", "sphere_diameter_mm": 7.0},
                   "tool": {"diameter_mm": 6.0}, "fixtures": {"fixture_height_mm": 150.0},
                   "visibility": {"cone_deg": [10, 60], "global": True, "travel": True},
                   "setups": {"coverage": 0.85, "max_setups": 5}},
    "half_sphere": {"normals": {"method": "input"}, "tool": {"diameter_mm": 10.0},
                    "orientations": {"phi_step_deg": 10, "theta_step_deg": 30},
                    "visibility": {"cone_deg": [10, 80]}, "setups": {"coverage": 0.95, "max_setups": 2}},
}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _say(t0: float, text: str) -> None:
    print(f"[{time.monotonic() - t0:7.2f} s] {text}", flush=True)


def write_sample(name: str, path: Path, n_points: int | None) -> int:
    """Write the sample as binary PLY (the femur without normals, like a raw scan); return its point count."""
    sys.path.insert(0, str(ROOT))
    from planning.inputs.samples import make_sample
    from planning.report.files import write_ply

    kwargs = {"n_points": n_points} if n_points else {}
    s = make_sample(name, **kwargs)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_ply(path, s.points, normals=s.normals if name == "half_sphere" else None, binary=True)
    return int(s.points.shape[0])


def start_server(data_dir: Path, port: int, log_path: Path, workers: int | None) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "scanmill.cli", "serve", "--host", "127.0.0.1", "--port", str(port),
           "--data-dir", str(data_dir)]
    if workers:
        cmd += ["--workers", str(workers)]
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with open(log_path, "wb") as log:            # the server keeps its own copy of the descriptor
        return subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)


def wait_ready(proc: subprocess.Popen, url: str, polls: int = 600) -> bool:
    for _ in range(polls):
        if proc.poll() is not None:
            return False
        try:
            if httpx.get(url + "/healthz", timeout=2).status_code == 200:
                return True
        except httpx.TransportError:
            pass
        time.sleep(0.1)
    return False


def stop_server(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(30)


def run(args) -> int:
    t0 = time.monotonic()
    out_dir = Path(args.out) / f"{args.sample}-service"
    scan = Path(args.out) / f"{args.sample}.ply"
    port = args.port or _free_port()
    url = f"http://127.0.0.1:{port}"
    key = os.environ.get("SCANMILL_DEMO_API_KEY")
    headers = {"Authorization": f"Bearer {key}"} if key else {}

    _say(t0, f"starting scanmill serve on {url} (data: {Path(args.data_dir).resolve()})")
    proc = start_server(Path(args.data_dir).resolve(), port, Path(args.out) / "service.log", args.workers)
    try:
        if not wait_ready(proc, url):
            print(f"error: the service did not start; see {Path(args.out) / 'service.log'}", file=sys.stderr)
            return 1
        _say(t0, f"service ready: {httpx.get(url + '/version').json()}")
        n = write_sample(args.sample, scan, args.points)
        _say(t0, f"wrote the {args.sample} scan: {scan} ({n:,} points, {scan.stat().st_size / 1e6:.1f} MB)")

        client = httpx.Client(base_url=url, headers=headers, timeout=600)
        params = CONFIGS[args.sample]
        if args.set:
            from schemas.params import apply_overrides

            params = apply_overrides(params, args.set)
        with open(scan, "rb") as fh:
            r = client.post("/jobs", files={"cloud": (scan.name, fh, "application/octet-stream")},
                            data={"parameters": json.dumps(params)},
                            headers={"Idempotency-Key": str(uuid.uuid4())})
        if r.status_code != 202:
            print(f"error: the service refused the job ({r.status_code}): {r.text}", file=sys.stderr)
            return 1
        job = r.json()
        _say(t0, f"submitted: {r.headers['location']} (status {job['status']})")

        last = None
        for _ in range(int(args.max_wait_s / 0.25)):
            job = client.get(f"/jobs/{job['id']}").json()
            state = (job["status"], job["stage"], round(job["progress"], 2))
            if state != last:
                _say(t0, f"{job['status']:<9} {job['stage'] or '-':<12} {job['progress']:4.0%}  {job['message'] or ''}")
                last = state
            if job["status"] in ("succeeded", "failed", "cancelled"):
                break
            time.sleep(0.25)
        if job["status"] != "succeeded":
            err = job.get("error") or {}
            print(f"error: job {job['id']} {job['status']}: [{err.get('code')}] {err.get('message')}", file=sys.stderr)
            return 1

        out_dir.mkdir(parents=True, exist_ok=True)
        for item in client.get(job["links"]["artifacts"]).json()["items"]:
            with client.stream("GET", item["href"]) as resp, open(out_dir / item["name"], "wb") as fh:
                for chunk in resp.iter_bytes():
                    fh.write(chunk)
        plan = client.get(job["links"]["result"]).json()
        # the job's own record (GET /jobs/{id}: status, times, the result headline) beside its artifacts
        (out_dir / "job.json").write_text(json.dumps(job, indent=1))
        print(plan["message"])
        for s in plan["setups"]:
            rot = " ".join(f"{k}{v:+.1f}" for k, v in s["rotary_deg"].items())
            print(f"  set-up {s['id']}: tool axis ({s['tool_axis'][0]:+.3f}, {s['tool_axis'][1]:+.3f}, "
                  f"{s['tool_axis'][2]:+.3f})  {rot}  {s['n_points']} points")
            path = s.get("path") or {}
            rough = path.get("roughing")
            if rough:
                print(f"    roughing: {rough['n_levels']} levels, {rough['length_mm'] / 1000:.1f} m")
            fin = path.get("finishing")
            if fin:
                print(f"    finishing: {fin['n_passes']} passes, {fin['n_cl']} moves ({fin['n_arcs']} arcs), "
                      f"min clearance {fin['min_clearance_mm']:.4f} mm"
                      f"{' (gouge free)' if fin['gouge_free'] else ' (GOUGES)'}; programs: "
                      + ", ".join(path.get("programs", {}).values()))
        _print_verification(plan)
        print(_summary(plan))
        for w in plan["warnings"]:
            print(f"  warning: {w}")
        print(f"results: {out_dir}/ ({', '.join(sorted(p.name for p in out_dir.iterdir()))})")
        print(_kept_line(url, job["id"], Path(args.data_dir)))
        if (out_dir / "viewer.json").is_file():
            print(f"see it in 3D: {Path(sys.executable).parent / 'scanmill'} view {out_dir}   (or, with the service "
                  f"running, {url}/jobs/{job['id']}/viewer)")
        # the exit status of `scanmill plan` (scanmill/cli.py): 4 unsafe, 3 infeasible, 5 unfinished
        if (plan.get("verification") or {}).get("status") == "failed":
            return 4
        return {"planned": 0, "unfinished": 5}.get(plan["status"], 3)
    finally:
        _say(t0, "stopping the service")
        stop_server(proc)


def _kept_line(url: str, job_id: str, data_dir: Path) -> str:
    """Where the demo's jobs are kept, how much they take and how to remove them: each `make run` adds one."""
    data = data_dir.resolve()
    files = [f for f in data.rglob("*") if f.is_file()]
    size_mb = sum(f.stat().st_size for f in files) / 1e6
    jobs = data / "jobs"
    n = sum(1 for d in jobs.iterdir() if d.is_dir()) if jobs.is_dir() else None
    count = f"{n} job{'s' if n != 1 else ''}, " if n is not None else ""
    return (f"job: {url}/jobs/{job_id} (kept in {data}: {count}{size_mb:.0f} MB; each `make run` adds one; "
            f"remove them with `rm -rf {data}`)")


def _print_verification(plan: dict) -> None:
    """What the simulated machine found (plan.json ``verification``), one line per area; the verdict itself
    is in the machining summary (:func:`_summary`)."""
    v = plan.get("verification")
    if not v or not v.get("areas"):
        return
    print("verification details (simulated machine):")
    for a in v.get("areas", []):
        print(f"    {a['program']}: {a['travel_excursions']} beyond travel, {a['rapids_into_material']} rapids into "
              f"material, {a['holder_collisions']} holder contacts, {a['fixture_collisions']} fixture contacts, "
              f"{a['machining_time_s'] / 60:.1f} min simulated")
    if v["status"] == "failed":
        print("    do not run these programs as they are: see deviation.png and plan.json verification.worst")


def _summary(plan: dict) -> str:
    """The machining summary `scanmill plan` prints too (scanmill/summary.py, standard library only): time per
    area in machining order, total, verdict, unmachined share."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from scanmill.summary import format_summary
    return format_summary(plan)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sample", choices=sorted(CONFIGS), default="femur_like")
    ap.add_argument("--points", type=int, help="points in the sample (default: the reference size)")
    ap.add_argument("--data-dir", default="scanmill-data", help="service data directory (default ./scanmill-data)")
    ap.add_argument("--out", default="scanmill-out", help="where the scan and the results go")
    ap.add_argument("--port", type=int, default=0, help="port (default: a free one)")
    ap.add_argument("--workers", type=int, help="worker processes of the service")
    ap.add_argument("--max-wait-s", type=float, default=1800.0, help="give up polling after this long")
    ap.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                    help="change one parameter of the sample's job, as `scanmill plan --set` does "
                         "(e.g. paths.finishing.mode=5axis); repeatable")
    return run(ap.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
