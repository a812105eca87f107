"""The memory estimate of a job (planning/budget.py): exact axis counts, monotone in the orientation
steps, the parameter that drives it named, and an upper bound of what a real job uses (issue 13,
finding 1: ``orientations.phi_step_deg = 0.01`` on the half sphere took the whole host)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from planning.budget import (
    MIB,
    candidate_counts,
    estimate_artifact_bytes,
    estimate_job_memory,
    sampled_points,
)
from planning.inputs.samples import half_sphere
from planning.orientations import candidate_axes, load_profile, machine_visibility
from planning.report.files import write_ply
from schemas.machine import available_profiles
from schemas.params import parse_config

ROOT = Path(__file__).resolve().parents[1]
HALF = (2537, (100.0, 100.0, 50.0))          # the paper's half sphere: points, bounding box (mm)
FEMUR = (1_000_000, (396.1, 104.9, 67.5))    # planning.inputs.samples.femur_like


def _cfg(**groups) -> object:
    return parse_config(groups)


@pytest.mark.parametrize("sampling,phi,theta,res", [
    ("phi_theta", 10, 30, 10), ("phi_theta", 7, 13, 10), ("phi_theta", 180, 360, 10), ("phi_theta", 0.5, 1, 10),
    ("phi_theta", 0.3, 45, 10), ("phi_theta", 45, 0.7, 10), ("phi_theta", 179, 359, 10), ("phi_theta", 60, 120, 10),
    ("phi_theta", 0.01, 30, 10), ("uniform", 10, 30, 10), ("uniform", 10, 30, 3.3), ("uniform", 10, 30, 1),
    ("uniform", 10, 30, 90), ("uniform", 10, 30, 1.7),
])
def test_axis_counts_equal_the_candidate_axes(sampling, phi, theta, res):
    o = _cfg(orientations={"sampling": sampling, "phi_step_deg": phi, "theta_step_deg": theta,
                           "resolution_deg": res}).orientations
    cand = candidate_axes(sampling, phi_step_deg=phi, theta_step_deg=theta, resolution_deg=res)
    for name in available_profiles():
        profile = load_profile(name)
        total, feasible = candidate_counts(o, name)
        assert total == len(cand.axes), name
        exact = int(np.count_nonzero(machine_visibility(cand.axes, profile).feasible))
        if profile.rotary_continuous:
            assert feasible == exact, (name, feasible, exact)
        else:                                   # a limited rotary axis: an upper bound
            assert exact <= feasible <= total, (name, feasible, exact)


def test_the_raster_caps_are_the_planners():
    import planning.budget as b
    from planning.geometry import collision
    from planning.normals import throwing
    from planning.toolpath.roughing import maps
    assert b.THROWING_MAX_CELLS == throwing.MAX_CELLS_PER_DIRECTION
    assert b.COLLISION_MAX_CELLS == collision._MAX_GRID_CELLS
    assert b.ROUGHING_MAX_CELLS == maps.MAX_CELLS


def test_an_unknown_profile_counts_every_axis():
    o = _cfg().orientations
    assert candidate_counts(o, "/no/such/profile.json") == (206, 206)


@pytest.mark.parametrize("key,steps", [
    ("phi_step_deg", [60, 30, 10, 5, 2, 1, 0.5, 0.2, 0.1, 0.05, 0.01]),
    ("theta_step_deg", [360, 120, 30, 10, 5, 1, 0.5, 0.1, 0.02]),
])
def test_estimate_grows_as_the_steps_get_finer(key, steps):
    n, extent = HALF
    totals = [estimate_job_memory(n, _cfg(orientations={key: s}), extent_mm=extent).total_bytes for s in steps]
    assert totals == sorted(totals), totals
    assert totals[-1] > 10 * totals[0]
    res = [estimate_job_memory(n, _cfg(orientations={"sampling": "uniform", "resolution_deg": r}),
                               extent_mm=extent).total_bytes for r in (30, 10, 5, 2, 1)]
    assert res == sorted(res)


def test_the_finding_phi_step_001_is_far_over_any_sane_limit():
    n, extent = HALF
    est = estimate_job_memory(n, _cfg(orientations={"phi_step_deg": 0.01}), extent_mm=extent)
    assert est.n_candidates == 215_990 and est.n_feasible == 144_001   # compact_trunnion_bc: phi <= 120
    assert est.total_bytes > 512 * 1024 * MIB                           # half a TiB: no host has it
    assert est.largest.parameter == "orientations.phi_step_deg"
    assert "144,001 candidate axes" in est.largest.driver
    # the default plan of the same cloud needs well under a GiB
    small = estimate_job_memory(n, _cfg(), extent_mm=extent)
    assert small.total_bytes < 1024 * MIB
    # the finding's own measurements: 0.2 deg peaked at 1.7 GB, 0.1 deg at 5.0 GB; the estimate is above,
    # by less than 3x (these searches settle at 2 set-ups; the estimate allows for a search to 5)
    for step, measured_gb in ((0.2, 1.7), (0.1, 5.0)):
        e = estimate_job_memory(n, _cfg(orientations={"phi_step_deg": step}), extent_mm=extent)
        assert measured_gb * 1e9 < e.total_bytes < 3 * measured_gb * 1e9, (step, e.total_mib)


def test_the_driving_parameter_is_named():
    n, extent = HALF
    e = estimate_job_memory(n, _cfg(orientations={"theta_step_deg": 0.02}), extent_mm=extent)
    assert e.largest.parameter == "orientations.theta_step_deg"
    e = estimate_job_memory(n, _cfg(orientations={"sampling": "uniform", "resolution_deg": 1}), extent_mm=extent)
    assert e.largest.parameter == "orientations.resolution_deg"
    e = estimate_job_memory(20_000_000, _cfg(normals={"method": "input"}), extent_mm=(300, 300, 300))
    assert e.largest.parameter in ("cloud", "normals.method", "visibility.obstacles")
    for t in e.terms:
        assert t.bytes > 0 and t.what and t.driver and t.advice


def test_sampled_points():
    n, extent = HALF
    assert sampled_points(n, _cfg(normals={"method": "input"}), extent) == n
    assert sampled_points(n, _cfg(), extent) == n        # sparse: the grid is clipped at r / 4, all are touched
    N, fext = FEMUR
    s = sampled_points(N, _cfg(), fext)                   # dense: measured 100,664 (10 %)
    assert 100_664 <= s <= 0.3 * N
    assert sampled_points(N, _cfg(normals={"grid_spacing_mm": 0.05}), fext) == N


def test_estimate_is_cheap_and_works_without_an_extent():
    e = estimate_job_memory(FEMUR[0], _cfg())
    assert 0 < e.total_bytes < 8 * 1024 * MIB
    assert estimate_artifact_bytes(FEMUR[0], _cfg(), extent_mm=FEMUR[1]) > estimate_artifact_bytes(*HALF[:1], _cfg(),
                                                                                                  extent_mm=HALF[1])


def _measure(tmp_path: Path, params: dict) -> dict:
    """Run one job as the embedded worker does (bench/bench_admission.py --one) and return its measurements.

    The job runs twice and the second run is measured: on a fresh checkout the first run compiles the
    numba kernels (LLVM maps hundreds of MiB while it compiles) and writes them to numba's cache; the
    estimate bounds a job whose kernels are cached, as they are from the second job of an install on.
    """
    ply = tmp_path / "half.ply"
    if not ply.exists():
        s = half_sphere()
        write_ply(ply, s.points, normals=s.normals, binary=True)
    for _ in range(2):
        out = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_admission.py"), "--one", str(ply),
                              json.dumps(params)], cwd=ROOT, capture_output=True, text=True, timeout=900,
                             check=False)
        assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_estimate_bounds_a_real_job(tmp_path):
    """The half sphere with the service tests' parameters, run as the worker runs it."""
    params = {"normals": {"method": "input"}, "tool": {"diameter_mm": 10}, "visibility": {"cone_deg": [10, 80]},
              "setups": {"coverage": 0.95, "max_setups": 2},
              "paths": {"finishing": {"scallop_mm": 0.2}, "roughing": {"step_down_mm": 5}}}
    got = _measure(tmp_path, params)
    est = estimate_job_memory(HALF[0], parse_config(params), extent_mm=HALF[1])
    assert got["vm_growth"] <= est.total_bytes <= 2.5 * got["vm_growth"], (got, est.total_mib)


@pytest.mark.slow
def test_estimate_bounds_a_real_job_with_a_fine_grid(tmp_path):
    """phi_step 0.5 deg: the set-up search's (m, m) matrices set the peak (about 2,900 axes)."""
    params = {"orientations": {"phi_step_deg": 0.5}}
    got = _measure(tmp_path, params)
    est = estimate_job_memory(HALF[0], parse_config(params), extent_mm=HALF[1])
    assert est.peak_stage == "setups"
    assert got["vm_growth"] <= est.total_bytes <= 2 * got["vm_growth"], (got, est.total_mib)
