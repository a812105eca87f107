"""The planning pipeline: cloud -> normals -> orientations -> visibility -> set-ups -> areas -> paths -> post.

One function, :func:`run_plan`, calls each stage in turn (docs/design.md "The pipeline", Makki 2010
§2-3), times it, and gathers the ``plan.json`` document and the ``plan.npz`` arrays. The stages'
algorithms live in their packages (``planning/normals``, ``planning/orientations``, ...); this module
only passes their results on and turns them into the plan's summaries and warnings. No global
state: the same cloud and parameters give the same plan.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

import scanmill
from planning.advice import advise
from planning.areas import Areas, assign_areas
from planning.errors import InputError, ParameterError
from planning.inputs import Cloud
from planning.inputs.scale import check_normal_share, check_part_size
from planning.normals import sphere_throwing
from planning.normals.mesh_input import facet_point_normals, mesh_cloud
from planning.orientations import (
    CandidateAxes,
    candidate_axes,
    load_profile,
    machine_visibility,
)
from planning.placement.stage import place, placement_hint, placement_result
from planning.post.programs import post_areas
from planning.report.figures import apply_figures, unreached_indices
from planning.setups import SetupSelection, select_setups, zone_mask
from planning.simulate.models import load_blank
from planning.toolpath.area_paths import area_toolpaths
from planning.toolpath.surface import path_surface
from planning.visibility import GlobalVisibility, cone_visibility, global_visibility
from schemas.params import PlanConfig
from schemas.plan import (
    AreaRegions,
    AreasSummary,
    AxisFilters,
    InputSummary,
    NormalsSummary,
    OrientationsSummary,
    PathsSurface,
    PlanResult,
    Selection,
    Setup,
    Timing,
    VisibilitySummary,
)

# progress(stage, fraction of that stage done in [0, 1], message)
Progress = Callable[[str, float, str], None]

STAGES = ("normals", "placement", "orientations", "visibility", "setups", "areas", "paths", "post", "simulate")

_ROTARY_NAMES = {
    "table_table_ac": ("A", "C"), "table_table_bc": ("B", "C"),
    "head_head_ac": ("A", "C"), "head_head_bc": ("B", "C"),
}


@dataclass
class PlanOutcome:
    """A finished plan: the ``plan.json`` model, the ``plan.npz`` arrays, and what the writers need."""

    result: PlanResult
    arrays: dict[str, np.ndarray]
    points: np.ndarray                      # (N,3) mm, the whole input cloud
    input_labels: np.ndarray                # (N,) set-up of every input point
    selected_axes: np.ndarray               # (k,3)
    extra: dict = field(default_factory=dict)


def _stage_progress(progress: Progress | None, stage: str):
    if progress is None:
        return None
    return lambda fraction, message="": progress(stage, float(fraction), str(message))



class _Run:
    """Timings and warnings of one plan; :meth:`stage` runs one stage with its progress lines."""

    def __init__(self, progress: Progress | None):
        self.progress = progress
        self.timings: list[Timing] = []
        self.warnings: list[str] = []

    def stage(self, stage: str, fn):
        """Run ``fn(stage_progress)``, time it as ``stage`` and report its start and end."""
        progress = self.progress
        t0 = time.perf_counter()
        if progress:
            progress(stage, 0.0, "start")
        out = fn(_stage_progress(progress, stage))
        self.timings.append(Timing(stage=stage, seconds=round(time.perf_counter() - t0, 4)))
        if progress:
            progress(stage, 1.0, f"done in {self.timings[-1].seconds:.2f} s")
        return out


@dataclass(frozen=True)
class _Normals:
    sample_index: np.ndarray     # (n,) int64 into the input points
    normals: np.ndarray          # (n,3) unit, outward
    summary: NormalsSummary


@dataclass(frozen=True)
class _Orientations:
    candidates: CandidateAxes    # every candidate axis on the Gaussian sphere
    feasible: np.ndarray         # (M,) bool: within the rotary travel
    axes: np.ndarray             # (m,3) the feasible axes, the visibility matrix's columns
    angles_deg: np.ndarray       # (m,2) their (tilt, rotary) positions


@dataclass(frozen=True)
class _Visibility:
    cone: np.ndarray             # (n,m) bool: tool cone only
    chain: GlobalVisibility      # after travel, fixtures and cloud collisions
    summary: VisibilitySummary


def _normals(cloud: Cloud, config: PlanConfig, progress, facets=None) -> _Normals:
    """Stage 2 (Makki §2.1): the file's normals, a mesh's facet normals (Chui 2008 eq. 8; ``facets`` the
    points :func:`planning.normals.mesh_input.mesh_cloud` laid on them), or sphere throwing's sampled
    points and normals."""
    p = config.normals
    n_input = cloud.points.shape[0]
    if p.method == "facets":
        sample_index, normals = facet_point_normals(cloud, facets)
        summary = NormalsSummary(method="facets", n_sampled=int(sample_index.size),
                                 sampled_fraction=sample_index.size / n_input)
        return _Normals(sample_index, normals, summary)
    if p.method == "input":
        if cloud.normals is None:
            raise InputError("normals.method is 'input' but the file carries no normals (PLY nx ny nz, "
                             "PCD normal_x normal_y normal_z); use normals.method = sphere_throwing",
                             code="missing_normals")
        nrm = np.asarray(cloud.normals, dtype=np.float64)
        length = np.linalg.norm(nrm, axis=1)
        good = np.isfinite(length) & (length > 1e-12)
        if not good.any():
            raise InputError("the normals in the file are all zero or invalid", code="invalid_normals")
        sample_index = np.flatnonzero(good).astype(np.int64)
        normals = nrm[good] / length[good, None]
        summary = NormalsSummary(method="input", n_sampled=int(sample_index.size),
                                 sampled_fraction=sample_index.size / n_input)
        return _Normals(sample_index, normals, summary)
    res = sphere_throwing(cloud.points, sphere_diameter_mm=p.sphere_diameter_mm,
                          grid_spacing_mm=p.grid_spacing_mm, directions=p.directions, progress=progress,
                          refine=p.refine)
    check_normal_share(cloud.points, int(res.sample_index.size), units=config.input.units,
                       sphere_diameter_mm=p.sphere_diameter_mm, tool_diameter_mm=config.tool.diameter_mm,
                       max_extent_mm=config.input.max_extent_mm, accept_small_part=config.input.accept_small_part)
    if res.sample_index.size == 0:
        raise InputError("sphere throwing touched no point: check normals.sphere_diameter_mm and "
                         "normals.grid_spacing_mm against the part size", code="no_normals")
    summary = NormalsSummary(method="sphere_throwing", n_sampled=int(res.sample_index.size),
                             sampled_fraction=res.sample_index.size / n_input,
                             sphere_diameter_mm=float(res.sphere_diameter_mm),
                             grid_spacing_mm=float(res.grid_spacing_mm))
    return _Normals(np.asarray(res.sample_index, dtype=np.int64), np.asarray(res.normals, dtype=np.float64), summary)


def _normals_warnings(nrm: _Normals) -> list[str]:
    s = nrm.summary
    if s.method == "sphere_throwing" and s.sampled_fraction < 0.01:
        return [f"only {s.sampled_fraction:.1%} of the points got a normal: the cloud may be sparse "
                "for the sphere diameter, or the grid spacing coarse"]
    return []


def _orientations(config: PlanConfig, profile) -> _Orientations:
    """Stage 3 (Makki §2.2.1-2.2.2): candidate axes, and those within the machine's rotary travel."""
    o = config.orientations
    cand = candidate_axes(o.sampling, phi_step_deg=o.phi_step_deg, theta_step_deg=o.theta_step_deg,
                          resolution_deg=o.resolution_deg)
    mv = machine_visibility(cand.axes, profile)
    feasible = np.asarray(mv.feasible, dtype=bool)
    if not feasible.any():
        raise ParameterError(f"no candidate orientation lies within the rotary travel of machine profile "
                             f"'{profile.name}'")
    return _Orientations(cand, feasible, cand.axes[feasible], np.asarray(mv.angles_deg)[feasible])


