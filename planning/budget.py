"""How much memory a plan will need, from its parameters and the cloud's point count, without planning.

A plan's memory is driven by a few sizes that the parameters fix before any geometry is computed
(docs/design.md, "The pipeline"):

* ``N``, the points of the cloud: its arrays, and the per-point work of sphere throwing, of the cloud
  collisions (every point is an obstacle, projected and sorted per axis on two threads) and of the
  tool paths (the whole cloud in each area's frame);
* ``n``, the sampled points (the rows of the visibility matrix): every point with
  ``normals.method = input``; with sphere throwing about a tenth to a fifth of a dense cloud at the
  default grid, all of a sparse one (where the grid is clipped at a quarter of the sphere radius);
* ``M`` candidate axes and the ``m`` of them within the machine's rotary travel (the columns), counted
  exactly from ``orientations.*`` and the machine profile (:func:`candidate_counts`);
* the ``(n, m)`` boolean matrices of the visibility chain (cone, travel, collisions) and their
  float temporaries (the cone's dot products, the set-up search's weighted class matrix), the ``M``
  rows of plan.json's per-axis report;
* the ``(m, m)`` float matrices of the set-up search (the weighted Gram matrix of the axes and, per
  level of the branch and bound, its restriction and the bounds' temporaries);
* rasters whose cells follow the part's extent: sphere throwing's candidate cells (``2 g`` wide),
  the collision raster (a third of the cutter radius) and the roughing map (``Rt / 16``); and the
  finishing CL points (the part's largest shadow / (step-over x step)) with their NC text.

:func:`estimate_job_memory` adds what stays allocated through the run to the largest stage and the
worker process's own overhead, and returns a :class:`MemoryEstimate` whose terms name the
parameter that drives each. It costs microseconds (``bench/bench_admission.py``).

Calibration (``bench/bench_admission.py --calibrate``; the figures are in the module constants): the
address space a job process adds (what ``SCANMILL_JOB_MEMORY_MB`` limits), measured on the half sphere at
``orientations.phi_step_deg`` 10, 2, 1, 0.5 and 0.2 and on the femur-like scan at 100k and 1M points
with the default parameters, is below the estimate and more than half of it. The set-up search is the
least predictable term: a search that proves k = 2 needed 22-28 bytes per feasible axis squared, one
that went on to 5 set-ups about 62; the estimate grows with ``setups.max_setups``
(:data:`SETUPS_BYTES_PER_AXIS2`, :data:`SETUPS_BYTES_PER_AXIS2_PER_LEVEL`), which covers the deep
search and puts the plans that settle at 2 set-ups at about twice their need (2.6 times at
``phi_step_deg`` 0.1). An estimate is not a guarantee: the worker also runs under a hard limit
(``service/memlimit.py``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

from planning.orientations.candidates import _STEP_EPS, FIBONACCI_COVERING_CONSTANT
from planning.orientations.kinematics import ANGLE_TOL_DEG
from schemas.params import PlanConfig

__all__ = [
    "MemoryEstimate",
    "MemoryTerm",
    "candidate_counts",
    "estimate_artifact_bytes",
    "estimate_job_memory",
    "sampled_points",
]

MIB = 1 << 20

# --- calibrated constants (bytes; bench/bench_admission.py --calibrate) ------------------------------
#: The job process before the stages: reading a small cloud, the first planning imports, thread stacks
#: (32 MiB of address space measured after the read of the half sphere, 50 MiB once sphere throwing ran).
PROCESS_BYTES = 56 * MIB
#: Per input point, for the whole run: points and normals (float64), labels, the reader's buffers.
CLOUD_BYTES_PER_POINT = 80
#: Per (sampled point, feasible axis) pair for the whole run: cone and global visibility, plan.npz's copy.
PAIR_BYTES = 3
#: Visibility stage: the cone's float64 dot products (8 B per pair of a chunk of 65,536 rows, with
#: 3 B of masks per pair), then the travel and collision filters' masks (per pair); the half sphere
#: measured 10.9 B per pair.
VISIBILITY_MASK_BYTES = 7
VISIBILITY_CHUNK_ROWS = 65_536
#: Per pair during the set-up search: the reduced matrix, its transpose, its float32 copy and the
#: weighted products (at most one class per sampled point).
SETUPS_PAIR_BYTES = 13
#: Per feasible axis squared during the set-up search (its Gram matrix, the node's restrictions and
#: the bounds' temporaries, float64): measured 22-28 B where the search settles at 2 set-ups, 62 B
#: where it goes on to 5. The search holds a restriction per level, so the estimate takes
#: SETUPS_BYTES_PER_AXIS2 + SETUPS_BYTES_PER_AXIS2_PER_LEVEL x (setups.max_setups - 2).
SETUPS_BYTES_PER_AXIS2 = 36
SETUPS_BYTES_PER_AXIS2_PER_LEVEL = 9
#: Per candidate axis (machine-feasible or not): its row of plan.json ``visibility.per_axis``.
CANDIDATE_BYTES = 2_500
#: Cloud collisions, per thread: per obstacle point (the points projected on the axis frame and
#: sorted by cell, float64 (N, 6) twice, with their ranks) and per raster cell (heights, starts).
COLLISION_BYTES_PER_POINT = 120
COLLISION_THREADS = 2
COLLISION_BYTES_PER_CELL = 48
COLLISION_MAX_CELLS = 8_000_000      # planning.geometry.collision._MAX_GRID_CELLS
#: Sphere throwing: per point (float64 copy, float32 columns) once, per point and per candidate cell
#: on each direction's thread (projections, cell indices; heights, top points, the sub-lattices).
THROWING_SHARED_BYTES_PER_POINT = 40
THROWING_BYTES_PER_POINT = 60
THROWING_BYTES_PER_CELL = 64
THROWING_MAX_CELLS = 1 << 25         # planning.normals.throwing.MAX_CELLS_PER_DIRECTION
THROWING_THREADS = 4
#: Share of a dense cloud's points sphere throwing samples at the density-derived grid (femur-like
#: 1M points: 10.1 %; 100k points: 16 %, where the grid is clipped at r / 4).
THROWING_SAMPLED_SHARE = 0.2
#: Tool paths and NC programs: a fixed part (their modules and kernels), per input point (the whole
#: cloud in the area's frame, binned), per finishing CL point of an area (ball drops, reduction, arcs,
#: verification), per roughing map cell, and the NC text and moves of every area per CL point.
PATHS_BASE_BYTES = 100 * MIB
PATHS_BYTES_PER_POINT = 120
FINISHING_BYTES_PER_CL = 1_600
ROUGHING_BYTES_PER_CELL = 60
ROUGHING_MAX_CELLS = 16_000_000     # planning.toolpath.roughing.maps.MAX_CELLS
POST_BYTES_PER_CL = 110
#: The verification's measure of the roughing's engagement (``simulate.engagement``,
#: planning/simulate/engagement.py): its kernels loaded from the cache, its height fields and per-step
#: areas. The half sphere's job grew by 22-52 MiB of address space with it on (157 MiB off; 179, 184 and
#: 209 MiB on, three runs of bench/bench_admission.py --one).
ENGAGEMENT_BYTES = 56 * MIB
#: Artifacts on disk: plan.npz, segmentation.ply, preview; NC programs and moves JSON per CL point.
ARTIFACT_BASE_BYTES = 8 * MIB
ARTIFACT_BYTES_PER_POINT = 40
ARTIFACT_BYTES_PER_CL = 120

_ANGLE_TOL_DEG = ANGLE_TOL_DEG
_FIBONACCI_K = FIBONACCI_COVERING_CONSTANT


@dataclass(frozen=True)
class MemoryTerm:
    """One part of a job's memory: ``what`` it is, the ``parameter`` that drives it most (a plan
    parameter name, or ``cloud`` for the point count), the ``driver`` sentence naming the
    parameters and the counts they give, ``advice`` (what to change), and its ``bytes``."""

    what: str
    parameter: str
    driver: str
    advice: str
    bytes: int

    @property
    def mib(self) -> float:
        return self.bytes / MIB


@dataclass(frozen=True)
class MemoryEstimate:
    """The memory a job will need at most, bytes (``total_bytes``), and its ``terms``, largest first.

    ``total_bytes`` = the process overhead + what stays allocated through the run (the cloud, the
    visibility matrices, the per-axis report) + the largest stage's own working memory; ``terms``
    lists each of those (the stages that do not set the peak are left out). The counts the
    estimate rests on: ``n_points`` (N), ``n_sampled`` (n, estimated), ``n_candidates`` (M) and
    ``n_feasible`` (m, exact for continuous rotary axes, an upper bound otherwise).
    """

    total_bytes: int
    terms: tuple[MemoryTerm, ...]
    n_points: int
    n_sampled: int
    n_candidates: int
    n_feasible: int
    peak_stage: str

    @property
    def total_mib(self) -> float:
        return self.total_bytes / MIB

    @property
    def largest(self) -> MemoryTerm:
        return self.terms[0]


# --------------------------------------------------------------------------------------------------
# counts


@lru_cache(maxsize=64)
def _profile_reach(profile_name: str) -> tuple[tuple[tuple[float, float], ...], bool] | None:
    """The polar angles (degrees) the profile's tilt reaches, as disjoint intervals, and whether its
    rotary axis is continuous; None for an unknown profile (then every axis counts as feasible)."""
    from planning.errors import PlanningError
    from schemas.machine import load_profile
    try:
        p = load_profile(profile_name)
    except (PlanningError, OSError, ValueError):
        return None
    lo, hi = float(p.tilt_min_deg), float(p.tilt_max_deg)
    # solution (+phi) needs lo <= phi <= hi, solution (-phi) needs lo <= -phi <= hi
    ivs = []
    for a, b in ((lo, hi), (-hi, -lo)):
        a, b = max(a - _ANGLE_TOL_DEG, 0.0), min(b + _ANGLE_TOL_DEG, 180.0)
        if a <= b:
            ivs.append((a, b))
    ivs.sort()
    merged: list[tuple[float, float]] = []
    for a, b in ivs:
        if merged and a <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], b))
        else:
            merged.append((a, b))
    return tuple(merged), bool(p.rotary_continuous)


def _count_multiples(step: float, lo: float, hi: float, k_min: int, k_max: int) -> int:
    """Integers k in [k_min, k_max] with lo <= k * step <= hi."""
    a = max(k_min, math.ceil(lo / step - _STEP_EPS))
    b = min(k_max, math.floor(hi / step + _STEP_EPS))
    return max(0, b - a + 1)


def candidate_counts(orientations, profile_name: str) -> tuple[int, int]:
    """(M, m): the candidate axes of ``orientations`` (exactly ``len(candidate_axes(...))``) and those
    within the rotary travel of the profile (exact for a continuous rotary axis, an upper bound for a
    limited one), counted without building them."""
    reach = _profile_reach(profile_name)
    if orientations.sampling == "uniform":
        res = math.radians(float(orientations.resolution_deg))
        n = max(4, int(math.ceil((_FIBONACCI_K / res) ** 2 - 1e-9)))
        if reach is None:
            return n, n
        # z_i = 1 - (2 i + 1) / n; phi_i = arccos(z_i) in [a, b]  <=>  (n (1 - cos a) - 1) / 2 <= i <= ...
        feas = 0
        for a, b in reach[0]:
            i0 = math.ceil((n * (1.0 - math.cos(math.radians(a))) - 1.0) / 2.0 - 1e-9)
            i1 = math.floor((n * (1.0 - math.cos(math.radians(b))) - 1.0) / 2.0 + 1e-9)
            feas += max(0, min(i1, n - 1) - max(i0, 0) + 1)
        return n, min(n, feas)
    s = float(orientations.phi_step_deg)
    t = float(orientations.theta_step_deg)
    n_phi = int(math.floor(180.0 / s + _STEP_EPS))
    south = abs(n_phi * s - 180.0) <= _STEP_EPS * s
    n_theta = int(math.ceil(360.0 / t - _STEP_EPS))
    n_rings = n_phi - 1 if south else n_phi
    total = 1 + n_rings * n_theta + (1 if south else 0)
    if reach is None:
        return total, total
    feas = 0
    for a, b in reach[0]:
        feas += n_theta * _count_multiples(s, a, b, 1, n_rings)
        feas += 1 if a <= 0.0 <= b else 0
        feas += 1 if south and a <= 180.0 <= b else 0
    return total, min(total, feas)


#: Without the cloud's extent, its points are assumed to cover the surface of a cube at least this
#: densely (points per mm^2; scans have 1-50, the sparse half sphere 0.16): sides of sqrt(N / (6 x this)) mm.
ASSUMED_MIN_DENSITY = 1.0


def _extent(extent_mm: Sequence[float] | None, config: PlanConfig, n_points: int = 1) -> tuple[float, float, float]:
    """The cloud's bounding-box sides (mm); without them a cube of ASSUMED_MIN_DENSITY, at most
    ``input.max_extent_mm`` on a side."""
    if extent_mm is None:
        e = min(float(config.input.max_extent_mm), math.sqrt(max(n_points, 1) / (6.0 * ASSUMED_MIN_DENSITY)))
        return e, e, e
    x, y, z = (max(float(v), 0.0) for v in extent_mm)
    return x, y, z


def _grid_spacing(n_points: int, config: PlanConfig, ext) -> tuple[float, float]:
    """(g used, g from the density): sphere throwing's line spacing, mm, estimated from the point count
    and the box's surface (the default grid is 1.5 x the point spacing, clipped to [r/32, r/4])."""
    r = float(config.normals.sphere_diameter_mm) / 2.0
    x, y, z = ext
    area = max(2.0 * (x * y + y * z + z * x), 1e-6)
    g_density = 1.5 * math.sqrt(area / max(n_points, 1))
    if config.normals.grid_spacing_mm is not None:
        return float(config.normals.grid_spacing_mm), g_density
    return min(max(g_density, r / 32.0), r / 4.0), g_density


