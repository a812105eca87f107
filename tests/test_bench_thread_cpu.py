"""bench/bench_plan_once.py --threads-cpu (issue 30, where a two-core plan's seconds go): the CPU seconds
it reads for a thread from /proc agree with the thread's own CPU clock (time.thread_time), for the
plan's thread and for a second thread that burns CPU of its own."""

from __future__ import annotations

import re
import sys
import threading
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import bench_plan_once  # noqa: E402


def _burn(seconds: float) -> float:
    t0 = time.thread_time()
    x = 0
    while time.thread_time() - t0 < seconds:
        x += sum(range(1000))
    return time.thread_time()


def test_thread_cpu_seconds_agree_with_each_threads_own_clock(capsys):
    mine = _burn(0.3)
    other = {}
    gate = threading.Event()

    def worker():
        other["cpu"] = _burn(0.5)
        gate.wait(30)                          # alive while the figures are read
    th = threading.Thread(target=worker, name="burner")
    th.start()
    while "cpu" not in other:
        time.sleep(0.01)
    mine = time.thread_time()
    bench_plan_once.print_thread_cpu()
    gate.set()
    th.join()
    out = capsys.readouterr().out
    got = {m.group(2): float(m.group(1)) for m in re.finditer(r"THREAD cpu_s=([\d.]+) name=(\S+)", out)}
    assert got["burner"] == pytest.approx(other["cpu"], abs=0.15)
    assert got[threading.main_thread().name] == pytest.approx(mine, abs=0.15)
    live, proc = map(float, re.search(r"live_cpu_s=([\d.]+) process_cpu_s=([\d.]+)", out).groups())
    assert got["burner"] + got[threading.main_thread().name] <= live + 0.1 <= proc + 0.2