def _visibility(points: np.ndarray, nrm: _Normals, ori: _Orientations, config: PlanConfig, tool, profile,
                base_dir, progress) -> tuple[np.ndarray, GlobalVisibility]:
    """Stage 4 (Makki §2.2.3-2.2.4): the tool cone, then travel, fixture and cloud collisions."""
    vp = config.visibility
    cone = cone_visibility(nrm.normals, ori.axes, vp.cone_deg)
    gv = global_visibility(points, nrm.sample_index, nrm.normals, ori.axes, ori.angles_deg, cone, tool=tool,
                           profile=profile, fixtures_params=config.fixtures, check_global=vp.global_,
                           check_travel=vp.travel, obstacles=vp.obstacles, base_dir=base_dir,
                           progress=progress, along_swing_deg=_along_swing(config))
    return cone, gv


def _along_swing(config: PlanConfig) -> float | None:
    """``global_visibility``'s ``along_swing_deg``: the 5-axis swing in simultaneous 5-axis finishing
    (the pass directions must be within travel themselves), None in 3+2."""
    fp = config.paths.finishing
    return float(fp.max_swing_deg) if fp.mode == "5axis" else None


def _visibility_summary(config: PlanConfig, nrm: _Normals, ori: _Orientations, cone: np.ndarray,
                        gv: GlobalVisibility) -> VisibilitySummary:
    """plan.json ``visibility``: what each filter removed, per candidate axis (machine-infeasible ones too)."""
    vp = config.visibility
    cand = ori.candidates
    vis = gv.visible
    n_s = int(nrm.sample_index.size)
    cone_counts = cone.sum(axis=0)
    col = {int(c): k for k, c in enumerate(np.flatnonzero(ori.feasible))}
    per_axis = []
    for c in range(cand.axes.shape[0]):
        k = col.get(c)
        if k is None:
            per_axis.append(AxisFilters(candidate=c, phi_deg=float(cand.phi_deg[c]), theta_deg=float(cand.theta_deg[c]),
                                        machine=n_s, cone=0, travel=0, fixture_collision=0, cloud_collision=0,
                                        visible=0))
        else:
            per_axis.append(AxisFilters(
                candidate=c, phi_deg=float(cand.phi_deg[c]), theta_deg=float(cand.theta_deg[c]), machine=0,
                cone=int(n_s - cone_counts[k]), travel=int(gv.removed["travel"][k]),
                fixture_collision=int(gv.removed["fixture_collision"][k]),
                cloud_collision=int(gv.removed["cloud_collision"][k]), visible=int(vis[:, k].sum())))
    return VisibilitySummary(
        global_checked=vp.global_, travel_checked=vp.travel, obstacles=vp.obstacles,
        n_obstacle_points=gv.n_obstacles, placement_mm=tuple(float(x) for x in gv.placement_mm),
        table_z_mm=gv.table_z_mm, pairs_cone=int(cone.sum()), pairs_visible=int(vis.sum()),
        removed_total={k: int(v.sum()) for k, v in gv.removed.items()}, per_axis=per_axis)


