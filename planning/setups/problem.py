"""Set-up selection, the problem: validated inputs, the reduced instance, the order of answers.

Stage 5 (set-ups) of the pipeline, Makki et al. 2010 §3.1: the "reduced visibility matrix".  Axes that
see fewer than ``min_points`` points are dropped; the points are merged into weighted classes of
identical visibility rows (zone membership is part of the class key; a class's weight is its number of
points), and identical columns are collapsed to their lowest index.  Every solver of
:mod:`planning.setups` works on this :class:`_Problem`, in reduced axis indices; ``axes`` maps them back
to the columns of the visibility matrix.

Also here: the required number of covered points (``ceil(P_a * n)``, exact), the keys of the total order
of :mod:`planning.setups.select` (``_key_overlap``, ``_key_cover``) and what a solver hands back
(:class:`_Outcome`).
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

from planning.errors import ParameterError


def _is_int(x) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))


def _validate(visibility, coverage, max_setups, min_points, zone_mask):
    """Checked inputs: (V as C-contiguous bool, coverage, max_setups, min_points, zone mask or None
    when it flags no point, required covered points = ceil(coverage * n), exactly)."""
    try:
        V = np.asarray(visibility)
    except Exception as exc:  # pragma: no cover - exotic inputs
        raise ParameterError(
            f"visibility must be a 2-D boolean array (points x axes): {exc}", parameter="visibility"
        ) from None
    if V.ndim != 2:
        raise ParameterError(
            f"visibility must be a 2-D boolean array (points x axes), got {V.ndim} dimension(s)",
            parameter="visibility", value=list(V.shape), allowed="shape (n_points, n_axes)",
        )
    if V.shape[0] < 1 or V.shape[1] < 1:
        raise ParameterError(
            f"visibility must have at least one point and one axis, got shape {V.shape}",
            parameter="visibility", value=list(V.shape), allowed="n_points >= 1, n_axes >= 1",
        )
    if V.dtype != bool and (V.dtype.kind not in "iuf" or not np.all((V == 0) | (V == 1))):
        raise ParameterError(
            "visibility must hold booleans (or only 0 and 1)",
            parameter="visibility", value=str(V.dtype), allowed="bool",
        )
    V = np.ascontiguousarray(V, dtype=bool)
    n = V.shape[0]

    if isinstance(coverage, (bool, np.bool_)) or not isinstance(
        coverage, (int, float, np.integer, np.floating)
    ):
        raise ParameterError(
            f"setups.coverage must be a number in (0, 1], got {coverage!r}",
            parameter="coverage", value=repr(coverage), allowed="(0, 1]",
        )
    cov = float(coverage)
    if not math.isfinite(cov) or not 0.0 < cov <= 1.0:
        raise ParameterError(
            f"setups.coverage must be in (0, 1] (a fraction of the points, e.g. 0.95), got {coverage!r}",
            parameter="coverage", value=cov, allowed="(0, 1]",
        )
    if not _is_int(max_setups) or max_setups < 1:
        raise ParameterError(
            f"setups.max_setups must be an integer >= 1, got {max_setups!r}",
            parameter="max_setups", value=repr(max_setups), allowed=">= 1",
        )
    if not _is_int(min_points) or min_points < 1:
        raise ParameterError(
            f"setups.min_points must be an integer >= 1, got {min_points!r}",
            parameter="min_points", value=repr(min_points), allowed=">= 1",
        )
    zone = None
    if zone_mask is not None:
        Z = np.asarray(zone_mask)
        if Z.shape != (n,):
            raise ParameterError(
                f"zone_mask must be a boolean array of shape ({n},) (one flag per point), "
                f"got shape {Z.shape}",
                parameter="zone_mask", value=list(Z.shape), allowed=f"shape ({n},)",
            )
        if Z.dtype != bool and (Z.dtype.kind not in "iu" or not np.all((Z == 0) | (Z == 1))):
            raise ParameterError(
                "zone_mask must hold booleans (or only 0 and 1)",
                parameter="zone_mask", value=str(Z.dtype), allowed="bool",
            )
        zone = np.ascontiguousarray(Z, dtype=bool)
        if not zone.any():
            zone = None
    required = math.ceil(Fraction(repr(cov)) * n)  # exact: 0.95 * 20 -> 19, 0.95 * 2537 -> 2411
    required = max(1, min(n, required))
    return V, cov, int(max_setups), int(min_points), zone, required


def _unique_rows(B: np.ndarray):
    """Unique rows of a 2-D bool array: (first index of each class, counts), by packed bytes."""
    packed = np.ascontiguousarray(np.packbits(B, axis=1))
    if packed.shape[1] == 0:  # pragma: no cover - no columns
        return np.zeros(1, np.int64), np.array([B.shape[0]])
    keys = packed.view(np.dtype((np.void, packed.shape[1]))).ravel()
    _, first, counts = np.unique(keys, return_index=True, return_counts=True)
    return first.astype(np.int64), counts.astype(np.int64)


def _wgram_t(Y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """:func:`_wgram` of ``X = Y^T`` (axes x classes): ``Y diag(w) Y^T``, as float64."""
    return ((Y * w[None, :]) @ Y.T).astype(np.float64)


def _wgram(X: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted Gram matrix ``X^T diag(w) X`` (classes x axes -> axes x axes), as float64: entry
    (a, b) is the weight of the classes both axes a and b see."""
    return ((X * w[:, None]).T @ X).astype(np.float64)


