"""The placement stage of :func:`planning.pipeline.run_plan` (``fixtures.placement``): how the part sits on
the table before the orientations, the as-scanned hint after an infeasible set-up stage, and the
``plan.json`` ``placement`` block. The search itself is :mod:`planning.placement.search`."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from planning.placement.poses import apply_pose, max_candidates, turn
from planning.placement.search import SCREENING, full_yaw, search_placement, search_work
from planning.setups import zone_mask
from schemas.plan import PlacementCandidate, PlacementSummary

__all__ = ["HINT_MAX_WORK", "Placed", "place", "placement_hint", "placement_result", "placement_summary"]

#: The as-scanned hint searches the other placements only when its collision tests rasterise at most
#: this many (point, axis) pairs (:func:`planning.placement.search_work`: about 5-10 s here); beyond it the
#: message only suggests fixtures.placement = auto. A count, not a clock: the same plan, the same message.
HINT_MAX_WORK = 5e7


@dataclass(frozen=True)
class Placed:
    """How the part sits on the table (``fixtures.placement``): the cloud and normals the plan runs on
    (placed; ``normals`` the pipeline's ``_Normals``), the scanned points (the frame of the functional
    zones), the ``plan.json`` block, the winner's exact visibility for the visibility stage to reuse, and
    the sentence an infeasible as-scanned plan adds to its message."""

    cloud: object
    normals: object
    scanned_points: np.ndarray
    summary: PlacementSummary
    visibility: tuple | None = None
    hint: str = ""


def placement_summary(mode: str, search=None, pose=None) -> PlacementSummary:
    """plan.json ``placement``: the rigid motion applied (the identity unless ``pose``) and the candidates tried."""
    R = np.eye(3) if pose is None else pose.rotation
    t = np.zeros(3) if pose is None else pose.translation_mm
    rows = [PlacementCandidate(
        index=c.index, kind=c.pose.kind, label=c.pose.label, up=tuple(map(float, c.pose.up)), yaw_deg=c.pose.yaw_deg,
        stability_deg=None if c.pose.stability_deg is None else round(c.pose.stability_deg, 3),
        part_height_mm=round(c.pose.part_height_mm, 3), stage=c.stage, feasible=c.feasible, k=c.k, overlap=c.overlap,
        coverage=c.coverage, coverage_bound=c.coverage_bound, seconds=round(c.seconds, 4))
        for c in (search.tried if search is not None else [])]
    return PlacementSummary(
        mode=mode, kind="as_scanned" if pose is None else pose.kind,
        candidate=None if search is None or search.winner is None else search.winner.index,
        label="as scanned" if pose is None else pose.label,
        rotation=tuple(tuple(float(x) for x in r) for r in R), translation_mm=tuple(float(x) for x in t),
        n_candidates=len(rows), candidates=rows, screening=SCREENING if search is not None else "",
        seconds=round(search.seconds, 4) if search is not None else 0.0,
        message="" if search is None else search.message)


def place(run, cloud, nrm, config, profile, tool, base_dir) -> Placed:
    """``fixtures.placement``: "as_scanned" plans the scan as it lies; "auto" searches the candidate
    placements (:func:`planning.placement.search_placement`, the timed stage "placement") and plans the
    winner: the cloud, its file normals and the sampled normals turned (exact: planning/placement/search.py),
    the winner's visibility handed on. No winner: planned as scanned, with a warning."""
    if config.fixtures.placement != "auto":
        return Placed(cloud, nrm, cloud.points, placement_summary("as_scanned"))
    zmask, _ = zone_mask(cloud.points, nrm.sample_index, config.setups.functional_zones)
    res = run.stage("placement", lambda p: search_placement(
        cloud.points, nrm.sample_index, nrm.normals, config, profile, tool, zone_mask=zmask, base_dir=base_dir,
        progress=p))
    if res.winner is None:
        run.warnings.append(f"fixtures.placement auto: {res.message}; the part is planned as scanned")
        return Placed(cloud, nrm, cloud.points, placement_summary("auto", res),
                      hint=f"; fixtures.placement auto: {res.message}")
    pose = res.winner.pose
    R = pose.rotation
    placed = replace(cloud, points=apply_pose(cloud.points, pose),
                     normals=None if cloud.normals is None else turn(cloud.normals, R))
    return Placed(placed, replace(nrm, normals=turn(nrm.normals, R)), cloud.points,
                  placement_summary("auto", res, pose), visibility=res.visibility)


def placement_hint(run, placed: Placed, sel, ori, config, profile, tool, base_dir, zmask: np.ndarray) -> Placed:
    """An as-scanned plan proven infeasible: would another placement reach the coverage? Searched
    (stage "placement", the as-scanned pose left out) when it is cheap (:data:`HINT_MAX_WORK`) and the
    infeasibility was proven within the time limit; the answer is added to the plan's message."""
    if config.fixtures.placement == "auto" or sel.status != "infeasible":
        return placed
    nrm = placed.normals
    work = search_work(placed.scanned_points.shape[0], nrm.sample_index.size, ori.axes.shape[0],
                       max_candidates(full_yaw(profile)), config.visibility.obstacles)
    if "time limit" in sel.message or work > HINT_MAX_WORK:
        hint = "; try fixtures.placement = auto to search other placements of the part"
        run.warnings.append(hint[2:])
        return replace(placed, hint=hint)
    res = run.stage("placement", lambda p: search_placement(
        placed.scanned_points, nrm.sample_index, nrm.normals, config, profile, tool, zone_mask=zmask,
        base_dir=base_dir, skip_identity=True, progress=p))
    if res.winner is not None:
        w = res.winner
        hint = (f"; fixtures.placement = auto reaches it with the part {w.pose.describe()}: {w.k} set-up"
                f"{'s' if w.k != 1 else ''} cover {w.coverage * 100:.1f} %")
    else:
        hint = f"; fixtures.placement = auto would not help: {res.message}"
    run.warnings.append(hint[2:])
    return replace(placed, summary=placement_summary("as_scanned", res), hint=hint)


def placement_result(result, placed: Placed) -> None:
    """plan.json ``placement``, the hint in the message, and ``placed.ply`` with "auto"."""
    result.placement = placed.summary
    if placed.hint:
        result.message += placed.hint
    if placed.summary.mode == "auto":
        result.artifacts.placed_ply = "placed.ply"