def _visibility_warnings(vis: _Visibility) -> list[str]:
    if not vis.chain.visible.any():
        return ["no sampled point is visible along any feasible axis after the travel and collision "
                "checks: check the tool length, holder, placement and fixtures"]
    return []


def selection_matrix(visible: np.ndarray, axes: np.ndarray, normals: np.ndarray, config: PlanConfig,
                     along: np.ndarray | None = None) -> np.ndarray:
    """(n, m) which set-up axis can finish which sample: ``visible`` itself in 3+2; in 5-axis finishing
    (``paths.finishing.mode``), the points some candidate axis within the swing sees, where the machine
    can present the set-up's own axis (``along``: :attr:`GlobalVisibility.along`;
    :func:`planning.visibility.five_axis.five_axis_visibility`)."""
    fp = config.paths.finishing
    if fp.mode != "5axis":
        return visible
    from planning.visibility.five_axis import five_axis_visibility

    return five_axis_visibility(visible, axes, normals, fp.max_swing_deg, along=along)


def _setups(visible: np.ndarray, zmask: np.ndarray, config: PlanConfig, progress) -> SetupSelection:
    """Stage 5 (Makki §3.1): the fewest axes covering ``setups.coverage`` with the least overlap, exactly,
    over ``visible`` (:func:`selection_matrix`)."""
    s = config.setups
    return select_setups(
        visible, coverage=s.coverage, max_setups=s.max_setups, min_points=s.min_points,
        zone_mask=zmask if zmask.any() else None, solver=s.solver, time_limit_s=s.time_limit_s,
        progress=progress)


