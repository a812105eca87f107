"""The longest silence between progress lines, per stage, of a plan run with the CLI (issue 34 item 4).

``scanmill plan`` prints a line per stage when the stage has moved on by a fifth or 2 s have passed since its
last line (scanmill/cli.py ``_Progress``), but only when the stage reports: a stage that calls no progress
for 10 s is silent for 10 s. This plans a sample (``scanmill sample NAME``) or a given file with the CLI,
reads the ``[ t s] stage  f%  message`` lines of its stderr, and prints per stage the longest gap between
one of its lines and the next line (the line that ends the gap: the stage's next, or the first of the stage
after it), with the message that was last shown before the silence.

    .venv/bin/python bench/bench_progress_gaps.py range_femur
    .venv/bin/python bench/bench_progress_gaps.py femur_like --set tool.diameter_mm=6 \\
        --set 'visibility.cone_deg=[10,60]' --set setups.coverage=0.85 --set fixtures.fixture_height_mm=150
    .venv/bin/python bench/bench_progress_gaps.py --log rf.err          # a stderr saved before

Exit status 1 when a gap exceeds ``--limit`` (default 2.5 s). Timings depend on the machine and its load.
"""

from __future__ import annotations

import argparse
import itertools
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

LINE = re.compile(r"^\[\s*([0-9.]+) s\] (\S+)\s+(\d+)%\s+(.*)$")


def parse(text: str) -> list[tuple[float, str, int, str]]:
    """(seconds, stage, percent, message) of every progress line of ``text`` (a plan's stderr)."""
    return [(float(m[1]), m[2], int(m[3]), m[4]) for m in map(LINE.match, text.splitlines()) if m]


def gaps(lines: list[tuple[float, str, int, str]]) -> dict[str, tuple[float, float, str, str]]:
    """Per stage, in order of appearance: (longest gap s, when it began s, the line before it, the line after)."""
    out: dict[str, tuple[float, float, str, str]] = {}
    for (t, stage, pct, msg), (t2, stage2, pct2, msg2) in itertools.pairwise(lines):
        g = t2 - t
        if stage not in out or g > out[stage][0]:
            out[stage] = (g, t, f"{pct}% {msg}", f"{stage2} {pct2}% {msg2}")
    if lines:
        out.setdefault(lines[-1][1], (0.0, lines[-1][0], f"{lines[-1][2]}% {lines[-1][3]}", ""))
    return out


def run_plan(sample: str | None, path: str | None, sets: list[str], workdir: Path) -> tuple[str, float, int]:
    """Plan ``path`` (or the sample, written first) with the CLI; (stderr, wall s, exit status)."""
    exe = shutil.which("scanmill") or str(Path(sys.executable).with_name("scanmill"))
    if path is None:
        path = str(workdir / f"{sample}.ply")
        subprocess.run([exe, "sample", sample, "--out", path], check=True, stdout=subprocess.DEVNULL)
    cmd = [exe, "plan", path, "--out", str(workdir / "out")]
    for s in sets:
        cmd += ["--set", s]
    print("$ " + " ".join(cmd), flush=True)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, check=False)
    return proc.stderr, time.perf_counter() - t0, proc.returncode


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sample", nargs="?", default="range_femur", help="a `scanmill sample` name (default range_femur)")
    ap.add_argument("--input", help="plan this file instead of a sample")
    ap.add_argument("--set", action="append", default=[], help="a parameter override, as for scanmill plan")
    ap.add_argument("--log", help="read the progress lines of a saved stderr instead of planning")
    ap.add_argument("--limit", type=float, default=2.5, help="exit 1 when a gap exceeds this (s; default 2.5)")
    ap.add_argument("--keep", help="plan into this folder (kept) instead of a temporary one")
    args = ap.parse_args(argv)
    if args.log:
        text, wall, rc = Path(args.log).read_text(), None, 0
    else:
        with tempfile.TemporaryDirectory() as tmp:
            work = Path(args.keep) if args.keep else Path(tmp)
            work.mkdir(parents=True, exist_ok=True)
            text, wall, rc = run_plan(None if args.input else args.sample, args.input, args.set, work)
    lines = parse(text)
    if not lines:
        print("no progress lines found", file=sys.stderr)
        print(text[-2000:], file=sys.stderr)
        return 2
    table = gaps(lines)
    print(f"{'stage':<13}{'longest gap s':>14}  {'at s':>8}  last line before it -> the next line")
    worst = 0.0
    for stage, (g, t, before, after) in table.items():
        worst = max(worst, g)
        flag = "  <-- over the limit" if g > args.limit else ""
        print(f"{stage:<13}{g:14.2f}  {t:8.2f}  {before} -> {after}{flag}")
    extra = f", wall {wall:.1f} s, exit status {rc}" if wall is not None else ""
    print(f"longest gap {worst:.2f} s over {len(lines)} progress lines{extra}")
    return 1 if worst > args.limit else 0


if __name__ == "__main__":
    sys.exit(main())
