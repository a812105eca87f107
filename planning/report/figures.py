"""The plan's figures, computed once (issue 34): what became of every input point, and the machining time.

Every report of a plan (the CLI summary, plan.json's message and status, the service's result headline,
the pictures, the viewer) reads :class:`schemas.plan.PlanFigures` from here instead of computing its own.

Each input point is in exactly one class, decided in this order:

1. **finished**: within ``paths.finishing.tolerance_mm + scallop_mm`` (+ the simulation's measuring
   bound) of the simulated final surface on both sides (:func:`planning.simulate.verify.verify_plan`'s
   reported deviation, the one the pictures show);
2. **not covered**: seen by no chosen orientation (its nearest sampled point was attached to an area by
   distance: ``areas.integrated``), so no finishing was planned for it on purpose;
3. **unreached**: reached by no kept finishing move (its CL points were cut out for the holder, the
   stock, a fixture or the travel: ``unmachined``);
4. **left**: reached, but not finished within tolerance (material left by a scallop, by a roughing
   the finishing could not clean, or a cut below the scan).

Without a simulation nothing is measured: finished and left are None, and points are only not covered or
unreached. The time is the simulated one (the posted programs as the control runs them,
:func:`planning.simulate.verify.move_minutes`) when the programs were simulated, else the paths' estimate.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from schemas.plan import AreaFigures, PlanFigures

__all__ = ["FINISHED", "LEFT", "NOT_COVERED", "UNREACHED", "plan_figures", "point_classes", "unreached_indices"]

#: Point classes of :func:`point_classes`.
FINISHED, NOT_COVERED, UNREACHED, LEFT = 0, 1, 2, 3


def unreached_indices(area_paths) -> np.ndarray:
    """The input point indices no kept finishing move of any area reaches (the areas' ``unmachined``)."""
    return np.concatenate([np.zeros(0, np.int64)] + [np.asarray(ap.unmachined, np.int64) for ap in area_paths
                                                     if getattr(ap, "unmachined", None) is not None])


def point_classes(n_points: int, *, deviation_mm: np.ndarray | None, limit_mm: float | None,
                  not_covered: np.ndarray, unreached: np.ndarray) -> np.ndarray:
    """(N,) int8 class of every input point (module docstring): ``deviation_mm`` (N,) the reported
    deviation (mm; NaN = not measured, never finished) and ``limit_mm`` the finishing limit, or None
    without a simulation (then no point is FINISHED and the measured rest counts as LEFT); ``not_covered``
    (N,) bool; ``unreached`` the input point indices no kept finishing move reaches."""
    cls = np.full(n_points, LEFT, dtype=np.int8)
    miss = np.zeros(n_points, dtype=bool)
    miss[np.asarray(unreached, dtype=np.int64)] = True
    cls[miss] = UNREACHED
    cls[np.asarray(not_covered, dtype=bool)] = NOT_COVERED
    if deviation_mm is not None and limit_mm is not None:
        with np.errstate(invalid="ignore"):
            cls[np.abs(np.asarray(deviation_mm, dtype=np.float64)) <= limit_mm] = FINISHED
    return cls


def plan_figures(*, n_points: int, input_labels: np.ndarray, order: Sequence[int], classes: np.ndarray,
                 measured: bool, target_coverage: float, verification=None, setups=()) -> PlanFigures:
    """:class:`PlanFigures` from the point ``classes`` (:func:`point_classes`) and ``input_labels`` (N,),
    per area in machining ``order``. Times: per area and operation from ``verification.areas[]``
    (simulated, s) when the verification ran, else from the set-ups' path summaries (estimate, s)."""
    counts = np.bincount(classes, minlength=4) if classes.size else np.zeros(4, dtype=np.int64)
    n = max(int(n_points), 1)

    def share(k: int) -> float:
        return round(float(counts[k]) / n, 6)

    sim = verification is not None and verification.status in ("passed", "failed") and verification.areas
    by_area = {a.area: a for a in verification.areas} if sim else {}
    paths = {s.id: s.path for s in setups}
    areas, total = [], 0.0
    for a in order:
        mine = input_labels == a
        c = np.bincount(classes[mine], minlength=4)
        rough = fin = semi = None
        if sim:
            av = by_area.get(a)
            whole = float(av.machining_time_s) if av is not None else 0.0
            if av is not None:
                ops = {op.operation: op.machining_time_s for op in av.operations}
                rough, fin, semi = ops.get("roughing"), ops.get("finishing"), ops.get("semi_finishing")
        else:
            p = paths.get(a)
            if p is not None:
                rough = p.roughing.machining_time_s if p.roughing is not None else None
                fin = p.finishing.machining_time_s if p.finishing is not None else None
                semi = p.semi_finishing.machining_time_s if p.semi_finishing is not None else None
            whole = (rough or 0.0) + (semi or 0.0) + (fin or 0.0)
        total += whole
        areas.append(AreaFigures(
            area=int(a), n_points=int(mine.sum()), finished=int(c[FINISHED]) if measured else None,
            left=int(c[LEFT]) if measured else None, unreached=int(c[UNREACHED]), not_covered=int(c[NOT_COVERED]),
            roughing_time_s=rough, semi_finishing_time_s=semi, finishing_time_s=fin,
            machining_time_s=round(whole, 1)))
    source = "simulated" if sim else ("estimate" if any(paths.get(a) is not None for a in order) else "none")
    return PlanFigures(
        n_points=int(n_points), measured=bool(measured),
        finished=int(counts[FINISHED]) if measured else None, finished_share=share(FINISHED) if measured else None,
        left=int(counts[LEFT]) if measured else None, left_share=share(LEFT) if measured else None,
        unreached=int(counts[UNREACHED]), unreached_share=share(UNREACHED),
        not_covered=int(counts[NOT_COVERED]), not_covered_share=share(NOT_COVERED),
        target_coverage=float(target_coverage),
        machining_time_s=round(float(verification.machining_time_s), 1) if sim else round(total, 1),
        time_source=source, areas=areas)


def headline(f: PlanFigures) -> str:
    """The plan message's first clause: the finished share against the target, and why the rest is not."""
    if not f.measured or f.finished_share is None:
        return ""
    rest = []
    if f.left:
        rest.append(f"{f.left_share:.1%} reached but not within tolerance")
    if f.unreached:
        rest.append(f"{f.unreached_share:.1%} reached by no kept finishing move")
    if f.not_covered:
        rest.append(f"{f.not_covered_share:.1%} seen by no chosen set-up")
    return (f"{f.finished_share:.1%} of the scan finished within tolerance (target {f.target_coverage:.0%})"
            + (f"; {', '.join(rest)}" if rest else ""))


def finishing_limit_mm(config, verification) -> float | None:
    """The finished-within-tolerance limit the verification used (mm), or None when it measured nothing."""
    if verification is None or verification.deviation is None or verification.measuring_bound_mm is None:
        return None
    fp = config.paths.finishing
    return float(fp.tolerance_mm + fp.scallop_mm + verification.measuring_bound_mm)


def apply_figures(result, *, input_labels: np.ndarray, not_covered: np.ndarray, unreached: np.ndarray,
                  deviation_mm: np.ndarray | None, config) -> np.ndarray:
    """Fill ``result.figures`` (a :class:`schemas.plan.PlanResult`), and let the plan's status and message
    speak for the part: a planned plan whose simulated programs finish less than ``setups.coverage`` of
    the scan becomes 'unfinished'; the message leads with the finished share (:func:`headline`).
    Returns the (N,) point classes (:func:`point_classes`), for the pictures."""
    v = result.verification
    limit = finishing_limit_mm(config, v)
    measured = deviation_mm is not None and limit is not None
    n = int(input_labels.shape[0])
    classes = point_classes(n, deviation_mm=deviation_mm if measured else None, limit_mm=limit,
                            not_covered=not_covered, unreached=unreached)
    order = list(result.machining_order) or [s.id for s in result.setups]
    result.figures = plan_figures(n_points=n, input_labels=input_labels, order=order, classes=classes,
                                  measured=measured, target_coverage=config.setups.coverage, verification=v,
                                  setups=result.setups)
    f = result.figures
    head = headline(f)
    if not head:
        return classes
    if result.status == "planned" and f.finished_share < f.target_coverage:
        result.status = "unfinished"
        result.message = (f"only {head}: the programs finish less of the scan than setups.coverage; "
                          f"the set-ups: {result.message}")
    else:
        result.message = f"{head}; the set-ups: {result.message}"
    return classes