def _setups_warnings(sel: SetupSelection, vsum: VisibilitySummary, config: PlanConfig) -> list[str]:
    warnings = []
    if sel.status in ("infeasible", "unknown"):
        warnings.append(sel.message)
        removed = {k: v for k, v in vsum.removed_total.items() if v}
        if removed:
            warnings.append(
                "of the " + f"{vsum.pairs_cone:,} (point, axis) pairs in the tool cone, "
                + ", ".join(f"{k.replace('_', ' ')} removed {v:,}" for k, v in removed.items())
                + " (per axis in plan.json 'visibility'): check fixtures.fixture_height_mm, the tool and holder "
                  "lengths and the machine profile's travel")
    elif sel.status == "feasible":
        warnings.append(f"the set-up search hit setups.time_limit_s = {config.setups.time_limit_s} s before proving "
                        f"optimality (gap {sel.gap:.1%}); the best plan found is returned")
    return warnings


def _areas_warnings(areas: Areas, nrm: _Normals) -> list[str]:
    n_integrated = int(areas.integrated.sum())
    if n_integrated:
        return [f"{n_integrated} sampled points ({n_integrated / max(len(nrm.sample_index), 1):.1%}) are seen "
                "by no chosen orientation and were attached to the nearest area: their accessibility "
                "is not guaranteed"]
    return []


def _paths(points: np.ndarray, cloud: Cloud, areas: Areas, sel_axes: np.ndarray, tool, gv: GlobalVisibility,
           config: PlanConfig, progress, carried=None) -> tuple:
    """Stage 7 (Makki §4; Sood; Popescu; Tchanchane & Bey): the surface the finishing ball rests on
    (:func:`planning.toolpath.surface.path_surface`; None without finishing), then roughing and finishing
    per area and region, on the carried stock when given (issue 16). Returns ``(surface, area paths)``."""
    pp = config.paths
    surface = (path_surface(points, radius_mm=tool.radius_mm, mode=pp.surface, faces=cloud.faces,
                            source_format=cloud.source_format) if pp.finishing.enabled else None)
    return surface, area_toolpaths(
        points, areas.input_labels, sel_axes, tool=tool, paths_params=pp, fixtures=gv.fixtures,
        forbidden=gv.forbidden_mm, max_slope_deg=min(float(config.visibility.cone_deg[1]), 87.0),
        input_regions=areas.input_regions, progress=progress, carried=carried,
        faces=None if surface is None else surface.faces, cone_deg=tuple(config.visibility.cone_deg),
        semi_tool=_semi_tool(config))


#: An area's operations in the order the posts write them (AreaPaths attributes, each with its ``_guard``).
_OPERATIONS = ("roughing", "semi_finishing", "finishing")


def _semi_tool(config: PlanConfig):
    """The semi-finishing cutter when ``paths.semi_finishing`` is enabled (with the finishing), else None."""
    if not (config.paths.semi_finishing.enabled and config.paths.finishing.enabled):
        return None
    from planning.toolpath.semi_finishing import semi_tool

    return semi_tool(config)


def _carried(points: np.ndarray, areas: Areas, config: PlanConfig, tool, gv: GlobalVisibility, profile,
             rotary_deg: np.ndarray, blank, normals: np.ndarray, selected: np.ndarray, visible: np.ndarray):
    """The stock carried through the set-ups (issue 16 item 1): the same stock, obstacles and tools
    as the verification (:mod:`planning.simulate.models`), the set-ups on the machine for the travel,
    and the machining order."""
    from planning.simulate.kinematics import MachineModel
    from planning.simulate.models import build_models
    from planning.simulate.verify import stock_extent, tool_shapes
    from planning.toolpath.carried import CarriedStock, footprint, machining_order
    from planning.toolpath.guard import SetupMachine

    tools = tool_shapes(config, tool)
    lo, hi = stock_extent(points, config.stock, blank)
    models = build_models(lo, hi, config, gv.fixtures, tools, resolution_mm=config.simulate.resolution_mm, blank=blank)
    model = MachineModel(profile, gv.placement_mm)
    machines = [SetupMachine(model, np.asarray(a, dtype=np.float64)) for a in rotary_deg]
    k = int(rotary_deg.shape[0])
    return CarriedStock(stock=models.stock, obstacles=models.obstacles,
                        finishing_shape=tools[config.post.finishing_tool_number],
                        roughing_shape=tools[config.post.roughing_tool_number], machines=machines,
                        semi_shape=tools.get(config.post.semi_finishing_tool_number)
                        if config.paths.semi_finishing.enabled else None,
                        order=machining_order(areas.input_labels, k),
                        rapid_clearance_mm=config.simulate.rapid_clearance_mm + config.paths.guard_rapid_clearance_mm,
                        resolution_mm=config.simulate.resolution_mm,
                        footprint=footprint(points), normals=normals,
                        visible=visible[:, selected][areas.nearest_sample], config=config)


