"""The machining summary of a plan, the same lines for ``scanmill plan`` and the ``make run`` demo.

:func:`summary_lines` reads a plan.json document (a dict, as ``PlanResult.model_dump(mode="json")``
or the service's ``GET /jobs/{id}/result`` gives it) and returns the lines to print, every figure from
plan.json ``figures`` (computed once by the planner, planning/report/figures.py): one row per area in
machining order (roughing, finishing and total minutes; finished, left, unreached and not-covered input
points), the machining time (h:mm, and whether simulated or estimated), the verification verdict with
its message, and the shares of the whole scan. A plan.json without ``figures`` is summarised from its
other fields, labelled as estimates. Standard library only, so an HTTP client can use it.
"""

from __future__ import annotations

__all__ = ["format_summary", "summary_lines"]


def _get(d, *keys, default=None):
    """d[k0][k1]... or ``default`` where a level is missing or null."""
    for k in keys:
        if not isinstance(d, dict):
            return default
        d = d.get(k)
        if d is None:
            return default
    return d


def _minutes(seconds: float | None) -> str:
    return "-" if seconds is None else f"{seconds / 60.0:.1f}"


def _hmm(seconds: float) -> str:
    m = round(seconds / 60.0)
    return f"{m // 60}:{m % 60:02d}"


def _ordered_setups(plan: dict) -> list[dict]:
    """The set-ups in ``machining_order`` (area ids), those it leaves out after them in plan order."""
    setups = [s for s in plan.get("setups") or [] if isinstance(s, dict)]
    by_id = {s.get("id", i): s for i, s in enumerate(setups)}
    order = plan.get("machining_order") or []
    out, seen = [], set()
    for a in order:
        if a in by_id and a not in seen:
            out.append(by_id[a])
            seen.add(a)
    out += [s for i, s in enumerate(setups) if s.get("id", i) not in seen]
    return out


def _table(head: list[str], rows: list[list[str]]) -> list[str]:
    """The header and the rows, indented two spaces, the first column left-aligned, the others right."""
    widths = [max(len(r[c]) for r in [head] + rows) for c in range(len(head))]
    return ["  " + "  ".join(v.rjust(w) if c else v.ljust(w) for c, (v, w) in enumerate(zip(r, widths)))
            for r in [head] + rows]


def _count(v) -> str:
    return "-" if v is None else f"{int(v):,}"


def summary_lines(plan: dict) -> list[str]:
    """The machining summary of the plan.json document ``plan``, one string per line.

    With plan.json ``figures`` (the plan's figures, computed once: planning/report/figures.py): one row per
    area in machining order with its roughing, finishing and total minutes (simulated, or the paths'
    estimate when the programs were not simulated: the header says which) and its input points by what
    became of them (finished, left, unreached, not covered); then ``machining time H:MM``, per area and
    tool what the simulated machine does (``verification.areas[].operations``), ``verification: STATUS -
    message``, and one line with the shares of the whole scan. Without ``figures`` (a plan.json of an
    older scanmill) the rows come from the paths' estimates and ``unmachined``, as that version printed.
    """
    f = plan.get("figures") if isinstance(plan.get("figures"), dict) else None
    if f is None:
        return _legacy_lines(plan)
    source = f.get("time_source", "none")
    # a semi-finishing column only where a plan has one (paths.semi_finishing)
    semi = any(a.get("semi_finishing_time_s") is not None for a in f.get("areas") or [])
    head = ["area", "roughing min"] + (["semi min"] if semi else []) + [
        "finishing min", "total min", "finished", "left", "unreached", "not covered"]
    rows = []
    for a in f.get("areas") or []:
        rows.append([str(a.get("area")), _minutes(a.get("roughing_time_s"))]
                    + ([_minutes(a.get("semi_finishing_time_s"))] if semi else [])
                    + [_minutes(a.get("finishing_time_s")), _minutes(a.get("machining_time_s")),
                       _count(a.get("finished")), _count(a.get("left")), _count(a.get("unreached")),
                       _count(a.get("not_covered"))])
    what = {"simulated": "simulated: the programs as the control runs them",
            "estimate": "ESTIMATE from the tool paths: the programs were not simulated"}.get(source, "no paths")
    lines = [f"machining summary (areas in machining order; minutes {what}; points: input points):"]
    lines += _table(head, rows)
    t = f.get("machining_time_s") or 0.0
    lines.append(f"machining time {_hmm(t)} ({t / 60.0:.1f} min, {source})")
    v = plan.get("verification") if isinstance(plan.get("verification"), dict) else None
    lines += _operation_lines(v, _bound_deg(plan))
    lines += _verdict_lines(v)
    lines.append(figures_line(f))
    return lines


def figures_line(f: dict) -> str:
    """One line: the shares of the scan's input points by class (plan.json ``figures``)."""
    n = f.get("n_points") or 0
    parts = []
    if f.get("measured"):
        parts.append(f"finished within tolerance {f.get('finished_share', 0.0):.1%}")
        parts.append(f"reached but not within tolerance {f.get('left_share', 0.0):.1%}")
    parts.append(f"reached by no kept finishing move {f.get('unreached_share', 0.0):.1%}")
    parts.append(f"seen by no chosen set-up {f.get('not_covered_share', 0.0):.1%}")
    target = f.get("target_coverage")
    return (f"scan ({int(n):,} input points): " + ", ".join(parts)
            + (f"; target {target:.0%}" if target is not None else "")
            + ("" if f.get("measured") else " (not simulated: the finish was not measured)"))


