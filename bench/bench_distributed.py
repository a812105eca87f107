#!/usr/bin/env python3
"""Throughput of the distributed backend: jobs per minute with one and with two Celery workers.

Starts Redis and PostgreSQL on 127.0.0.1 (tests/servers.py), the API (``scanmill serve`` with
``SCANMILL_BACKEND=celery``) and ``--workers`` worker processes (``scanmill worker``, one job at a
time each, one BLAS thread), all sharing a temporary data directory. For each worker count in
``--workers`` (default ``1 2``, run in this one command so the ratio compares like with like) it
first runs one warm-up job per worker (imports and numba compilation in each pool child), then
submits ``--jobs`` copies of a small job at once and times from the first submission to the last
completion, polling ``GET /jobs/{id}`` every 0.2 s. Prints jobs/minute, the mean job run time
(started_at to finished_at, from the job store), and how the jobs spread over the workers.
Figures only; nothing here asserts on time.

    .venv/bin/python bench/bench_distributed.py --jobs 16 --workers 1 2
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from datetime import datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from servers import PostgresServer, RedisServer  # noqa: E402
from service_fixtures import HALF_SPHERE_PARAMS, ServerProcess, WorkerProcess, submit, write_half_sphere  # noqa: E402


def _wait_all(client, ids: list[str], max_polls: int) -> list[dict]:
    pending, done = set(ids), {}
    for _ in range(max_polls):
        for jid in list(pending):
            j = client.get(f"/jobs/{jid}").json()
            if j["status"] in ("succeeded", "failed", "cancelled"):
                done[jid] = j
                pending.discard(jid)
        if not pending:
            return [done[i] for i in ids]
        time.sleep(0.2)
    raise RuntimeError(f"{len(pending)} job(s) did not finish")


def run(n_workers: int, n_jobs: int, base: Path, redis: RedisServer, pg: PostgresServer, params: dict) -> dict:
    data = base / f"w{n_workers}"
    data.mkdir()
    cloud = write_half_sphere(base / "half_sphere.ply")
    common = dict(backend="celery", broker_url=redis.url, database_url=pg.create_database(), workers=1,
                  worker_threads=1, log_level="warning")
    api = ServerProcess(data, log_dir=base, **common).start()
    workers = [WorkerProcess(f"b{n_workers}-{i}", base, data_dir=data, **dict(common, log_level="info")).start()
               for i in range(n_workers)]
    try:
        with api.client() as c:
            warm = [submit(c, cloud, params).json()["id"] for _ in range(n_workers)]
            _wait_all(c, warm, 3000)
            t0 = time.perf_counter()
            ids = [submit(c, cloud, params).json()["id"] for _ in range(n_jobs)]
            jobs = _wait_all(c, ids, 30000)
            wall = time.perf_counter() - t0
        runs = [(datetime.fromisoformat(j["finished_at"]) - datetime.fromisoformat(j["started_at"])).total_seconds()
                for j in jobs]
        spread = {w.name: w.log_text().count("succeeded on attempt") for w in workers}
        return {"workers": n_workers, "jobs": n_jobs, "succeeded": sum(j["status"] == "succeeded" for j in jobs),
                "wall_s": round(wall, 2), "jobs_per_min": round(60 * n_jobs / wall, 1),
                "mean_job_s": round(statistics.mean(runs), 2), "jobs_per_worker_incl_warmup": spread}
    finally:
        for w in workers:
            w.stop()
        api.stop()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=16, help="jobs timed per worker count")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker counts to compare")
    ap.add_argument("--no-paths", action="store_true", help="plan set-ups only (no tool paths / NC programs)")
    args = ap.parse_args()
    params = json.loads(json.dumps(HALF_SPHERE_PARAMS))
    if args.no_paths:
        params["paths"] = {"finishing": {"enabled": False}, "roughing": {"enabled": False}}
    results = []
    with tempfile.TemporaryDirectory(prefix="scanmill-bench-dist-") as tmp, RedisServer() as redis, \
            PostgresServer() as pg:
        for n in args.workers:
            r = run(n, args.jobs, Path(tmp), redis, pg, params)
            results.append(r)
            print(json.dumps(r), flush=True)
    if len(results) >= 2:
        print(f"throughput {results[-1]['workers']} vs {results[0]['workers']} worker(s): "
              f"{results[-1]['jobs_per_min'] / results[0]['jobs_per_min']:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