def _unmachined(area_paths, n_points: int):
    """The plan's unmachined scan points (issue 16 item 3), or None when no area was guarded."""
    from schemas.plan import UnmachinedSummary

    done = [ap for ap in area_paths if getattr(ap, "unmachined", None) is not None]
    if not done:
        return None
    per = {int(ap.area): int(ap.unmachined.size) for ap in done}
    n = int(sum(per.values()))
    msg = ("every scan point is reached by a kept finishing move" if n == 0 else
           f"{n} scan points ({n / max(n_points, 1):.1%}) are reached by no kept finishing move: their CL points "
           "were cut out where the holder, the stock, a fixture or the travel forbids them (setups[].path.finishing."
           "blocked_cl)")
    return UnmachinedSummary(n_points=n, share=round(n / max(n_points, 1), 6), per_area=per, message=msg)


def _paths_warnings(area_paths) -> list[str]:
    warnings = []
    for ap in area_paths:
        if ap.finishing is not None and not ap.gouge_free:
            warnings.append(f"area {ap.area}: the finishing path comes {ap.min_clearance_mm:.4f} mm from a cloud "
                            f"point, closer than R - tolerance: it would gouge")
        for op in _OPERATIONS:
            g = getattr(ap, f"{op}_guard", None)
            if g is not None and g.truncated:
                warnings.append(f"area {ap.area}: the {op} path was cut off {g.truncated} moves before its end: they "
                                f"still met the stock, a fixture or the travel after {g.rounds} repair rounds "
                                f"(setups[].path.{op}.guard)")
        if getattr(ap, "blocked", None) and sum(ap.blocked.values()) and ap.finishing is None:
            reasons = ", ".join(f"{k} {v}" for k, v in ap.blocked.items() if v)
            warnings.append(f"set-up {ap.area} cannot finish any of its area: every finishing CL point is blocked "
                            f"({reasons}; 'travel' = beyond the machine's travel at this set-up's rotary "
                            f"position); its {0 if ap.unmachined is None else ap.unmachined.size} scan points are "
                            "left unmachined")
        elif getattr(ap, "blocked", None) and sum(ap.blocked.values()):
            reasons = ", ".join(f"{k} {v}" for k, v in ap.blocked.items() if v)
            warnings.append(f"area {ap.area}: finishing CL points cut out where the tool may not go ({reasons}); "
                            f"{0 if ap.unmachined is None else ap.unmachined.size} scan points of the area are left "
                            "unmachined (plan.json unmachined)")
        if ap.holder_collisions or ap.fixture_collisions:
            warnings.append(f"area {ap.area}: at {ap.holder_collisions} finishing CL points the shank or holder "
                            f"meets the cloud and at {ap.fixture_collisions} the tool meets a fixture or the "
                            "table (plan.json setups[].path): check the stick-out and the holder")
    return warnings


def _setup_rows(ori: _Orientations, vis: np.ndarray, selected: np.ndarray, areas: Areas, names,
                path_summaries: dict) -> list[Setup]:
    """plan.json ``setups``: each chosen axis with its rotary positions, point counts and path summary."""
    axes, angles, cand = ori.axes, ori.angles_deg, ori.candidates
    setups = []
    for i, j in enumerate(selected):
        lab = areas.labels == i
        setups.append(Setup(
            id=i, candidate_index=int(j), tool_axis=tuple(float(c) for c in axes[j]),
            phi_deg=float(cand.phi_deg[ori.feasible][j]), theta_deg=float(cand.theta_deg[ori.feasible][j]),
            rotary_deg={names[0]: float(angles[j, 0]), names[1]: float(angles[j, 1])},
            n_visible=int(vis[:, j].sum()), n_points=int(lab.sum()),
            n_integrated=int((lab & areas.integrated).sum()),
            n_input_points=int((areas.input_labels == i).sum()), regions=_regions_row(areas, i),
            path=path_summaries.get(i)))
    return setups


def _regions_row(areas: Areas, i: int) -> AreaRegions | None:
    """plan.json ``setups[i].regions`` from the areas stage's figures."""
    if i >= len(areas.figures):
        return None
    f = areas.figures[i]
    return AreaRegions(n_regions=f.n_regions, largest_region_share=round(f.largest_region_share, 6),
                       n_small_regions=f.n_small_regions, min_regions=f.min_regions,
                       n_visible_regions=f.n_visible_regions, area_mm2=round(f.area_mm2, 3),
                       seam_mm=round(f.seam_mm, 3))


