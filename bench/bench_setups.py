"""Benchmark: set-up selection (Makki 2010 §3) on synthetic visibility matrices.  Prints figures only.

Instances are built here, without the other pipeline stages:

* ``half-sphere``: the paper's §3.2 case shape: 2537 points on a half sphere with non-uniform
  density and exact normals, cone [10, 80] deg, max 2 set-ups, P_a 95 %.
* ``bone``: ~100k unit normals of an elongated bumpy ellipsoid 400 x 40 x 40 mm (area-uniform samples,
  normals with Gaussian noise of ``--noise-deg``), cone [10, 60] and [10, 80] deg, max 5 set-ups,
  P_a 95 %.

Candidate axes: phi 0..``--phi-max`` step 10 deg (the pole once) x theta step 30 deg.  The
visibility is the tool cone only (angle between normal and axis in the cone), which is what
``select_setups`` receives from the visibility stage anyway: a bool matrix.

    .venv/bin/python bench/bench_setups.py                       # all cases, branch and bound
    .venv/bin/python bench/bench_setups.py --cpsat-seconds 20    # plus CP-SAT for comparison
    .venv/bin/python bench/bench_setups.py --case bone --phi-max 180 --points 100000
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from planning.setups import brute_force_setups, select_setups  # noqa: E402


def candidate_axes(phi_max_deg: int = 120, phi_step_deg: int = 10, theta_step_deg: int = 30) -> np.ndarray:
    """Unit axes on the Gaussian sphere: the pole +Z once, then rings phi x theta (phi from +Z)."""
    axes = [[0.0, 0.0, 1.0]]
    for phi in range(phi_step_deg, phi_max_deg + 1, phi_step_deg):
        if phi >= 180:
            axes.append([0.0, 0.0, -1.0])
            continue
        p = np.radians(phi)
        for th in range(0, 360, theta_step_deg):
            t = np.radians(th)
            axes.append([np.sin(p) * np.cos(t), np.sin(p) * np.sin(t), np.cos(p)])
    return np.array(axes)


def bumpy_ellipsoid_normals(n: int, semi_axes_mm=(200.0, 20.0, 20.0), noise_deg: float = 2.0,
                            seed: int = 0) -> np.ndarray:
    """Outward unit normals of ``n`` area-uniform samples of an ellipsoid, with angular noise."""
    rng = np.random.default_rng(seed)
    a = np.asarray(semi_axes_mm, float)
    out, got = [], 0
    dmax = a.prod() * np.max(1.0 / a)
    while got < n:
        u = rng.normal(size=(4 * n, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        dens = a.prod() * np.linalg.norm(u / a, axis=1)  # area element of sphere -> ellipsoid
        u = u[rng.random(len(u)) < dens / dmax]
        out.append(u)
        got += len(u)
    u = np.concatenate(out)[:n]
    nrm = u / a  # gradient of the implicit function at (a0 u0, a1 u1, a2 u2)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    nrm += rng.normal(scale=np.radians(noise_deg), size=nrm.shape)
    return nrm / np.linalg.norm(nrm, axis=1, keepdims=True)


def half_sphere_normals(n: int = 2537, seed: int = 0) -> np.ndarray:
    """Exact normals of a half sphere (z >= 0) sampled with non-uniform density (denser at the top)."""
    rng = np.random.default_rng(seed)
    z = rng.random(n) ** 0.6  # more points near the pole than an area-uniform sampling
    t = rng.random(n) * 2 * np.pi
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(t), r * np.sin(t), z], axis=1)


def cone_visibility(normals: np.ndarray, axes: np.ndarray, cone_deg) -> np.ndarray:
    ang = np.degrees(np.arccos(np.clip(normals @ axes.T, -1.0, 1.0)))
    return (ang >= cone_deg[0]) & (ang <= cone_deg[1])


def run_case(name, V, *, max_setups, coverage, cpsat_seconds, bnb_seconds, check_brute=False):
    n, m = V.shape
    print(f"\n== {name}: {n} points x {m} axes, max_setups {max_setups}, coverage {coverage}")
    r = select_setups(V, coverage=coverage, max_setups=max_setups, solver="branch_and_bound",
                      time_limit_s=bnb_seconds)
    print(f"  branch_and_bound: status {r.status}, k {r.k}, coverage {r.coverage * 100:.2f} %, "
          f"overlap {r.overlap}, lower bound {r.lower_bound}, classes {r.n_classes}, axes kept "
          f"{r.n_axes_kept}, {r.seconds:.2f} s; selected {r.selected.tolist()}")
    print(f"    {r.message}")
    if check_brute:
        t = time.perf_counter()
        b = brute_force_setups(V, coverage=coverage, max_setups=max_setups)
        same = (b.status, b.k, b.overlap, b.covered, b.selected.tolist()) == (
            r.status, r.k, r.overlap, r.covered, r.selected.tolist())
        print(f"  brute_force: k {b.k}, overlap {b.overlap}, covered {b.covered}, "
              f"{time.perf_counter() - t:.2f} s; same answer: {same}")
    if cpsat_seconds > 0:
        c = select_setups(V, coverage=coverage, max_setups=max_setups, solver="cpsat",
                          time_limit_s=cpsat_seconds)
        print(f"  cpsat (limit {cpsat_seconds:g} s): status {c.status}, k {c.k}, coverage "
              f"{c.coverage * 100:.2f} %, overlap {c.overlap}, lower bound {c.lower_bound}, gap "
              f"{'-' if c.gap is None else f'{c.gap * 100:.1f} %'}, {c.seconds:.2f} s")
    return r


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", choices=["all", "half-sphere", "bone"], default="all")
    ap.add_argument("--points", type=int, default=100_000)
    ap.add_argument("--phi-max", type=int, nargs="+", default=[120, 180])
    ap.add_argument("--cones", default="10-60,10-80", help="comma list of lo-hi cones for the bone case")
    ap.add_argument("--noise-deg", type=float, default=2.0)
    ap.add_argument("--max-setups", type=int, default=5)
    ap.add_argument("--coverage", type=float, default=0.95)
    ap.add_argument("--bnb-seconds", type=float, default=60.0)
    ap.add_argument("--cpsat-seconds", type=float, default=0.0, help="0: skip CP-SAT")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)

    if a.case in ("all", "half-sphere"):
        N = half_sphere_normals(2537, seed=a.seed)
        for pm in (90, 180):
            V = cone_visibility(N, candidate_axes(pm), (10, 80))
            run_case(f"half sphere (phi <= {pm})", V, max_setups=2, coverage=0.95,
                     cpsat_seconds=a.cpsat_seconds, bnb_seconds=a.bnb_seconds, check_brute=True)
    if a.case in ("all", "bone"):
        t = time.perf_counter()
        N = bumpy_ellipsoid_normals(a.points, noise_deg=a.noise_deg, seed=a.seed)
        print(f"\n(built {a.points} bone-like normals in {time.perf_counter() - t:.2f} s)")
        for pm in a.phi_max:
            axes = candidate_axes(pm)
            for cone in a.cones.split(","):
                lo, hi = (float(x) for x in cone.split("-"))
                V = cone_visibility(N, axes, (lo, hi))
                run_case(f"bone 400x40x40, phi <= {pm}, cone [{lo:g}, {hi:g}]", V,
                         max_setups=a.max_setups, coverage=a.coverage,
                         cpsat_seconds=a.cpsat_seconds, bnb_seconds=a.bnb_seconds)


if __name__ == "__main__":
    main()