def _verdict_lines(v: dict | None) -> list[str]:
    if v is None:
        return ["verification: not run"]
    status = v.get("status")
    message = (v.get("message") or "").strip()
    if status == "failed" and "; " in message:
        return ["verification: FAILED"] + [f"  - {part}" for part in message.split("; ")]
    return [f"verification: {str(status).upper()}" + (f" - {message}" if message else "")]


def _legacy_lines(plan: dict) -> list[str]:
    """The summary of a plan.json without ``figures`` (scanmill before issue 34)."""
    setups = _ordered_setups(plan)
    per_area = _get(plan, "unmachined", "per_area")
    per_area = {str(k): v for k, v in per_area.items()} if isinstance(per_area, dict) else None

    def unfinished(s, i):
        if per_area is not None:
            return per_area.get(str(s.get("id", i)), 0)
        return _get(s, "path", "finishing", "unmachined_points")

    show_left = per_area is not None or any(unfinished(s, i) is not None for i, s in enumerate(setups))
    head = ["area", "roughing min", "finishing min", "total min"] + (["unreached pts"] if show_left else [])
    rows, total_s = [], 0.0
    for i, s in enumerate(setups):
        rough = _get(s, "path", "roughing", "machining_time_s")
        fin = _get(s, "path", "finishing", "machining_time_s")
        both = None if rough is None and fin is None else (rough or 0.0) + (fin or 0.0)
        total_s += both or 0.0
        row = [str(s.get("id", i)), _minutes(rough), _minutes(fin), _minutes(both)]
        if show_left:
            left = unfinished(s, i)
            row.append("-" if left is None else f"{int(left):,}")
        rows.append(row)
    lines = ["machining summary (areas in machining order; minutes: estimate from the tool paths):"]
    lines += _table(head, rows)
    v = plan.get("verification") if isinstance(plan.get("verification"), dict) else None
    lines.append(f"machining time (estimate) {_hmm(total_s)} ({total_s / 60.0:.1f} min)")
    lines += _operation_lines(v, _bound_deg(plan))
    lines += _verdict_lines(v)
    un = plan.get("unmachined") if isinstance(plan.get("unmachined"), dict) else None
    finished = _get(v or {}, "deviation", "finished_share")
    if un is not None and un.get("share") is not None:
        n = un.get("n_points")
        lines.append(f"unreached: {un['share']:.1%} of the scan points"
                     + (f" ({int(n):,})" if n is not None else "") + " reached by no kept finishing move")
    if finished is not None:
        lines.append(f"finished within tolerance: {finished:.1%} of the scan points (simulation)")
    exact = _get(v or {}, "finish", "finished_share")
    if exact is not None:
        lines.append(f"finished, measured exactly from the finishing moves: {exact:.1%} of the scan points within "
                     f"{_get(v, 'finish', 'limit_mm')} mm (scallop p95 {_get(v, 'finish', 'scallop_p95_mm')} mm)")
    return lines


def _bound_deg(plan: dict):
    """``paths.roughing.max_engagement_deg`` of the plan's parameters, or None."""
    p = plan.get("parameters")
    r = (p.get("paths") or {}).get("roughing") if isinstance(p, dict) else None
    return r.get("max_engagement_deg") if isinstance(r, dict) else None


def _operation_lines(v: dict | None, bound_deg=None) -> list[str]:
    """Per area (machining order) and tool, what the simulated machine does: feed length and its share in
    air, straight plunges into material, volume removed, time (``verification.areas[].operations``)."""
    areas = [a for a in (v or {}).get("areas") or [] if isinstance(a, dict) and a.get("operations")]
    if not areas:
        return []
    out = ["simulated per operation (feed in air: moves that removed no material):"]
    for a in areas:
        for op in a["operations"]:
            plunges = op.get("plunges_into_material") or 0
            out.append(f"  area {a.get('area')} {op.get('operation', '?'):9s} T{op.get('tool')}: feed "
                       f"{(op.get('feed_mm') or 0) / 1000:.1f} m, {op.get('air_share') or 0:.0%} in air"
                       + (f", {plunges} straight plunges into material" if plunges else "")
                       + (f", engagement up to {op['engagement_max_deg']:.0f} deg (p95 {op.get('engagement_p95_deg') or 0:.0f}), "
                          f"{op.get('over_engagement_moves') or 0} moves over "
                          + (f"{bound_deg:g} deg" if bound_deg is not None else "the bound")
                          if op.get("engagement_max_deg") is not None else "")
                       + f", removed {(op.get('removed_mm3') or 0) / 1000:.1f} cm3, "
                       f"{_minutes(op.get('machining_time_s'))} min")
    return out


def format_summary(plan: dict) -> str:
    """:func:`summary_lines` joined by newlines."""
    return "\n".join(summary_lines(plan))