def _plan_arrays(nrm: _Normals, ori: _Orientations, vis: np.ndarray, selected: np.ndarray, areas: Areas,
                 area_paths) -> dict[str, np.ndarray]:
    """The plan.npz arrays (docs/design.md, "plan output contract")."""
    arrays = {
        "sample_index": nrm.sample_index, "normals": nrm.normals, "candidate_axes": ori.axes,
        "candidate_rotary_deg": ori.angles_deg, "visibility": vis, "selected": selected,
        "labels": areas.labels, "integrated": areas.integrated, "overlap": areas.overlap,
        "input_labels": areas.input_labels,
    }
    for ap in area_paths:
        if ap.finishing is not None:
            # ball centres in the part frame, every move of the final path; cl_kind_i: 0 rapid,
            # 1 feed, 2 arc cw, 3 arc ccw (arc end points; centres in the neutral JSON)
            arrays[f"cl_{ap.area}"] = ap.frame.to_part(ap.finishing.xyz_mm)
            arrays[f"cl_kind_{ap.area}"] = ap.finishing.kind
    return arrays


def run_plan(cloud: Cloud, config: PlanConfig, *, name: str | None = None,
             progress: Progress | None = None, base_dir=None, command_line=None) -> PlanOutcome:
    """Plan the 3+2 machining of ``cloud`` (points in mm) with ``config`` (Makki 2010 §2-3).

    Returns the ``plan.json`` model and the ``plan.npz`` arrays: ``sample_index`` (n,),
    ``normals`` (n,3), ``candidate_axes`` (m,3) (machine-feasible axes), ``visibility`` (n,m),
    ``selected`` (k,), ``labels`` (n,), ``integrated`` (n,), plus ``input_labels`` (N,).
    ``base_dir``: where relative fixture mesh paths are looked up (the configuration's folder).
    ``command_line``: the ``scanmill plan`` command (argv, program first) that runs this plan, or None
    (a service job, the Python API): an infeasible plan's advice gives it back with the change to make.
    """
    run = _Run(progress)
    run.warnings += list(getattr(cloud, "warnings", ()))     # what reading changed (an image scaled down, ...)
    points = cloud.points
    check_part_size(points, units=config.input.units, tool_diameter_mm=config.tool.diameter_mm,
                    min_tool_diameters=config.input.min_part_tool_diameters,
                    max_extent_mm=config.input.max_extent_mm, accept_small_part=config.input.accept_small_part)
    n_file_points = int(points.shape[0])
    cloud, facets = mesh_cloud(cloud, config.input.mesh_sample_mm, config.input.mesh_max_points)   # meshes
    points = cloud.points
    profile = load_profile(config.machine.profile)
    tool = config.tool.assembly()          # cutter, shank and holder: visibility, paths and posts
    carry = config.paths.carry_stock and (config.paths.finishing.enabled or config.paths.roughing.enabled)
    blank = load_blank(config.stock, base_dir) if (config.simulate.enabled or carry) else None   # a bad file stops here

    nrm = run.stage("normals", lambda p: _normals(cloud, config, p, facets))
    run.warnings += _normals_warnings(nrm)
    placed = place(run, cloud, nrm, config, profile, tool, base_dir)     # fixtures.placement
    cloud, points, nrm = placed.cloud, placed.cloud.points, placed.normals
    ori = run.stage("orientations", lambda p: _orientations(config, profile))
    cone, gv = run.stage("visibility", lambda p: placed.visibility or _visibility(points, nrm, ori, config, tool, profile,
                                                                                  base_dir, p))
    vis = _Visibility(cone, gv, _visibility_summary(config, nrm, ori, cone, gv))
    run.warnings += _visibility_warnings(vis)
    zmask, zone_warnings = zone_mask(placed.scanned_points, nrm.sample_index, config.setups.functional_zones)
    run.warnings += zone_warnings
    finish_vis = selection_matrix(gv.visible, ori.axes, nrm.normals, config, along=gv.along)
    sel = run.stage("setups", lambda p: _setups(finish_vis, zmask, config, p))
    run.warnings += _setups_warnings(sel, vis.summary, config)
    hinted = {}

    def placement_search(sel=sel, placed=placed):
        """The placement hint (another placement of the part?), searched when the advice's tries come to it."""
        hinted["placed"] = placement_hint(run, placed, sel, ori, config, profile, tool, base_dir, zmask)
        return hinted["placed"].summary

    advice, sel = advise(run, sel, points=points, nrm=nrm, ori=ori, config=config, profile=profile,   # issue 34
                         visible=finish_vis, zmask=zmask, placement=placement_search, base_dir=base_dir,
                         command_line=command_line)
    placed = hinted.get("placed", placed)
    selected = np.asarray(sel.selected, dtype=np.int64)
    sel_axes = ori.axes[selected]
    label_cone = (config.visibility.cone_deg if config.paths.finishing.mode != "5axis"
                  else (0.0, config.paths.finishing.max_swing_deg))
    areas = run.stage("areas", lambda p: assign_areas(points, nrm.sample_index, nrm.normals, finish_vis,
                                                      selected, sel_axes, label_cone,
                                                      config.areas, progress=p))
    run.warnings += _areas_warnings(areas, nrm)
    area_paths = []
    surface = carried = None
    pp = config.paths
    order = list(range(int(selected.size)))
    if (pp.finishing.enabled or pp.roughing.enabled) and selected.size:
        normals = cloud.normals if cloud.normals is not None else nrm.normals[areas.nearest_sample]
        carried = (_carried(points, areas, config, tool, gv, profile, ori.angles_deg[selected], blank, normals,
                            selected, finish_vis) if carry else None)
        if carried is not None:
            order = carried.order
        surface, area_paths = run.stage("paths", lambda p: _paths(points, cloud, areas, sel_axes, tool, gv, config,
                                                                  p, carried))
        if surface is not None and surface.warning:
            run.warnings.append(surface.warning)
        run.warnings += _paths_warnings(area_paths)
    programs, path_summaries = ({}, {})
    if area_paths:
        programs, path_summaries = run.stage("post", lambda p: post_areas(
            area_paths, setups_axes=sel_axes, rotary_deg=ori.angles_deg[selected], profile=profile,
            placement_mm=gv.placement_mm, gauge_length_mm=tool.gauge_length_mm, config=config, progress=p))
    simulation = _simulation(cloud, config, nrm, areas, programs, order, profile, tool, gv, blank, run,
                             area_paths=area_paths, carried=carried if area_paths else None)

    names = _ROTARY_NAMES[profile.kinematics]
    result = _plan_result(cloud, config, name, nrm, ori, vis, sel, areas, profile, names,
                          _setup_rows(ori, gv.visible, selected, areas, names, path_summaries), run)
    result.verification = simulation.verification
    if surface is not None:
        result.paths_surface = PathsSurface(**surface.summary())
    if facets is not None:
        result.input.n_points = n_file_points
        result.input.n_faces = int(cloud.faces.shape[0])
        result.input.n_points_planned = int(points.shape[0])
        result.input.facet_spacing_mm = round(float(facets.spacing_mm), 6)
    elif cloud.faces is not None:
        result.input.n_faces = int(cloud.faces.shape[0])
    placement_result(result, placed)
    result.advice = advice
    result.machining_order = order
    result.unmachined = _unmachined(area_paths, points.shape[0])
    if result.unmachined is not None and result.unmachined.n_points:
        result.artifacts.unmachined_png = "unmachined.png"
    if simulation.deviation_mm is not None:
        result.artifacts.deviation_ply, result.artifacts.deviation_png = "deviation.ply", "deviation.png"
    if simulation.stock is not None:
        result.artifacts.stock_ply = "stock.ply"
    classes = apply_figures(result, input_labels=areas.input_labels,
                            not_covered=areas.integrated[areas.nearest_sample],
                            unreached=unreached_indices(area_paths),
                            deviation_mm=simulation.deviation_mm, config=config)
    return PlanOutcome(result=result, arrays=_plan_arrays(nrm, ori, gv.visible, selected, areas, area_paths),
                       points=points, input_labels=areas.input_labels, selected_axes=sel_axes,
                       extra={"programs": programs, "area_paths": area_paths, "areas": areas,
                              "simulation": simulation, "verify_again": getattr(simulation, "again", None),
                              "point_classes": classes})