def sampled_points(n_points: int, config: PlanConfig, extent_mm: Sequence[float] | None = None) -> int:
    """The points that get a normal (the visibility matrix's rows), estimated: all of them with
    ``normals.method = input``; with sphere throwing :data:`THROWING_SAMPLED_SHARE` of a dense cloud,
    more where the grid is finer than the density's (clipped at r / 4, or set), at most all."""
    N = max(int(n_points), 1)
    if config.normals.method == "input":
        return N
    g, g_density = _grid_spacing(N, config, _extent(extent_mm, config, N))
    share = THROWING_SAMPLED_SHARE * max(1.0, (g_density / g) ** 2)
    return max(1, min(N, int(math.ceil(N * share))))


# --------------------------------------------------------------------------------------------------
# the estimate


def _orientation_parameter(config: PlanConfig) -> tuple[str, str]:
    """(the orientation parameter that sets the axis count, its value as text)."""
    o = config.orientations
    if o.sampling == "uniform":
        return "orientations.resolution_deg", f"orientations.resolution_deg = {o.resolution_deg:g}"
    # which step is finer than its default, relatively
    phi_ratio, theta_ratio = 10.0 / float(o.phi_step_deg), 30.0 / float(o.theta_step_deg)
    name = "orientations.phi_step_deg" if phi_ratio >= theta_ratio else "orientations.theta_step_deg"
    return name, f"orientations.phi_step_deg = {o.phi_step_deg:g} / theta_step_deg = {o.theta_step_deg:g}"


