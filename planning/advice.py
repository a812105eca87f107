"""Advice that was tried (issue 34 item 3): when no ``setups.max_setups`` set-ups reach ``setups.coverage``,
the planner tries the cheap changes itself before it advises one.

Each try changes one parameter and runs the visibility stage (tool cone, travel, fixtures, cloud
collisions: :func:`planning.pipeline._visibility`) and the set-up stage
(:func:`planning.pipeline._setups` on :func:`planning.pipeline.selection_matrix`) again, on the plan's
own sampled points and normals; the paths are not run. The order is fixed (:func:`candidate_changes`),
cheapest on the shop floor first, and the tries stop at the first change that reaches the coverage:

1. ``fixtures.fixture_height_mm`` raised to each of :data:`FIXTURE_HEIGHTS_MM` above the current one (a
   higher riser frees the holder from the table; only with ``fixtures.placement_mm`` null, where it
   places the part);
2. ``fixtures.placement = auto``: not searched again, the result of the as-scanned hint's placement
   search (:func:`planning.placement.stage.placement_hint`, the plan's ``placement`` block) is read;
3. ``setups.max_setups`` raised by each of :data:`MORE_SETUPS` (up to the schema's 12): only the set-up
   stage runs again, on the plan's visibility;
4. ``visibility.cone_deg`` widened to each of :data:`CONES_DEG` that contains the current cone;
5. ``tool.stickout_mm`` lengthened to each of :data:`STICKOUTS_MM` above the current one (the holder
   further from the part; with ``tool.gauge_length_mm`` null the gauge length follows).

A change is reported as reaching the coverage only when the set-up stage itself reached it with the
change ("optimal", or "feasible": a selection reaching it found within the time limit), so the
suggested command plans feasibly: it runs the same stages on the same points with the same
parameters. The tries share a wall-clock budget of :data:`ADVICE_BUDGET_S` seconds: no try starts
after it is spent, nor a try that runs the visibility stage when less is left than the plan's own
visibility stage took (a try started may still end after the budget; each selection's time limit is
capped to what is left); the changes not tried are listed, and the set-up-only tries (max_setups) still
run. The placement search is the hint's, run only when the tries come
to the placement (a riser that reaches the coverage spares it), its time outside the budget.

The command line: given the ``scanmill plan`` command that runs the plan (``run_plan(command_line=)``,
which the CLI passes), the suggested command is that command as given, with any ``--set`` of the same
parameter taken out and ``--set parameter=value`` added; without it (a service job, the Python API)
the message names the parameter to set.
"""

from __future__ import annotations

import json
import shlex
import time
from dataclasses import dataclass, replace

import numpy as np

from planning.errors import ParameterError
from schemas.params import PlanConfig, apply_overrides, parse_config
from schemas.plan import Advice, AdviceTry, PlacementSummary

__all__ = ["ADVICE_BUDGET_S", "CONES_DEG", "FIXTURE_HEIGHTS_MM", "MORE_SETUPS", "STICKOUTS_MM", "Change", "advise",
           "candidate_changes", "changed_config", "command_with", "try_changes"]

#: Wall-clock seconds all the tries of one plan may take together (no try starts after they are spent).
ADVICE_BUDGET_S = 30.0
#: Riser heights tried, mm (only those above the current ``fixtures.fixture_height_mm``).
FIXTURE_HEIGHTS_MM = (100.0, 150.0)
#: Set-ups added to ``setups.max_setups``, a count.
MORE_SETUPS = (1, 2)
#: Wider tool cones tried, degrees [v1, v2] (only those containing the current cone and differing from it).
CONES_DEG = ((10.0, 80.0), (5.0, 85.0))
#: Longer stick-outs tried, mm (only those above the current ``tool.stickout_mm``).
STICKOUTS_MM = (45.0, 60.0)

_OLD_ADVICE = ": change the part set-up or raise setups.max_setups"
_FEASIBLE = ("optimal", "feasible")


def _value_text(v) -> str:
    """The value as ``--set`` takes it (JSON, integral floats without '.0', strings bare)."""
    if isinstance(v, str):
        return v
    if isinstance(v, (list, tuple)):
        return "[" + ",".join(_value_text(x) for x in v) + "]"
    if isinstance(v, float) and v.is_integer():
        return str(int(v))
    return json.dumps(v)