def _simulated_operations(area_paths, carried) -> dict | None:
    """Per area, the posted operations' moves as the guard ran them on the carried stock (roughing,
    semi-finishing, then 3+2 finishing: the order :func:`planning.post.programs.post_areas` posts them), for the
    single-pass verification; None when the paths were not run on the carried stock."""
    if carried is None:
        return None
    out = {}
    for ap in area_paths:
        ops = []
        for tp, g in ((getattr(ap, op, None), getattr(ap, f"{op}_guard", None)) for op in _OPERATIONS):
            if tp is None:
                continue
            if g is None or g.moves is None or tp.axis is not None:
                ops = None                     # not guarded, or 5-axis (its own post): run again
                break
            ops.append(g.moves)
        if ops is not None:
            out[ap.area] = ops
    return out


def _simulation(cloud: Cloud, config: PlanConfig, nrm: _Normals, areas: Areas, programs: dict, order: list[int],
                profile, tool, gv: GlobalVisibility, blank, run: _Run, area_paths=(), carried=None):
    """Stage 9 (issue 15): the posted programs run on the simulated machine and stock, or why not
    (single pass: the moves the paths stage ran on the ``carried`` stock, once proven to be the
    programs', are not run again)."""
    from planning.simulate.verify import skipped, verify_plan

    if not config.simulate.enabled:
        return skipped("simulate.enabled is false")
    if not programs:
        return skipped("no program was posted")
    normals = cloud.normals if cloud.normals is not None else nrm.normals[areas.nearest_sample]
    args = dict(programs=programs, order=order, profile=profile, placement_mm=gv.placement_mm, tool=tool,
                fixtures=gv.fixtures, points=cloud.points, normals=normals, input_labels=areas.input_labels,
                blank=blank, simulated=_simulated_operations(area_paths, carried),
                stock_after=None if carried is None else carried.stock)

    def again(mode: str = "independent", programs: dict | None = None, progress=None):
        """The verification once more, with ``simulate.mode = mode`` and ``programs`` (default: the
        posted ones); the plan's outcome keeps this as ``extra["verify_again"]``: the tests compare
        the two modes on the same programs, and on programs changed after posting."""
        cfg = config.model_copy(update={"simulate": config.simulate.model_copy(update={"mode": mode})})
        return verify_plan(config=cfg, progress=progress, **{**args, **({} if programs is None else
                                                                         {"programs": programs})})

    out = run.stage("simulate", lambda p: verify_plan(config=config, progress=p, **args))
    out.again = again
    return out


