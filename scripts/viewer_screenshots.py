"""Screenshots of the plan viewer for docs/viewer.md (issue 34): its default view and its deviation view,
taken in headless Chromium (tests/browser.py: Debian's chromium and chromedriver, software WebGL) through
``scanmill view``.

Without ``--plan-dir`` it plans a sample first, as a new user would, with the CLI's defaults::

    scanmill sample half_sphere --points 40000 --out TMP/half_sphere.ply
    scanmill plan TMP/half_sphere.ply --out TMP/plan/

(about 2 minutes on two cores) and writes ``viewer_default.png`` (the page as it opens: the scan by area,
every area's finishing path, the tables) and ``viewer_deviation.png`` (colour: deviation, with its colour
bar) into ``--out`` (default docs/images). A PNG over ``--max-kb`` is written again with 256 colours.

    python scripts/viewer_screenshots.py
    python scripts/viewer_screenshots.py --plan-dir scanmill-out/f --out /tmp/shots
"""

from __future__ import annotations

import argparse
import io
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from browser import chromium, js_errors, wait_viewer


def _scanmill(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "scanmill.cli", *args], cwd=ROOT, check=True)


def plan_sample(sample: str, work: Path, points: int | None) -> Path:
    """Plan ``sample`` with the CLI's defaults into ``work/plan``; return the plan folder."""
    cloud = work / f"{sample}.ply"
    _scanmill("sample", sample, "--out", str(cloud), *(["--points", str(points)] if points else []))
    out = work / "plan"
    r = subprocess.run([sys.executable, "-m", "scanmill.cli", "plan", str(cloud), "--out", str(out)], cwd=ROOT,
                       check=False)
    if not (out / "viewer.json").is_file():
        raise SystemExit(f"scanmill plan wrote no viewer.json (exit status {r.returncode})")
    return out


def _save(png: bytes, path: Path, max_kb: float) -> int:
    """Write the screenshot as an RGB PNG, or with 256 colours when that is over ``max_kb``; its size in bytes."""
    from PIL import Image

    img = Image.open(io.BytesIO(png)).convert("RGB")
    path.parent.mkdir(parents=True, exist_ok=True)
    img.save(path, format="PNG", optimize=True)
    if path.stat().st_size > max_kb * 1000:
        img.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.FLOYDSTEINBERG).save(
            path, format="PNG", optimize=True)
    return path.stat().st_size


def _frame_after(driver, action) -> None:
    """Run ``action`` and wait (bounded) until the page has drawn a new frame."""
    frames = driver.execute_script("return window.scanmillViewer.frames")
    action()
    for _ in range(200):
        if driver.execute_script("return window.scanmillViewer.frames") > frames:
            time.sleep(0.3)
            return
        time.sleep(0.05)
    raise SystemExit("the page drew no new frame")


def screenshots(plan_dir: Path, out: Path, *, width: int, height: int, max_kb: float) -> dict[str, int]:
    """Serve ``plan_dir`` with ``scanmill view``, take both screenshots; their sizes by path."""
    proc = subprocess.Popen([sys.executable, "-m", "scanmill.cli", "view", str(plan_dir)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    sizes = {}
    try:
        line = proc.stdout.readline()
        m = re.search(r"http://\S+", line)
        if not m:
            raise SystemExit(f"scanmill view did not start: {line}")
        with chromium(width, height) as d:
            for _ in range(100):                     # the server answers once uvicorn is up
                d.get(m.group(0))
                state = wait_viewer(d, paths=True, polls=1200)
                if state.get("pathsReady"):
                    break
                time.sleep(0.2)
            else:
                raise SystemExit(f"the page did not finish: {state}")
            time.sleep(0.5)
            sizes[str(out / "viewer_default.png")] = _save(d.get_screenshot_as_png(), out / "viewer_default.png",
                                                           max_kb)
            if d.find_element("id", "colour-deviation").is_enabled():
                _frame_after(d, lambda: d.find_element("id", "colour-deviation").click())
                sizes[str(out / "viewer_deviation.png")] = _save(d.get_screenshot_as_png(),
                                                                 out / "viewer_deviation.png", max_kb)
            else:
                print("the plan was not simulated: no deviation view", file=sys.stderr)
            errors = js_errors(d)
            if errors:
                raise SystemExit(f"script errors on the page: {errors}")
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    return sizes


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plan-dir", help="an existing plan folder (default: plan --sample first)")
    ap.add_argument("--sample", default="half_sphere", help="sample to plan (default half_sphere)")
    ap.add_argument("--points", type=int, default=40000, help="points of the sample (default 40000)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "images"), help="folder of the PNGs (default docs/images)")
    ap.add_argument("--width", type=int, default=1360)
    ap.add_argument("--height", type=int, default=840)
    ap.add_argument("--max-kb", type=float, default=290.0, help="largest RGB PNG kept, kB (default 290)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="scanmill-shots-") as tmp:
        plan_dir = Path(args.plan_dir) if args.plan_dir else plan_sample(args.sample, Path(tmp), args.points)
        sizes = screenshots(plan_dir, Path(args.out), width=args.width, height=args.height, max_kb=args.max_kb)
    for path, n in sizes.items():
        print(f"{path}: {n / 1000:.0f} kB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
