"""The machining summary of a plan, the same lines for ``scanmill plan`` and the ``make run`` demo.

:func:`summary_lines` reads a plan.json document (a dict, as ``PlanResult.model_dump(mode="json")``
or the service's ``GET /jobs/{id}/result`` gives it) and returns the lines to print: one row per
area in machining order (roughing, finishing and total minutes), the total machining time (h:mm),
the verification verdict with its message, and the share of the scan left unmachined. Fields a
plan may lack (``machining_order``, ``unmachined``, ``path.finishing.unmachined_points``; any path,
roughing or finishing that was not computed) are read with a default. Standard library only, so an
HTTP client can use it.
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


def summary_lines(plan: dict) -> list[str]:
    """The machining summary of the plan.json document ``plan``, one string per line.

    Rows: area, roughing and finishing machining time (min, one decimal; ``-`` when that path was
    not computed), their total, and the points left unfinished by the area's finishing when the plan
    reports them (``unmachined.per_area``, else ``path.finishing.unmachined_points``). Then
    ``total machining time H:MM`` (the sum of the rows; the simulated time too when the programs
    were simulated), per area and tool what the simulated machine does (feed length, its share in air,
    plunges, volume removed, minutes; when the plan has ``verification.areas[].operations``), ``verification: STATUS - message`` (a failed verdict lists its offences one
    per line), and the unmachined share: ``unmachined.share`` when the plan has it, else
    1 - ``verification.deviation.finished_share`` (not finished within tolerance, simulation).
    """
    setups = _ordered_setups(plan)
    per_area = _get(plan, "unmachined", "per_area")
    per_area = {str(k): v for k, v in per_area.items()} if isinstance(per_area, dict) else None

    def unfinished(s, i):
        """Points of the area no kept finishing move reaches: plan-level ``unmachined.per_area`` (areas
        absent there have none), else the set-up's ``path.finishing.unmachined_points``, else None."""
        if per_area is not None:
            return per_area.get(str(s.get("id", i)), 0)
        return _get(s, "path", "finishing", "unmachined_points")

    show_left = per_area is not None or any(unfinished(s, i) is not None for i, s in enumerate(setups))
    head = ["area", "roughing min", "finishing min", "total min"] + (["unfinished pts"] if show_left else [])
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
    widths = [max(len(r[c]) for r in [head] + rows) for c in range(len(head))]
    lines = ["machining summary (areas in machining order):"]
    lines.append("  " + "  ".join(h.rjust(w) if c else h.ljust(w) for c, (h, w) in enumerate(zip(head, widths))))
    for r in rows:
        lines.append("  " + "  ".join(v.rjust(w) if c else v.ljust(w) for c, (v, w) in enumerate(zip(r, widths))))

    v = plan.get("verification") if isinstance(plan.get("verification"), dict) else None
    status = (v or {}).get("status")
    total = f"total machining time {_hmm(total_s)} ({total_s / 60.0:.1f} min)"
    sim_s = (v or {}).get("machining_time_s")
    if status in ("passed", "failed") and sim_s:
        total += f"; simulated {_hmm(sim_s)}"
    lines.append(total)
    lines += _operation_lines(v)

    if v is None:
        lines.append("verification: not run")
    else:
        message = (v.get("message") or "").strip()
        if status == "failed" and "; " in message:
            lines.append("verification: FAILED")
            lines += [f"  - {part}" for part in message.split("; ")]
        else:
            lines.append(f"verification: {str(status).upper()}" + (f" - {message}" if message else ""))

    un = plan.get("unmachined") if isinstance(plan.get("unmachined"), dict) else None
    finished = _get(v or {}, "deviation", "finished_share")
    if un is not None and un.get("share") is not None:
        n = un.get("n_points")
        lines.append(f"unmachined: {un['share']:.1%} of the scan points"
                     + (f" ({int(n):,})" if n is not None else "") + " reached by no kept finishing move")
    elif finished is not None:
        lines.append(f"unmachined: {1.0 - finished:.1%} of the scan points not finished within tolerance "
                     f"(simulation)")
    else:
        lines.append("unmachined: unknown (no finishing coverage in the plan and no simulation)")
    return lines


def _operation_lines(v: dict | None) -> list[str]:
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
                       + f", removed {(op.get('removed_mm3') or 0) / 1000:.1f} cm3, "
                       f"{_minutes(op.get('machining_time_s'))} min")
    return out


def format_summary(plan: dict) -> str:
    """:func:`summary_lines` joined by newlines."""
    return "\n".join(summary_lines(plan))