class _Problem:
    """The reduced instance: weighted classes x distinct kept axes (Makki §3.1 reduced matrix)."""

    def __init__(self, V: np.ndarray, zone: np.ndarray | None, min_points: int, required: int):
        n = V.shape[0]
        self.n = n
        self.required = required
        counts = V.sum(axis=0)
        kept = np.flatnonzero(counts >= min_points)
        self.n_axes_kept = int(kept.size)
        Vk = V[:, kept]
        key = Vk if zone is None else np.concatenate([Vk, zone[:, None]], axis=1)
        if kept.size:
            first, w = _unique_rows(key)
        else:
            first, w = np.zeros(0, np.int64), np.zeros(0, np.int64)
        A = Vk[first]
        zc = zone[first] if zone is not None else np.zeros(first.size, bool)
        seen = A.any(axis=1) if kept.size else np.zeros(first.size, bool)
        A, w, zc = A[seen], w[seen], zc[seen]
        # identical columns: keep the lowest index (it wins the lexicographic tie, and a minimal-k
        # solution never holds two identical columns)
        if kept.size and A.shape[0]:
            colfirst, _ = _unique_rows(np.ascontiguousarray(A.T))
            cols = np.sort(colfirst)
        else:
            cols = np.zeros(0, np.int64)
        A = np.ascontiguousarray(A[:, cols])
        self.axes = kept[cols].astype(np.int64)  # original column index of each reduced axis
        self.A = A  # (C, m) bool
        self.AT = np.ascontiguousarray(A.T)  # (m, C) bool
        self.w = w.astype(np.int64)
        self.zone = zc
        self.C, self.m = A.shape
        self.ftype = np.float32 if n < 2**24 else np.float64  # integer sums stay exact
        self.Af = A.astype(self.ftype)
        # axes x classes, row-major: a node of the search gathers its few candidate axes over the
        # classes it changes (a few rows, then those columns) instead of copying whole class rows
        self.ATf = np.ascontiguousarray(self.Af.T)
        self.wf = self.w.astype(self.ftype)
        self.sizes = (self.wf @ self.Af).astype(np.float64) if self.m else np.zeros(0)
        if self.m:
            self.gram = _wgram(self.Af, self.wf)
        else:
            self.gram = np.zeros((0, 0))
        # zone conflicts: two axes that both see a zone class may not be chosen together
        if zc.any() and self.m:
            Az = A[zc].astype(np.float32)
            self.conflict = (Az.T @ Az) > 0
            np.fill_diagonal(self.conflict, False)
        else:
            self.conflict = np.zeros((self.m, self.m), bool)
        self.has_conflicts = bool(self.conflict.any())

    # -- evaluation ----------------------------------------------------------------------------
    def evaluate(self, sel) -> tuple[int, int]:
        """(covered, overlap) of reduced axes ``sel``."""
        sel = list(sel)
        if not sel:
            return 0, 0
        deg = self.AT[sel].sum(axis=0)
        return int(self.w[deg >= 1].sum()), int(self.w[deg >= 2].sum())

    def tuple_of(self, sel) -> tuple[int, ...]:
        return tuple(sorted(int(self.axes[s]) for s in sel))


# --------------------------------------------------------------------------------------------
# keys (the total order of planning.setups.select)
# --------------------------------------------------------------------------------------------


def _key_overlap(ov, cov, tup):
    return (ov, -cov, tup)


def _key_cover(ov, cov, tup):
    return (-cov, ov, tup)


# --------------------------------------------------------------------------------------------
# what a solver hands back
# --------------------------------------------------------------------------------------------


class _Outcome:
    """What a solver found, in reduced axis indices (converted to a SetupSelection at the end)."""

    def __init__(self, status, sel, lower_bound=None, note=""):
        self.status = status
        self.sel = list(sel)
        self.lower_bound = lower_bound
        self.note = note