def _shadow_mm2(ext) -> float:
    """The largest area the part's bounding box shows along any direction, mm^2 (an area's footprint
    in its frame is at most this): sqrt((yz)^2 + (zx)^2 + (xy)^2)."""
    x, y, z = ext
    return math.sqrt((y * z) ** 2 + (z * x) ** 2 + (x * y) ** 2)


def _finishing_cl(config: PlanConfig, ext) -> float:
    """Finishing CL points of one area, at most: its footprint (grown by the margin) / (step-over x step)."""
    fp = config.paths.finishing
    R = float(config.tool.diameter_mm) / 2.0
    h = min(float(fp.scallop_mm), R)
    stepover = max(2.0 * math.sqrt(max(2.0 * R * h - h * h, 1e-12)), 1e-3)
    step = float(fp.step_mm) if fp.step_mm is not None else R / 4.0
    grow = 2.0 * float(fp.margin_mm)
    return _shadow_mm2(tuple(e + grow for e in ext)) / (stepover * step)


def _roughing_cells(config: PlanConfig, ext) -> float:
    """Cells of the roughing map of one area: its stock's footprint / (Rt / 16)^2, at most ROUGHING_MAX_CELLS."""
    rp = config.paths.roughing
    Rt = float(rp.diameter_mm) / 2.0
    h = Rt / 16.0
    grow = 2.0 * (float(rp.stock_margin_mm) + Rt + 3.0 * h)
    return min(ROUGHING_MAX_CELLS, _shadow_mm2(tuple(e + grow for e in ext)) / (h * h))


