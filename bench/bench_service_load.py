#!/usr/bin/env python3
"""Load on the jobs API over loopback: many concurrent pollers of ``GET /jobs/{id}`` while small jobs run.

Starts ``scanmill serve`` on 127.0.0.1 (a free port, a temporary data directory), submits ``--jobs``
copies of the paper's half sphere (2537 points, ~1 s of planning each), and runs ``--pollers``
concurrent clients that poll ``GET /jobs/{id}`` (each on its own keep-alive connection, one request
every ``--interval-s`` after a random start offset, round robin over the jobs) until every job has
finished. Prints the latency of those polls (p50, p90, p99, max), the request rate, the errors
(any transport error or status other than 200), and how long the jobs took. Bounded: it stops
after ``--max-seconds`` or ``--max-requests``, whichever comes first, and always stops the server.
Figures only; nothing here asserts on time.

    .venv/bin/python bench/bench_service_load.py --jobs 20 --pollers 50
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import statistics
import sys
import tempfile
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from service_fixtures import HALF_SPHERE_PARAMS, ServerProcess, write_half_sphere  # noqa: E402


class RawConnection:
    """A minimal HTTP/1.1 keep-alive client on asyncio streams (httpx costs ~5 ms of client CPU per request,
    which on a 2-core machine would measure the client rather than the service)."""

    def __init__(self, host: str, port: int):
        self.host, self.port = host, port
        self.reader: asyncio.StreamReader | None = None
        self.writer: asyncio.StreamWriter | None = None

    async def get(self, path: str) -> tuple[int, bytes]:
        if self.writer is None:
            self.reader, self.writer = await asyncio.open_connection(self.host, self.port)
        self.writer.write(f"GET {path} HTTP/1.1\r\nHost: {self.host}\r\nAccept: application/json\r\n\r\n".encode())
        await self.writer.drain()
        head = await self.reader.readuntil(b"\r\n\r\n")
        lines = head.decode("latin-1").split("\r\n")
        status = int(lines[0].split()[1])
        length = 0
        for line in lines[1:]:
            if line.lower().startswith("content-length:"):
                length = int(line.split(":", 1)[1])
        body = await self.reader.readexactly(length)
        return status, body

    async def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
            try:
                await self.writer.wait_closed()
            except OSError:
                pass
            self.writer = None


def percentile(values: list[float], q: float) -> float:
    s = sorted(values)
    if not s:
        return float("nan")
    k = (len(s) - 1) * q
    lo, hi = int(k), min(int(k) + 1, len(s) - 1)
    return s[lo] + (s[hi] - s[lo]) * (k - lo)


async def run(args) -> dict:
    with tempfile.TemporaryDirectory(prefix="scanmill-bench-") as tmp:
        tmp = Path(tmp)
        cloud = write_half_sphere(tmp / "half_sphere.ply").read_bytes()
        srv = ServerProcess(tmp / "data", workers=args.workers, worker_threads=args.worker_threads,
                            log_level="warning").start()
        try:
            async with httpx.AsyncClient(base_url=srv.url, timeout=60,
                                         limits=httpx.Limits(max_connections=args.pollers + 10,
                                                             max_keepalive_connections=args.pollers + 10)) as c:
                t_submit = time.perf_counter()
                ids = []
                for _ in range(args.jobs):
                    r = await c.post("/jobs", files={"cloud": ("half_sphere.ply", cloud, "application/octet-stream")},
                                     data={"parameters": json.dumps(HALF_SPHERE_PARAMS)})
                    r.raise_for_status()
                    ids.append(r.json()["id"])
                submit_s = time.perf_counter() - t_submit

                latencies: list[float] = []
                errors: list[str] = []
                final: dict[str, dict] = {}
                deadline = time.perf_counter() + args.max_seconds
                counter = {"n": 0}
                rng = random.Random(0)

                async def poller(k: int) -> None:
                    i = k
                    conn = RawConnection("127.0.0.1", srv.port)
                    await asyncio.sleep(rng.uniform(0, args.interval_s))     # pollers are not in lockstep
                    try:
                        while (len(final) < len(ids) and time.perf_counter() < deadline
                               and counter["n"] < args.max_requests):
                            jid = ids[i % len(ids)]
                            i += 1
                            counter["n"] += 1
                            t0 = time.perf_counter()
                            try:
                                status, body = await conn.get(f"/jobs/{jid}")
                                dt = time.perf_counter() - t0
                                if status != 200:
                                    errors.append(f"HTTP {status}")
                                else:
                                    latencies.append(dt)
                                    job = json.loads(body)
                                    if job["status"] in ("succeeded", "failed", "cancelled"):
                                        final[jid] = job
                            except (OSError, asyncio.IncompleteReadError, ValueError) as exc:
                                errors.append(type(exc).__name__)
                                await conn.close()
                            await asyncio.sleep(args.interval_s)
                    finally:
                        await conn.close()

                t_poll = time.perf_counter()
                await asyncio.gather(*(poller(k) for k in range(args.pollers)))
                poll_s = time.perf_counter() - t_poll
                statuses = {}
                for j in final.values():
                    statuses[j["status"]] = statuses.get(j["status"], 0) + 1
                health = (await c.get("/healthz")).json()
        finally:
            srv.stop()
    return {
        "jobs": args.jobs, "pollers": args.pollers, "interval_s": args.interval_s, "workers": args.workers,
        "submit_s": submit_s, "poll_s": poll_s, "requests": len(latencies) + len(errors), "errors": len(errors),
        "error_kinds": sorted(set(errors)), "finished": len(final), "statuses": statuses,
        "rate_per_s": (len(latencies) + len(errors)) / poll_s if poll_s else 0.0,
        "p50_ms": 1e3 * percentile(latencies, 0.50), "p90_ms": 1e3 * percentile(latencies, 0.90),
        "p99_ms": 1e3 * percentile(latencies, 0.99), "max_ms": 1e3 * max(latencies, default=float("nan")),
        "mean_ms": 1e3 * statistics.fmean(latencies) if latencies else float("nan"), "health": health,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=20)
    ap.add_argument("--pollers", type=int, default=50)
    ap.add_argument("--interval-s", type=float, default=0.05, help="pause of each poller between its requests")
    ap.add_argument("--workers", type=int, default=1, help="SCANMILL_WORKERS of the server")
    ap.add_argument("--worker-threads", type=int, default=1,
                    help="SCANMILL_WORKER_THREADS (1: the job leaves a core to the API on a 2-core machine)")
    ap.add_argument("--max-seconds", type=float, default=300.0)
    ap.add_argument("--max-requests", type=int, default=200_000)
    args = ap.parse_args(argv)
    r = asyncio.run(run(args))
    print(f"service load: {r['jobs']} half-sphere jobs (2537 points), {r['workers']} worker(s), "
          f"{r['pollers']} concurrent pollers every {r['interval_s']:g} s, loopback")
    print(f"  submitted {r['jobs']} jobs in {r['submit_s']:.2f} s; all finished after {r['poll_s']:.1f} s of polling "
          f"({r['finished']}/{r['jobs']} finished: {r['statuses']})")
    print(f"  GET /jobs/{{id}}: {r['requests']} requests, {r['rate_per_s']:.0f}/s, errors {r['errors']} "
          f"{r['error_kinds'] or ''}")
    print(f"  latency ms: p50 {r['p50_ms']:.1f}  p90 {r['p90_ms']:.1f}  p99 {r['p99_ms']:.1f}  "
          f"max {r['max_ms']:.1f}  mean {r['mean_ms']:.1f}")
    return 0 if r["errors"] == 0 and r["finished"] == r["jobs"] else 1


if __name__ == "__main__":
    sys.exit(main())