@dataclass(frozen=True)
class Change:
    """One parameter change: ``parameter`` as ``--set`` names it, ``value`` in the parameter's unit."""

    parameter: str
    value: object

    @property
    def assignment(self) -> str:
        """The ``--set`` argument, ``parameter=value``."""
        return f"{self.parameter}={_value_text(self.value)}"

    def describe(self) -> str:
        return f"{self.parameter} = {_value_text(self.value)}"


def candidate_changes(config: PlanConfig) -> tuple[list[Change], list[str]]:
    """The changes to try, in the fixed order of the module docstring, for ``config``; and the changes of
    that order left out with why (``'parameter=value (why)'``)."""
    out: list[Change] = []
    left: list[str] = []
    fx = config.fixtures
    heights = [h for h in FIXTURE_HEIGHTS_MM if h > fx.fixture_height_mm]
    if fx.placement_mm is None:
        out += [Change("fixtures.fixture_height_mm", h) for h in heights]
    else:
        left += [f"{Change('fixtures.fixture_height_mm', h).assignment} (fixtures.placement_mm places the part)"
                 for h in heights]
    if fx.placement == "as_scanned":
        ch = Change("fixtures.placement", "auto")
        if fx.placement_mm is None:
            out.append(ch)
        else:
            left.append(f"{ch.assignment} (fixtures.placement_mm is set)")
    K = config.setups.max_setups
    out += [Change("setups.max_setups", K + d) for d in MORE_SETUPS if K + d <= 12]
    v1, v2 = config.visibility.cone_deg
    out += [Change("visibility.cone_deg", [float(a), float(b)]) for a, b in CONES_DEG
            if a <= v1 and b >= v2 and (a, b) != (v1, v2)]
    out += [Change("tool.stickout_mm", s) for s in STICKOUTS_MM if s > config.tool.stickout_mm]
    return out, left


def changed_config(config: PlanConfig, change: Change) -> PlanConfig:
    """``config`` with ``change`` applied the way ``--set`` applies it (validated: ParameterError if not)."""
    return parse_config(apply_overrides(config.to_json_dict(), [change.assignment]))


def command_with(argv: list[str], change: Change) -> list[str]:
    """``argv`` with every ``--set`` of ``change.parameter`` taken out and ``--set parameter=value`` added
    at the end (where it wins over the ``--config`` file and any other ``--set`` anyway)."""

    def same(item: str) -> bool:
        return item.split("=", 1)[0].strip() == change.parameter

    out, i = [], 0
    while i < len(argv):
        a = argv[i]
        if a == "--set" and i + 1 < len(argv):
            if not same(argv[i + 1]):
                out += [a, argv[i + 1]]
            i += 2
            continue
        if not (a.startswith("--set=") and same(a[len("--set="):])):
            out.append(a)
        i += 1
    return out + ["--set", change.assignment]


def _placement_try(change: Change, summary: PlacementSummary | None) -> AdviceTry | None:
    """The ``fixtures.placement = auto`` try read from the as-scanned hint's search (the plan's
    ``placement`` block); None when the hint searched nothing."""
    if summary is None or summary.mode != "as_scanned" or not summary.candidates:
        return None
    rows = summary.candidates
    base = {"parameter": change.parameter, "value": change.value, "assignment": change.assignment,
            "seconds": round(float(summary.seconds), 4)}
    if summary.candidate is not None:
        w = next(c for c in rows if c.index == summary.candidate)
        return AdviceTry(**base, feasible=True, coverage=w.coverage, k=w.k,
                         note=f"the placement search of the hint: {w.label}, {w.stage}")
    scored = [c for c in rows if c.coverage is not None]
    if not scored:
        bound = max((c.coverage_bound for c in rows if c.coverage_bound is not None), default=None)
        return AdviceTry(**base, feasible=False, coverage=bound, k=None,
                         note="the placement search of the hint: every placement proven short by the price bound "
                              "(coverage: the highest bound)")
    best = max(scored, key=lambda c: c.coverage)
    return AdviceTry(**base, feasible=False, coverage=best.coverage, k=best.k,
                     note=f"the placement search of the hint: best {best.label}, {best.stage}"
                          + (" (screened: an upper estimate)" if best.stage == "screened" else ""))