def _throwing_cells(config: PlanConfig, ext, g: float) -> list[float]:
    """Candidate cells of each throwing direction (the box's shadow across it, cells 2 g wide, padded)."""
    r = float(config.normals.sphere_diameter_mm) / 2.0
    G = 2.0 * g
    pad = math.ceil(r / G) + 1
    out = []
    for d in config.normals.directions:
        k = math.sqrt(sum(c * c for c in d))
        v = [c / k for c in d]
        # two unit vectors across v; the box's shadow along each is sum |a_i| * side_i
        w = (1.0, 0.0, 0.0) if abs(v[0]) < 0.9 else (0.0, 1.0, 0.0)
        a = (v[1] * w[2] - v[2] * w[1], v[2] * w[0] - v[0] * w[2], v[0] * w[1] - v[1] * w[0])
        ka = math.sqrt(sum(c * c for c in a))
        a = tuple(c / ka for c in a)
        b = (v[1] * a[2] - v[2] * a[1], v[2] * a[0] - v[0] * a[2], v[0] * a[1] - v[1] * a[0])
        su = sum(abs(c) * e for c, e in zip(a, ext))
        sv = sum(abs(c) * e for c, e in zip(b, ext))
        out.append(min(THROWING_MAX_CELLS, (su / G + 4 * pad + 1) * (sv / G + 4 * pad + 1)))
    return out


