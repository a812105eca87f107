"""What an upload costs the API process: admission time, the API process's memory, /healthz meanwhile.

    .venv/bin/python bench/bench_hostile_uploads.py                       # legitimate height maps + hostile files
    .venv/bin/python bench/bench_hostile_uploads.py --only legit          # the 1 MP and 4 MP height maps only
    .venv/bin/python bench/bench_hostile_uploads.py --repo /path/to/other/checkout --only legit

Starts ``scanmill serve`` (embedded backend, SQLite, one worker, the default limits) on 127.0.0.1 from
``--repo`` (default: this checkout; give an older checkout to measure the code before a change, run with
this environment's interpreter), makes one small warm-up submission, then posts each file once as
``POST /jobs`` with the default parameters and prints per file:

- ``answer``: the HTTP status and problem code (202 = accepted; the job is deleted at once, it is not
  planned here);
- ``admission s``: from the request to its answer;
- ``API +MB``: growth of the API process's peak resident set (``VmHWM`` in /proc) over the warm-up's;
- ``healthz max s`` and ``healthz n``: the slowest ``GET /healthz`` while the upload was checked, from a
  thread that polls it in a bounded loop, and how many it made; a timed-out poll (10 s) counts as 10 s.

The files: a smooth 16-bit height map of 1024 x 1024 (1 MP) and 2048 x 2048 (4 MP) pixels, and the hostile
files of issue 29 (tests/test_service_hostile.py makes them): a 28 kB PNG of 4472 x 4472 grey pixels, a
334-byte JPEG whose header claims 13000 x 13000, binary PLYs whose face element claims 2.5e8 and 1e12
records or whose list count is 0xFFFFFFFF, an STL of degenerate triangles, a float TIFF with a NaN pixel,
and a 64 MB OBJ of 8 M copies of one triangle.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
MIB = 1 << 20


def height_map(side: int) -> bytes:
    """A smooth 16-bit PNG height map (a sum of Gaussian hills) of side x side pixels."""
    from PIL import Image
    yy, xx = np.mgrid[0:side, 0:side] / side
    z = np.zeros((side, side))
    rng = np.random.default_rng(side)
    for cx, cy, w, a in rng.uniform([0.1, 0.1, 0.05, 0.2], [0.9, 0.9, 0.3, 1.0], (6, 4)):
        z += a * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * w * w))
    img = np.round(z / z.max() * 65535).astype(np.uint16)
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="PNG")
    return buf.getvalue()


def obj_copies(n: int = 8_000_000) -> bytes:
    """An OBJ of one triangle's three vertices and n faces that all repeat it (~64 MB at 8 M)."""
    return b"v 0 0 0\nv 50 0 0\nv 0 50 0\n" + b"f 1 2 3\n" * n


def files(only: str) -> list[tuple[str, str, callable]]:
    from test_service_hostile import (degenerate_stl, float_tiff_with_nan, jpeg_header_bomb, ply_claiming_faces,
                                      png_bomb)
    legit = [("height map 1 MP (1024 x 1024, 16 bit)", "relief1.png", lambda: height_map(1024)),
             ("height map 4 MP (2048 x 2048, 16 bit)", "relief4.png", lambda: height_map(2048))]
    hostile = [("PNG bomb 4472 x 4472 grey", "bomb.png", png_bomb),
               ("JPEG header claims 13000 x 13000", "bomb.jpg", jpeg_header_bomb),
               ("PLY face element claims 2.5e8", "faces.ply", lambda: ply_claiming_faces(250_000_000)),
               ("PLY face element claims 1e12", "huge.ply", lambda: ply_claiming_faces(10 ** 12)),
               ("PLY list count 0xFFFFFFFF", "list.ply", lambda: ply_claiming_faces(1, "uint", 0xFFFFFFFF)),
               ("STL, all triangles degenerate", "flat.stl", degenerate_stl),
               ("float TIFF with a NaN pixel", "nan.tif", float_tiff_with_nan),
               ("OBJ, 8 M copies of one triangle", "copies.obj", obj_copies)]
    return {"legit": legit, "hostile": hostile, "all": legit + hostile}[only]


def vm(pid: int, field: str) -> int:
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
    return 0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repo", default=str(ROOT), help="checkout whose service is measured (default: this one)")
    ap.add_argument("--only", choices=["legit", "hostile", "all"], default="all")
    args = ap.parse_args()
    repo = Path(args.repo).resolve()
    data = Path(tempfile.mkdtemp(prefix="bench-hostile-"))
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("SCANMILL_")}
    env.update(PYTHONPATH=str(repo), PYTHONUNBUFFERED="1", SCANMILL_WORKERS="1")
    log = open(data / "server.log", "wb")
    proc = subprocess.Popen([sys.executable, "-m", "scanmill.cli", "serve", "--host", "127.0.0.1", "--port",
                             str(port), "--data-dir", str(data / "d")], cwd=repo, env=env, stdout=log,
                            stderr=subprocess.STDOUT, start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    try:
        for _ in range(600):
            try:
                if httpx.get(url + "/healthz", timeout=2).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        from service_fixtures import HALF_SPHERE_PARAMS, write_half_sphere
        hs = write_half_sphere(data / "hs.ply").read_bytes()
        print(f"service from {repo} (git {git_rev(repo)}), pid {proc.pid}; {os.cpu_count()} cores; "
              f"load {os.getloadavg()[0]:.2f}")
        print(f"{'file':42s} {'bytes':>11s} {'answer':>26s} {'admission s':>12s} {'API +MB':>8s} "
              f"{'healthz max s':>14s} {'healthz n':>10s}")
        with httpx.Client(base_url=url, timeout=600) as c:
            r = c.post("/jobs", files={"cloud": ("hs.ply", hs)}, data={"parameters": json.dumps(HALF_SPHERE_PARAMS)})
            c.delete(f"/jobs/{r.json()['id']}")
            for label, name, make in files(args.only):
                body = make()
                hwm0 = vm(proc.pid, "VmHWM")
                lat: list[float] = []
                done = threading.Event()

                def poll():
                    with httpx.Client(base_url=url, timeout=10) as h:
                        for _ in range(100_000):           # bounded; ends with the upload
                            if done.is_set():
                                return
                            t0 = time.perf_counter()
                            try:
                                h.get("/healthz")
                                lat.append(time.perf_counter() - t0)
                            except httpx.TimeoutException:
                                lat.append(10.0)
                            time.sleep(0.05)

                t = threading.Thread(target=poll)
                t.start()
                t0 = time.perf_counter()
                try:
                    r = c.post("/jobs", files={"cloud": (name, body, "application/octet-stream")},
                               data={"parameters": "{}"})
                    answer = f"{r.status_code} {r.json().get('code', '') if r.status_code != 202 else 'accepted'}"
                except httpx.HTTPError as exc:
                    r, answer = None, type(exc).__name__
                dt = time.perf_counter() - t0
                done.set()
                t.join()
                if r is not None and r.status_code == 202:
                    c.delete(f"/jobs/{r.json()['id']}")
                grow = (vm(proc.pid, "VmHWM") - hwm0) / MIB
                print(f"{label:42s} {len(body):>11,d} {answer:>26s} {dt:>12.2f} {grow:>8.0f} "
                      f"{max(lat, default=0):>14.3f} {len(lat):>10d}", flush=True)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
        log.close()


def git_rev(repo: Path) -> str:
    r = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=repo, capture_output=True, text=True)
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=repo, capture_output=True,
                           text=True).stdout.strip()
    return r.stdout.strip() + ("+changes" if dirty else "")


if __name__ == "__main__":
    main()