def try_changes(points: np.ndarray, nrm, ori, config: PlanConfig, profile, visible: np.ndarray, zmask: np.ndarray, *,
                placement: PlacementSummary | None = None, base_dir=None, budget_s: float = ADVICE_BUDGET_S,
                visibility_s: float = 0.0, progress=None, clock=time.perf_counter) -> Advice:
    """Try the changes of :func:`candidate_changes` in order on an infeasible plan and return what each
    reached (:class:`schemas.plan.Advice`, no message yet).

    ``points`` (N,3) mm and ``nrm`` (the pipeline's ``_Normals``: sampled indices and unit normals) are the
    placed cloud the plan ran on; ``ori`` its orientations; ``visible`` (n,m) bool its selection matrix
    (what the max_setups tries select on); ``zmask`` (n,) bool its functional zones; ``placement`` the
    plan's placement block after :func:`planning.placement.stage.placement_hint`, or a function that runs
    that search and returns it (called only when the tries reach the placement: a riser that reaches the
    coverage spares the search). ``budget_s`` seconds of
    wall time (``clock``) for the tries together; ``visibility_s``: what the plan's own visibility stage took,
    s, the expected cost of a try that runs it (such a try is not started when less of the budget is left;
    the set-up-only tries still run); ``progress(fraction, message)``. Coverages are fractions
    of the sampled points; seconds are wall time.
    """
    # the plan's own stage functions (imported here: the pipeline imports this module)
    from planning import pipeline as pl

    t0 = clock()
    say = progress or (lambda fraction, message="": None)
    changes, not_tried = candidate_changes(config)
    tries: list[AdviceTry] = []
    spent = False
    for i, ch in enumerate(changes):
        frac = i / max(len(changes), 1)
        if ch.parameter == "fixtures.placement":
            if callable(placement):
                # the placement hint's search, run only now that the changes before it did not reach the
                # coverage; its time is the hint's, outside the budget
                p0 = clock()
                placement = placement()
                t0 += clock() - p0
            t = _placement_try(ch, placement)
            if t is None:
                not_tried.append(f"{ch.assignment} (the placement hint did not search: too costly or the set-up "
                                 "search hit its time limit; try it yourself)")
                continue
            tries.append(t)
            say(frac, f"advice: {ch.describe()}: {'reaches' if t.feasible else 'does not reach'} the coverage")
            if t.feasible:
                break
            continue
        left = budget_s - (clock() - t0)
        need = 0.0 if ch.parameter == "setups.max_setups" else float(visibility_s)
        if left <= 0 or need > left:
            spent = True
            not_tried.append(f"{ch.assignment} (the {budget_s:g} s budget " + (
                "was spent)" if left <= 0 else f"had {left:.0f} s left; a visibility stage takes about {need:.0f} s)"))
            continue
        try:
            cfg = changed_config(config, ch)
        except ParameterError as exc:
            not_tried.append(f"{ch.assignment} (not valid here: {exc.message})")
            continue
        cfg = cfg.model_copy(update={"setups": cfg.setups.model_copy(update={
            "time_limit_s": float(min(cfg.setups.time_limit_s, max(left, 1.0)))})})
        say(frac, f"advice: trying {ch.describe()} ({i + 1} of {len(changes)})")
        c0 = clock()
        if ch.parameter == "setups.max_setups":
            vis = visible
        else:
            sub = (lambda f, m="", at=frac: say(at + f / max(len(changes), 1), m)) if progress else None
            _, gv = pl._visibility(points, nrm, ori, cfg, cfg.tool.assembly(), profile, base_dir, sub)
            vis = pl.selection_matrix(gv.visible, ori.axes, nrm.normals, cfg, along=gv.along)
        sel = pl._setups(vis, zmask, cfg, None)
        feasible = sel.status in _FEASIBLE
        note = "the selection's time limit (capped to the budget left) ran out" if sel.status == "unknown" else ""
        tries.append(AdviceTry(parameter=ch.parameter, value=ch.value, assignment=ch.assignment, feasible=feasible,
                               coverage=float(sel.coverage), k=int(sel.k), seconds=round(clock() - c0, 4), note=note))
        if feasible:
            break
    chosen = next((j for j, t in enumerate(tries) if t.feasible), None)
    closest = None
    if chosen is None and tries:
        cov = [-1.0 if t.coverage is None else t.coverage for t in tries]
        closest = int(np.argmax(cov))
    say(1.0, "advice: done")
    return Advice(target_coverage=float(config.setups.coverage), budget_s=float(budget_s),
                  seconds=round(clock() - t0, 4), tries=tries, not_tried=not_tried, budget_spent=spent,
                  chosen=chosen, closest=closest)