def _plan_result(cloud: Cloud, config: PlanConfig, name, nrm: _Normals, ori: _Orientations, vis: _Visibility,
                 sel: SetupSelection, areas: Areas, profile, names, setups: list[Setup], run: _Run) -> PlanResult:
    """The plan.json document of a finished run."""
    points = cloud.points
    lo, hi = points.min(axis=0), points.max(axis=0)
    return PlanResult(
        scanmill_version=scanmill.__version__,
        status={"infeasible": "infeasible", "unknown": "incomplete"}.get(sel.status, "planned"),
        message=sel.message,
        input=InputSummary(name=name, format=cloud.source_format, n_points=int(points.shape[0]),
                           units=config.input.units, bbox_min_mm=tuple(map(float, lo)),
                           bbox_max_mm=tuple(map(float, hi)), has_normals=cloud.normals is not None),
        parameters=config,
        normals=nrm.summary,
        orientations=OrientationsSummary(
            sampling=config.orientations.sampling, n_candidates=int(ori.candidates.axes.shape[0]),
            n_machine_feasible=int(ori.feasible.sum()), n_kept=int(sel.n_axes_kept),
            machine_profile=profile.name, kinematics=profile.kinematics, rotary_axes=names),
        visibility=vis.summary,
        selection=Selection(status=sel.status, solver=sel.solver, k=int(sel.k), covered=int(sel.covered),
                            required_covered=int(sel.required_covered), coverage=float(sel.coverage),
                            overlap=int(sel.overlap), lower_bound=sel.lower_bound, gap=sel.gap,
                            best_coverage_at_max=sel.best_coverage_at_max, n_classes=int(sel.n_classes),
                            seconds=float(sel.seconds), message=sel.message),
        setups=setups, coverage=float(sel.coverage), overlap_points=int(sel.overlap),
        n_integrated=int(areas.integrated.sum()),
        areas=AreasSummary(method=areas.method, n_regions=sum(f.n_regions for f in areas.figures),
                           seam_mm=round(areas.seam_mm, 3), label_change_share=round(areas.label_change_share, 6)),
        timings=run.timings, warnings=run.warnings)
