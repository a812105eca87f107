"""Set-up selection, the answer: :class:`SetupSelection` and the message a person reads.

Stage 5 (set-ups) of the pipeline, Makki et al. 2010 §3.1.  Every solver of :mod:`planning.setups`
(:func:`planning.setups.select_setups` and the reference :func:`planning.setups.brute_force_setups`)
ends in :func:`_make_result`: original axis indices, covered and overlap point counts, the status with
its proof (gap, lower bound) and one message line.  It lives apart from :mod:`planning.setups.select`
because the brute force builds the same answer and ``select_setups`` calls the brute force.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SetupSelection:
    """The chosen set-ups (tool axes) and what they achieve.

    ``status`` is ``"optimal"`` (the order of Makki §3 with the tie rules of
    :mod:`planning.setups.select` is proven), ``"feasible"`` (the time limit was hit; ``selected``
    reaches the coverage and ``gap`` bounds its distance to the optimal overlap; ``lower_bound`` is
    ``None`` where not even ``k`` was proven minimal), ``"infeasible"`` (proven: no
    ``k <= max_setups`` reaches the coverage; ``selected`` is the best-coverage subset) or
    ``"unknown"`` (the time limit was hit before a subset reaching the coverage was found and before
    infeasibility was proven; ``selected`` is the best found).  Counts are points; ``coverage`` and
    ``gap`` are fractions; ``selected`` holds column indices of the visibility matrix.
    """

    status: str
    selected: np.ndarray
    k: int
    n_points: int
    covered: int
    coverage: float
    overlap: int
    required_covered: int
    lower_bound: int | None
    gap: float | None
    best_coverage_at_max: float | None
    solver: str
    n_classes: int
    n_axes_kept: int
    seconds: float
    message: str


def _setups(k: int) -> str:
    """'1 set-up covers' / '3 set-ups cover'."""
    return f"{k} set-up covers" if k == 1 else f"{k} set-ups cover"


def _make_result(*, status, sel_orig, covered, overlap, n, required, K, coverage_target, lower_bound,
                 solver, n_classes, n_axes_kept, seconds, note="", min_points=1) -> SetupSelection:
    sel_orig = np.array(sorted(int(s) for s in sel_orig), dtype=np.int64)
    k = int(sel_orig.size)
    frac = covered / n
    target = f"{coverage_target * 100:g}"
    gap = None
    best_at_max = None
    head = f"{_setups(k)} {frac * 100:.1f} % with {overlap} overlap points"
    if status == "optimal":
        gap = 0.0
        lower_bound = overlap
        msg = f"{head} (proven optimal)"
    elif status == "feasible":
        note = note or "time limit reached"
        if lower_bound is not None:
            gap = (overlap - lower_bound) / max(overlap, 1)
            msg = (f"{head} ({note}; best found: at least {lower_bound} overlap points are "
                   f"unavoidable, gap {gap * 100:.1f} %)")
        else:
            msg = f"{head} ({note}; not proven)"
    elif status == "infeasible":
        lower_bound = None
        best_at_max = frac
        if n_axes_kept == 0:
            msg = (f"no tool axis sees at least {min_points} points, so no set-up reaches {target} % "
                   f"coverage: change the part set-up or lower setups.min_points")
        else:
            none = "no single set-up reaches" if K == 1 else f"no {K} set-ups reach"
            msg = (f"{none} {target} % coverage; the best {_setups(k)} {frac * 100:.1f} %: "
                   f"change the part set-up or raise setups.max_setups")
            if note:
                msg += f" ({note})"
    else:  # unknown
        lower_bound = None
        msg = (f"time limit reached before {target} % coverage was reached or proven unreachable; "
               f"the best found, {_setups(k)} {frac * 100:.1f} %: raise the time limit")
    return SetupSelection(
        status=status, selected=sel_orig, k=k, n_points=n, covered=int(covered), coverage=frac,
        overlap=int(overlap), required_covered=int(required), lower_bound=lower_bound, gap=gap,
        best_coverage_at_max=best_at_max, solver=solver, n_classes=int(n_classes),
        n_axes_kept=int(n_axes_kept), seconds=float(seconds), message=msg,
    )
