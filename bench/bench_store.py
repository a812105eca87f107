#!/usr/bin/env python3
"""Cost of one job-store call: ``JobStore.get`` (what every poll does) and ``update_progress``.

Creates 20 jobs in a fresh SQLite file (or, with ``--postgres``, a fresh database on a throwaway
PostgreSQL server on 127.0.0.1, tests/servers.py), then times ``--calls`` gets and a tenth as many
progress updates in one thread. ``--root`` imports ``service.store`` from another checkout (e.g.
a git worktree of an older commit) to compare in the same command. Figures only.

    .venv/bin/python bench/bench_store.py
    .venv/bin/python bench/bench_store.py --root /tmp/wt-old     # the same loop on another checkout
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default=str(ROOT), help="checkout whose service.store is measured")
    ap.add_argument("--calls", type=int, default=5000)
    ap.add_argument("--postgres", action="store_true", help="PostgreSQL instead of SQLite")
    args = ap.parse_args()
    sys.path.insert(0, args.root)
    sys.path.insert(1, str(ROOT / "tests"))
    from service.store import JobStore
    with tempfile.TemporaryDirectory(prefix="scanmill-bench-store-") as tmp:
        server = None
        if args.postgres:
            from servers import PostgresServer
            server = PostgresServer().start()
            store = JobStore(server.create_database())
        else:
            store = JobStore(Path(tmp) / "db.sqlite3")
        try:
            ids = [f"{i:032x}" for i in range(20)]
            for i in ids:
                store.create(job_id=i, owner="o", parameters={"a": 1}, input={"path": "x"}, time_limit_s=10)
            t = time.perf_counter()
            for k in range(args.calls):
                store.get(ids[k % 20], owner="o")
            get_us = (time.perf_counter() - t) / args.calls * 1e6
            n = max(1, args.calls // 10)
            t = time.perf_counter()
            for k in range(n):
                store.update_progress(ids[k % 20], 0, "normals", 0.5, "m")
            upd_us = (time.perf_counter() - t) / n * 1e6
        finally:
            store.close()
            if server is not None:
                server.stop()
    print(f"{args.root} ({'postgresql' if args.postgres else 'sqlite'}): get {get_us:.0f} us, "
          f"update_progress {upd_us:.0f} us")
    return 0


if __name__ == "__main__":
    sys.exit(main())