def estimate_job_memory(n_points: int, config: PlanConfig, *,
                        extent_mm: Sequence[float] | None = None) -> MemoryEstimate:
    """The memory (bytes of address space) a job planning ``n_points`` points with ``config`` needs at most.

    ``extent_mm``: the cloud's bounding-box sides (x, y, z) in mm; without it a cube whose surface the
    points cover at :data:`ASSUMED_MIN_DENSITY` (pass the extent: the raster terms follow it). Computed
    from these numbers alone, in microseconds; see the module docstring for the model and its
    calibration.
    """
    N = max(int(n_points), 1)
    ext = _extent(extent_mm, config, N)
    M, m = candidate_counts(config.orientations, config.machine.profile)
    n = sampled_points(N, config, extent_mm)
    # distinct visibility columns: at most the faces of the arrangement of the 2n cone circles
    m_red = min(m, 2 * n * (2 * n - 1) + 2)
    pairs = n * m
    o_param, o_text = _orientation_parameter(config)
    axes_text = f"{o_text} ({m:,} candidate axes within the machine's travel, of {M:,})"
    n_text = (f"normals.method = input ({n:,} sampled points)" if config.normals.method == "input"
              else f"sphere throwing (about {n:,} sampled points of {N:,})")
    coarsen = ("Coarsen the orientation grid (a larger orientations.phi_step_deg / theta_step_deg, or "
               "orientations.resolution_deg)")
    decimate = "Decimate the cloud"
    if m >= 1_000 or n <= 50_000:
        pair_param, pair_advice = o_param, coarsen + " or decimate the cloud."
    else:
        pair_param = "normals.method" if config.normals.method == "input" else "cloud"
        pair_advice = decimate + " (or let sphere throwing sample it: normals.method = sphere_throwing)."

    always = [
        MemoryTerm("the worker process (libraries, thread stacks)", "SCANMILL_JOB_MEMORY_MB",
                   "the planning code itself", "Raise SCANMILL_JOB_MEMORY_MB.", PROCESS_BYTES),
        MemoryTerm("the cloud's arrays", "cloud", f"the cloud's {N:,} points", decimate + ".",
                   CLOUD_BYTES_PER_POINT * N),
        MemoryTerm("the visibility matrices", pair_param, f"{axes_text} x {n_text}", pair_advice,
                   PAIR_BYTES * pairs),
        MemoryTerm("the per-axis visibility report", o_param, axes_text, coarsen + ".", CANDIDATE_BYTES * M),
    ]

    stages: dict[str, list[MemoryTerm]] = {}
    if config.normals.method == "sphere_throwing":
        g, _ = _grid_spacing(N, config, ext)
        cells = sorted(_throwing_cells(config, ext, g), reverse=True)
        threads = min(THROWING_THREADS, len(cells))
        stages["normals"] = [MemoryTerm(
            "sphere throwing's rasters", "normals.grid_spacing_mm",
            f"normals.grid_spacing_mm = {g:.3g} mm (estimated) and normals.sphere_diameter_mm = "
            f"{config.normals.sphere_diameter_mm:g} over the cloud's {N:,} points",
            "Use a larger normals.grid_spacing_mm (or leave it null) or decimate the cloud.",
            int((THROWING_SHARED_BYTES_PER_POINT + threads * THROWING_BYTES_PER_POINT) * N
                + THROWING_BYTES_PER_CELL * sum(cells[:threads])))]

    # the cone's float64 dot products (one chunk of rows) with its masks, or later the filters' masks
    cone = 8 * min(n, VISIBILITY_CHUNK_ROWS) * m + 3 * pairs
    vis = [MemoryTerm("the visibility stage's dot products and masks", pair_param, f"{axes_text} x {n_text}",
                      pair_advice, int(max(cone, VISIBILITY_MASK_BYTES * pairs)))]
    if config.visibility.global_:
        R = float(config.tool.diameter_mm) / 2.0
        radii = [R] + ([float(config.tool.shank_diameter_mm) / 2.0] if config.tool.shank_diameter_mm else [])
        h = 0.35 * min(radii)
        side = max(ext) + 1.0
        cells = min(COLLISION_MAX_CELLS, (side / h + 2 * math.ceil(R / h) + 8) ** 2)
        obst = N if config.visibility.obstacles == "all" else n
        vis.append(MemoryTerm(
            "the cloud collision test", "visibility.obstacles",
            f"visibility.global with visibility.obstacles = {config.visibility.obstacles} ({obst:,} obstacle "
            "points, two axes at a time)",
            "Decimate the cloud or use visibility.obstacles = sampled.",
            int(COLLISION_THREADS * (COLLISION_BYTES_PER_POINT * obst + COLLISION_BYTES_PER_CELL * cells))))
    stages["visibility"] = vis

    per_axis2 = SETUPS_BYTES_PER_AXIS2 + SETUPS_BYTES_PER_AXIS2_PER_LEVEL * max(0, config.setups.max_setups - 2)
    stages["setups"] = [
        MemoryTerm("the set-up search's axis-by-axis matrices", o_param,
                   f"{axes_text}, setups.max_setups = {config.setups.max_setups}", coarsen + ".",
                   int(per_axis2 * m_red * m_red)),
        MemoryTerm("the set-up search's reduced visibility matrix", pair_param, f"{axes_text} x {n_text}",
                   pair_advice, int(SETUPS_PAIR_BYTES * pairs)),
    ]

    pp = config.paths
    if pp.finishing.enabled or pp.roughing.enabled:
        cl = _finishing_cl(config, ext) if pp.finishing.enabled else 0.0
        rcells = _roughing_cells(config, ext) if pp.roughing.enabled else 0.0
        areas = config.setups.max_setups
        scallop = (f"paths.finishing.scallop_mm = {pp.finishing.scallop_mm:g} (about {cl:,.0f} finishing CL "
                   "points per area)")
        stages["paths"] = [
            MemoryTerm("the tool paths of an area", "paths.finishing.scallop_mm",
                       f"{scallop}, the roughing map ({rcells:,.0f} cells) and the cloud's {N:,} points",
                       "Use a larger paths.finishing.scallop_mm or step_mm, or decimate the cloud.",
                       int(PATHS_BASE_BYTES + PATHS_BYTES_PER_POINT * N + FINISHING_BYTES_PER_CL * cl
                           + ROUGHING_BYTES_PER_CELL * rcells)),
            MemoryTerm("the NC programs and moves of every area", "paths.finishing.scallop_mm",
                       f"{scallop} x setups.max_setups = {areas} areas",
                       "Use a larger paths.finishing.scallop_mm, or fewer post.dialects.",
                       int(POST_BYTES_PER_CL * cl * areas * max(1, len(config.post.dialects)))),
        ]
        if pp.roughing.enabled and config.simulate.enabled and config.simulate.engagement:
            stages["paths"].append(MemoryTerm(
                "the roughing's engagement measure", "simulate.engagement",
                "simulate.engagement = true (the verification measures every roughing move's engagement)",
                "Set simulate.engagement to false.", ENGAGEMENT_BYTES))

    peak_stage, peak_terms = max(stages.items(), key=lambda kv: sum(t.bytes for t in kv[1]))
    terms = sorted((t for t in always + peak_terms if t.bytes > 0), key=lambda t: -t.bytes)
    return MemoryEstimate(total_bytes=int(sum(t.bytes for t in terms)), terms=tuple(terms), n_points=N,
                          n_sampled=int(n), n_candidates=int(M), n_feasible=int(m), peak_stage=peak_stage)


def estimate_artifact_bytes(n_points: int, config: PlanConfig, *,
                            extent_mm: Sequence[float] | None = None) -> int:
    """About how many bytes a job's artifacts take on disk (plan.npz, segmentation.ply, preview, NC programs,
    moves JSON): per point, plus per finishing CL point of every area and dialect. For the free-space
    check before a job starts; measured 44 MiB on the half sphere and 160-170 MiB on the femur-like
    scan at the default paths."""
    N = max(int(n_points), 1)
    ext = _extent(extent_mm, config, N)
    size = ARTIFACT_BASE_BYTES + ARTIFACT_BYTES_PER_POINT * N
    pp = config.paths
    if pp.finishing.enabled:
        size += ARTIFACT_BYTES_PER_CL * _finishing_cl(config, ext) * config.setups.max_setups \
            * (1 + len(config.post.dialects))
    return int(size)
