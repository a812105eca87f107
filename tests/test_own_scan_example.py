"""The README's "Planning your own scan" example, run as a user runs it (slow: a whole plan through the CLI): the
simulated 40,000-point range scan of the femur-like shape on a 100 mm riser. Its programs must verify clean with
no straight plunge of the roughing end mill into material (issue 30: a plunge is a planning error). Before the
live remaining-material map kept above the slivers that the stock view's line reading misses, the roughing's
holder met such a sliver 40 times in one set-up, the guard cut those moves out and came down again through
the material: 12 plunges beside a PASSED verdict."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

_SCANMILL = str(Path(sys.executable).with_name("scanmill"))


@pytest.mark.slow
def test_the_readme_own_scan_example_verifies_clean_without_plunges(tmp_path):
    subprocess.run([_SCANMILL, "sample", "range_femur", "--out", "part.ply"], cwd=tmp_path, check=True,
                   capture_output=True)
    p = subprocess.run([_SCANMILL, "plan", "part.ply", "--out", "plan", "--set", "fixtures.fixture_height_mm=100"],
                       cwd=tmp_path, capture_output=True, text=True)
    plan = json.loads((tmp_path / "plan" / "plan.json").read_text())
    v = plan["verification"]
    # planned and safe; not every point finished within tolerance (status unfinished, exit 5) or all of it (0)
    assert p.returncode in (0, 5), p.stdout[-2000:] + p.stderr[-2000:]
    assert v["status"] == "passed", v["message"]
    assert v["plunges_into_material"] == 0
    assert all(op["plunges_into_material"] == 0 for a in v["areas"] for op in a["operations"])
    assert "plunge" not in p.stdout
    assert all(a["rapids_into_material"] == a["holder_collisions"] == a["fixture_collisions"] == 0 for a in v["areas"])


@pytest.mark.slow
def test_the_range_half_sphere_as_the_range_bench_plans_it_verifies_clean(tmp_path):
    """bench/bench_range_scan.py's half sphere (coverage 0.9, 5 set-ups): planned (exit 0) and clean, no
    scan point cut below the surface. With wider side steps on its steep convex flanks, an arc fitted
    through a steep pass swung a millimetre off its CL points and the flutes above the ball cut the
    wall 0.77 mm (exit 4) until fit_arcs bounded the arc's bulge between neighbouring CL points."""
    subprocess.run([_SCANMILL, "sample", "range_half_sphere", "--out", "part.ply"], cwd=tmp_path, check=True,
                   capture_output=True)
    p = subprocess.run([_SCANMILL, "plan", "part.ply", "--out", "plan", "--set", "setups.coverage=0.9",
                        "--set", "setups.max_setups=5"], cwd=tmp_path, capture_output=True, text=True)
    v = json.loads((tmp_path / "plan" / "plan.json").read_text())["verification"]
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    assert v["status"] == "passed", v["message"]
    assert v["deviation"]["n_gouged"] == 0
    assert v["finish"]["below_max_mm"] <= 0.02