def _pct(x: float | None) -> str:
    return "?" if x is None else f"{x * 100:.1f} %"


def _cover(k: int) -> str:
    return f"{k} set-up covers" if k == 1 else f"{k} set-ups cover"


def _sentence(advice: Advice, command: list[str] | None) -> str:
    """The words the plan's message gets for ``advice`` (empty when nothing was tried)."""
    if not advice.tries:
        return (f"; the {advice.budget_s:g} s for trying changes ran out before any was tried"
                if advice.budget_spent else "")
    spent = ""
    if advice.budget_spent:
        spent = f" (the {advice.budget_s:g} s for trying ran out before " + ", ".join(
            x.split(" (", 1)[0] for x in advice.not_tried if "budget" in x) + ")"
    n = len(advice.tries)
    target = f"{advice.target_coverage * 100:g} %"
    tried = f"tried {n} change{'s' if n != 1 else ''} on the visibility and set-up stages"
    if advice.chosen is not None:
        t = advice.tries[advice.chosen]
        ch = Change(t.parameter, t.value)
        # a placement try reaches the coverage only where the hint's search found a winner, which the
        # message names at its end
        figures = ("the placement named at the end" if t.parameter == "fixtures.placement"
                   else f"{_cover(t.k)} {_pct(t.coverage)}")
        how = (f"run `{shlex.join(command)}`" if command is not None
               else f"set {ch.describe()} (command line: --set {ch.assignment})")
        return f"; {tried}{spent}: the first that reaches {target} is {ch.describe()} ({figures}): {how}"
    c = advice.tries[advice.closest]
    closest = (f"the closest is {Change(c.parameter, c.value).describe()}, "
               + (f"{_cover(c.k)} " if c.k is not None else "at most ")
               + _pct(c.coverage))
    return (f"; {tried}{spent} and none reaches {target} ({closest}): combine changes (plan.json advice) or "
            "change the part set-up")


def advise(run, sel, *, points: np.ndarray, nrm, ori, config: PlanConfig, profile, visible: np.ndarray,
           zmask: np.ndarray, placement, base_dir=None, command_line=None,
           budget_s: float | None = None):
    """An infeasible plan's advice, tried (module docstring): returns ``(advice, sel)``.

    ``sel`` (:class:`planning.setups.SetupSelection`) comes back with its message telling the first change
    that reaches ``setups.coverage``, its value and the command line (or the parameter to set), or the
    closest try; the old words "change the part set-up or raise setups.max_setups" stay only when nothing
    was tried. The plan's warning that repeated the selection's message is replaced the same way. Runs as
    the timed stage "setups" (again) of ``run`` (the pipeline's ``_Run``). ``advice`` is None (and ``sel``
    unchanged) when ``sel`` is not proven infeasible. Arguments as :func:`try_changes`; coverages are
    fractions of the sampled points, times wall seconds; ``budget_s`` None: :data:`ADVICE_BUDGET_S` (read at
    the call).
    """
    if sel.status != "infeasible":
        return None, sel
    budget_s = ADVICE_BUDGET_S if budget_s is None else float(budget_s)
    visibility_s = next((t.seconds for t in reversed(run.timings) if t.stage == "visibility"), 0.0)
    advice = run.stage("setups", lambda p: try_changes(
        points, nrm, ori, config, profile, visible, zmask, placement=placement, base_dir=base_dir,
        budget_s=budget_s, visibility_s=visibility_s, progress=p))
    command = None
    if advice.chosen is not None and command_line:
        command = command_with([str(a) for a in command_line], Change(advice.tries[advice.chosen].parameter,
                                                                     advice.tries[advice.chosen].value))
    words = _sentence(advice, command)
    advice = advice.model_copy(update={"command": None if command is None else shlex.join(command),
                                       "message": words[2:]})
    if not words:
        return advice, sel
    old = sel.message
    message = (old.replace(_OLD_ADVICE, "", 1) if advice.tries else old) + words
    run.warnings[:] = [message if w == old else w for w in run.warnings]
    return advice, replace(sel, message=message)
