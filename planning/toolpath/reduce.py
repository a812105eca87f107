"""Fewer moves for the same cut: CL-point reduction (Sood 2015 §4.4) and circular arcs (G2/G3, the
arcs Chui 2008 joins CL points with), both bounded by a tolerance and gouge safe (issue 5: "after
every transformation, no CL point and no interpolated segment comes closer than R - tol to any
cloud point").

Sood §4.4 drops CL points whose height stays within epsilon of a reference point and does not
check gouging (docs/design.md "Papers": a straight move can then pass up to ~2 eps off a dropped point).
Here, within each run of consecutive FEED moves (module :mod:`planning.toolpath.moves`; a run is
the moves of one ``use``, by default the cutting moves, and of one pass where ``pass_index`` is
given), greedily from the run's start (anchor i), the next kept point j is the farthest one found
such that

* every dropped CL point (i < k < j) lies within ``tol_mm`` (3-D distance) of the replacing move:
  the path never passes farther than tol from (in particular never lower than tol below) a
  dropped ball-drop position; with the original path's points all within tol, the straight move
  and the polyline it replaces are within tol of each other everywhere;
* the replacing move keeps clearance >= R - tol from every cloud point (the exact check of
  :mod:`planning.toolpath.verify`); where it does not, a nearer end is taken: a dropped point that
  holds the tool off the cloud is kept.

The farthest feasible j is searched by doubling then bisection (O(L log L) per run of L points; a
chord found this way is checked in full, so it is always valid, though on a strongly non-monotone
run a farther one may exist), then backed off one point at a time (up to 8) and then by halves
until the move clears. A single original move is always kept as it was: the reduction never makes
a path worse than its input, and what the input already gouged is not repaired here
(:func:`planning.toolpath.verify.clearance_report` tells).

Arcs (:func:`fit_arcs`): the points of a run that lie in one plane of the chosen kind (G18: y
const, the plane of a pass along X) are joined by circular arcs through the run's end points
(start and end exactly on the circle, the centre on their perpendicular bisector: an algebraic
least-squares fit, refined by a few Gauss-Newton steps on the geometric residuals of the
interior points) when every CL point in between lies within tol of the arc and in order along
it, the arc between two neighbouring CL points bulges at most tol off the straight move between them
(its sagitta r (1 - cos(dtheta / 2)): without it an arc through the points of a steep pass could swing
a millimetre out between two of them, which the ball's clearance check passes while the flutes above
the ball cut the wall; the range half sphere's plan did, 0.77 mm), the arc turns at most 180 degrees (minor arcs only), its radius is within
[``min_radius_mm``, ``max_radius_mm``] (default 0.5 mm .. 500 mm, ``post.max_arc_radius_mm``:
tighter arcs are lines; no flatter arc is fitted, so such a stretch stays straight moves, reduced
and gouge-checked as any other) and it keeps R - tol from the cloud. Arcs are preferred to straight moves
only when they reach farther.

Everything runs in numba, parallel over runs; the cloud is binned once
(:class:`planning.toolpath.verify.BinnedCloud`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from planning.errors import ParameterError
from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    FEED,
    PLANE_AXES,
    PLANE_ZX,
    USE_CUT,
    Toolpath,
)
from planning.toolpath.verify import (
    _NF,
    BinnedCloud,
    _arc_dist,
    _binned,
    _check_radius,
    _fill_arc,
    _fill_line,
    _mod2pi,
    _move_min,
    _seg_d2,
    move_clearance,
)

_BACKOFF_STEPS = 8          # single-point back-offs before halving, when a move would gouge
_GN_STEPS = 3               # Gauss-Newton refinements of an arc's centre


# ------------------------------------------------------------------------------------ kernels

@njit(cache=True, nogil=True)
def _chord_ok(xyz, i, j, tol2):
    """Every point strictly between i and j within sqrt(tol2) of the segment xyz[i] -> xyz[j]."""
    sx, sy, sz = xyz[i, 0], xyz[i, 1], xyz[i, 2]
    dx, dy, dz = xyz[j, 0] - sx, xyz[j, 1] - sy, xyz[j, 2] - sz
    L2 = dx * dx + dy * dy + dz * dz
    for k in range(i + 1, j):
        if _seg_d2(xyz[k, 0], xyz[k, 1], xyz[k, 2], sx, sy, sz, dx, dy, dz, L2) > tol2:
            return False
    return True


@njit(cache=True, nogil=True)
def _arc_fit(xyz, i, j, tol, ia, ib, inn, plane_tol, rmin, rmax):
    """Circle through xyz[i] and xyz[j] in the plane (ia, ib; normal inn) fitted to the points in
    between (module docstring). Returns (ok, centre u, centre v, ccw)."""
    an = xyz[i, inn]
    for k in range(i + 1, j + 1):
        if abs(xyz[k, inn] - an) > plane_tol:
            return False, 0.0, 0.0, False
    au, av = xyz[i, ia], xyz[i, ib]
    du, dv = xyz[j, ia] - au, xyz[j, ib] - av
    L = math.sqrt(du * du + dv * dv)
    if L == 0.0:
        return False, 0.0, 0.0, False
    mu, mv = au + 0.5 * du, av + 0.5 * dv
    nu, nv = -dv / L, du / L                    # left normal of the chord
    hl2 = 0.25 * L * L
    sgh = 0.0
    shh = 0.0
    side = 0.0
    for k in range(i + 1, j):
        pu, pv = xyz[k, ia] - mu, xyz[k, ib] - mv
        hk = 2.0 * (nu * pu + nv * pv)
        sgh += (pu * pu + pv * pv - hl2) * hk
        shh += hk * hk
        side += hk
    if shh == 0.0:
        return False, 0.0, 0.0, False           # collinear: a straight move does it
    s = sgh / shh                               # centre = midpoint + s * left normal
    for _ in range(_GN_STEPS):
        r = math.sqrt(hl2 + s * s)
        num = 0.0
        den = 0.0
        for k in range(i + 1, j):
            pu, pv = xyz[k, ia] - mu - s * nu, xyz[k, ib] - mv - s * nv
            dk = math.sqrt(pu * pu + pv * pv)
            if dk == 0.0:
                continue
            jac = -(pu * nu + pv * nv) / dk - s / r
            num += (dk - r) * jac
            den += jac * jac
        if den == 0.0 or not math.isfinite(num / den):
            break
        s -= num / den
    r = math.sqrt(hl2 + s * s)
    if not (rmin <= r <= rmax):
        return False, 0.0, 0.0, False
    # a minor arc runs counter-clockwise when its centre is left of the chord
    ccw = s > 0.0 if s != 0.0 else side < 0.0
    cu, cv = mu + s * nu, mv + s * nv
    t0 = math.atan2(av - cv, au - cu)
    t1 = math.atan2(xyz[j, ib] - cv, xyz[j, ia] - cu)
    sw = _mod2pi(t1 - t0) if ccw else -_mod2pi(t0 - t1)
    if sw == 0.0 or abs(sw) > math.pi + 1e-9:
        return False, 0.0, 0.0, False
    r0 = math.sqrt((au - cu) ** 2 + (av - cv) ** 2)
    dn = xyz[j, inn] - an
    slack = 2.0 * tol / r0
    prev = 0.0
    for k in range(i + 1, j):
        u, v = xyz[k, ia] - cu, xyz[k, ib] - cv
        if _arc_dist(u, v, an - xyz[k, inn], t0, sw, r0, dn) > tol:
            return False, 0.0, 0.0, False
        phi = math.atan2(v, u)
        rel = _mod2pi(phi - t0) if ccw else _mod2pi(t0 - phi)
        if rel > math.pi + 0.5 * abs(sw):
            rel -= 2.0 * math.pi                # just before the start
        if rel < prev - slack:
            return False, 0.0, 0.0, False       # not in order along the arc
        if rel > prev and r0 * (1.0 - math.cos(0.5 * (rel - prev))) > tol:
            return False, 0.0, 0.0, False       # the arc bulges off the move between two CL points
        prev = max(prev, rel)
    if abs(sw) > prev and r0 * (1.0 - math.cos(0.5 * (abs(sw) - prev))) > tol:
        return False, 0.0, 0.0, False
    return True, cu, cv, ccw


@njit(cache=True, nogil=True)
def _chord_clear(xyz, i, j, F, I, pts, start, cmin, cmax, x0, y0, h, nx, ny, slack, thr):
    _fill_line(F, I, 0, xyz[i, 0], xyz[i, 1], xyz[i, 2], xyz[j, 0], xyz[j, 1], xyz[j, 2])
    return _move_min(F, I, 0, pts, start, cmin, cmax, x0, y0, h, nx, ny, slack, thr, thr) >= thr


@njit(cache=True, nogil=True)
def _arc_clear(xyz, i, j, cu, cv, ccw, ia, ib, inn, F, I, pts, start, cmin, cmax, x0, y0, h, nx, ny,
               slack, thr):
    _fill_arc(F, I, 0, xyz[i], xyz[j], cu, cv, ia, ib, inn, ccw)
    return _move_min(F, I, 0, pts, start, cmin, cmax, x0, y0, h, nx, ny, slack, thr, thr) >= thr


@njit(cache=True, nogil=True)
def _farthest_chord(xyz, i, last, tol2):
    """Farthest j <= last with a deviation-feasible chord, by doubling then bisection (i + 1 at
    least)."""
    good = i + 1
    bad = -1
    step = 1
    while good < last:
        j = min(good + step, last)
        if _chord_ok(xyz, i, j, tol2):
            good = j
            step *= 2
        else:
            bad = j
            break
    if bad > 0:
        while bad - good > 1:
            mid = (good + bad) // 2
            if _chord_ok(xyz, i, mid, tol2):
                good = mid
            else:
                bad = mid
    return good


@njit(cache=True, nogil=True)
def _farthest_arc(xyz, i, j0, last, tol, ia, ib, inn, plane_tol, rmin, rmax):
    """Farthest j in [j0, last] with a feasible arc fit (doubling then bisection); -1 if j0 fails."""
    ok, _, _, _ = _arc_fit(xyz, i, j0, tol, ia, ib, inn, plane_tol, rmin, rmax)
    if not ok:
        return -1
    good = j0
    bad = -1
    step = 1
    while good < last:
        j = min(good + step, last)
        ok, _, _, _ = _arc_fit(xyz, i, j, tol, ia, ib, inn, plane_tol, rmin, rmax)
        if ok:
            good = j
            step *= 2
        else:
            bad = j
            break
    if bad > 0:
        while bad - good > 1:
            mid = (good + bad) // 2
            ok, _, _, _ = _arc_fit(xyz, i, mid, tol, ia, ib, inn, plane_tol, rmin, rmax)
            if ok:
                good = mid
            else:
                bad = mid
    return good


@njit(cache=True, nogil=True)
def _next_try(i, j, tries):
    return j - 1 if tries <= _BACKOFF_STEPS else i + (j - i) // 2


@njit(parallel=True, cache=True)
def _reduce_runs(xyz, run_lo, run_hi, do_lines, do_arcs, tol, thr, ia, ib, inn, plane_tol, rmin, rmax,
                 min_pts, pts, start, cmin, cmax, x0, y0, h, nx, ny, slack, code, centre):
    """For each run (points run_lo[r] .. run_hi[r]): code[k] = 0 for dropped points, FEED / ARC_CW /
    ARC_CCW for the kept ones (with the arc centre in ``centre``)."""
    tol2 = tol * tol
    for r in prange(run_lo.shape[0]):
        F = np.empty((1, _NF))
        I = np.empty((1, 4), np.int64)
        i = run_lo[r]
        last = run_hi[r]
        for k in range(i + 1, last + 1):
            code[k] = 0
        while i < last:
            # the farthest gouge-free straight move
            jc = i + 1
            if do_lines and last >= i + 2:
                j = _farthest_chord(xyz, i, last, tol2)
                tries = 0
                while j > i + 1:
                    if (tries == 0 or _chord_ok(xyz, i, j, tol2)) and \
                            _chord_clear(xyz, i, j, F, I, pts, start, cmin, cmax, x0, y0, h, nx, ny, slack, thr):
                        break
                    tries += 1
                    j = _next_try(i, j, tries)
                jc = j
            # the farthest gouge-free arc, if it beats the straight move
            ja = -1
            acu, acv, accw = 0.0, 0.0, False
            j0 = max(i + min_pts - 1, jc + 1)
            if do_arcs and j0 <= last:
                j = _farthest_arc(xyz, i, j0, last, tol, ia, ib, inn, plane_tol, rmin, rmax)
                tries = 0
                while j > jc:
                    ok, cu, cv, ccw = _arc_fit(xyz, i, j, tol, ia, ib, inn, plane_tol, rmin, rmax)
                    if ok and _arc_clear(xyz, i, j, cu, cv, ccw, ia, ib, inn, F, I, pts, start, cmin, cmax,
                                         x0, y0, h, nx, ny, slack, thr):
                        ja, acu, acv, accw = j, cu, cv, ccw
                        break
                    tries += 1
                    j = _next_try(i, j, tries)
                    if j < i + min_pts - 1:
                        break
            if ja > jc:
                code[ja] = ARC_CCW if accw else ARC_CW
                centre[ja, ia] = acu
                centre[ja, ib] = acv
                centre[ja, inn] = xyz[i, inn]
                i = ja
            else:
                code[jc] = FEED
                i = jc


# ------------------------------------------------------------------------------------ driver

def _runs(tp: Toolpath, uses, pass_index):
    """(first point, last point) of each run of >= 2 consecutive FEED moves of one use in ``uses``
    (and one pass where ``pass_index`` is given)."""
    P = tp.n_moves
    ok = (tp.kind == FEED) & np.isin(tp.use, np.asarray(uses, dtype=np.int64))
    if P:
        ok[0] = False
    if pass_index is not None:
        pi = np.asarray(pass_index).reshape(-1)
        if pi.shape[0] != P:
            raise ParameterError(f"pass_index must have one entry per move ({P}), not {pi.shape[0]}")
        ok[1:] &= (pi[1:] == pi[:-1]) & (pi[1:] >= 0)
    cont = np.zeros(P, dtype=bool)              # move i continues the run of move i - 1
    cont[1:] = ok[1:] & ok[:-1] & (tp.use[1:] == tp.use[:-1])
    first = np.flatnonzero(ok & ~cont)
    # the run starting at move f ends before the next move that does not continue it
    stops = np.flatnonzero(~cont)               # moves that do not continue their predecessor
    nxt = np.searchsorted(stops, first, side="right")
    last = np.where(nxt < stops.size, stops[np.minimum(nxt, stops.size - 1)] - 1, P - 1)
    keep = last - first >= 1                    # at least two moves
    return (first[keep] - 1).astype(np.int64), last[keep].astype(np.int64)


def _reduce(tp, points, radius_mm, tol_mm, *, lines_, arcs, plane, min_points, min_radius_mm,
            max_radius_mm, plane_tol_mm, uses, pass_index, cell_mm) -> tuple[Toolpath, np.ndarray]:
    R = _check_radius(radius_mm)
    tol = float(tol_mm)
    if not (0 < tol < R):
        raise ParameterError(f"tol_mm = {tol_mm}: must be in (0, R = {R})")
    if arcs:
        if int(plane) not in PLANE_AXES:
            raise ParameterError(f"plane = {plane}: must be 17 (XY), 18 (ZX) or 19 (YZ)")
        if int(min_points) < 3:
            raise ParameterError(f"min_points = {min_points}: must be >= 3")
        if not (0 < float(min_radius_mm) <= float(max_radius_mm)):
            raise ParameterError(f"min_radius_mm = {min_radius_mm}, max_radius_mm = {max_radius_mm}: "
                                 "need 0 < min <= max")
        if not float(plane_tol_mm) >= 0:
            raise ParameterError(f"plane_tol_mm = {plane_tol_mm}: must be >= 0")
    xyz = np.ascontiguousarray(tp.xyz_mm, dtype=np.float64)
    lo, hi = _runs(tp, uses, pass_index)
    if lo.size and not np.all(np.isfinite(xyz)):
        raise ParameterError("the path's points must be finite")
    code = np.full(tp.n_moves, -1, dtype=np.int64)
    centre = np.full((tp.n_moves, 3), np.nan)
    if lo.size:
        cloud = _binned(points, R, cell_mm)
        ia, ib, inn = PLANE_AXES[int(plane) if arcs else PLANE_ZX]
        _reduce_runs(xyz, lo, hi, bool(lines_), bool(arcs), tol, R - tol, ia, ib, inn, float(plane_tol_mm),
                     float(min_radius_mm), float(max_radius_mm), int(min_points), *cloud.arrays, code, centre)
        if cloud.triangles is not None:
            _clear_of_triangles(tp, xyz, code, centre, plane, cloud, R, tol)
    return _assemble(tp, xyz, code, centre, plane)


def _assemble(tp: Toolpath, xyz, code, centre, plane) -> tuple[Toolpath, np.ndarray]:
    """The path the kernel's ``code`` describes (0 dropped, -1 kept as it was, else the new move's kind
    ending there), and the index in ``tp`` of each of its points."""
    keep = code != 0
    new = code >= 0
    is_arc = (code == ARC_CW) | (code == ARC_CCW)
    kind = np.where(new, code, tp.kind).astype(np.int8)
    cen = np.where(is_arc[:, None], centre, tp.centre_mm)
    pl = np.where(is_arc, np.int8(plane), tp.plane).astype(np.int8)
    return (Toolpath(xyz_mm=xyz[keep].copy(), kind=kind[keep], centre_mm=cen[keep], plane=pl[keep],
                     use=tp.use[keep].copy(), tip_offset_mm=tp.tip_offset_mm,
                     axis=None if tp.axis is None else tp.axis[keep].copy()), np.flatnonzero(keep))


def _clear_of_triangles(tp: Toolpath, xyz, code, centre, plane, cloud, R: float, tol: float) -> None:
    """The kernel checks the replacing moves against the points; with triangles through them
    (:mod:`planning.toolpath.surface`) a replacing move can still pass through a facet between its
    points. Each new move (line or arc) closer than R - tol to the triangles (or the points) is undone
    in ``code``: the original CL points it replaced are kept, as the original moves were (the passes
    were made safe against the triangles, :func:`planning.toolpath.finishing.finishing_passes`)."""
    out, at = _assemble(tp, xyz, code, centre, plane)
    new = np.flatnonzero(code[at] >= 0)
    new = new[new > 0]
    if new.size == 0:
        return
    clear = move_clearance(out, cloud, R, moves=new)
    bad = new[clear[new] < R - tol]
    for m in bad:                       # one slice per undone move
        code[at[m - 1] + 1:at[m] + 1] = -1


def reduce_cl(tp: Toolpath, points, radius_mm: float, *, tol_mm: float, uses=(USE_CUT,),
              pass_index: np.ndarray | None = None, cell_mm: float | None = None,
              with_kept: bool = False) -> Toolpath | tuple[Toolpath, np.ndarray]:
    """Drop CL points of ``tp`` (ball centres, area frame, mm) whose straight replacement passes
    within ``tol_mm`` (3-D) of every dropped point and keeps clearance >= R - tol from every point
    of ``points`` (N,3, or a :class:`planning.toolpath.verify.BinnedCloud`); Sood 2015 §4.4 made
    tolerance bounded and gouge safe (module docstring). Runs are consecutive FEED moves of one
    ``use`` in ``uses`` (default the cutting moves), split where ``pass_index`` (P,) changes or is
    negative when given (:attr:`planning.toolpath.finishing.FinishingPath.pass_index`). Other moves
    are kept as they are. Returns a new :class:`Toolpath` (same tip offset); with ``with_kept``
    ``(toolpath, kept)``, ``kept`` the index in ``tp`` of each of its points (to carry per-point
    arrays such as a pass index across the reduction)."""
    out = _reduce(tp, points, radius_mm, tol_mm, lines_=True, arcs=False, plane=PLANE_ZX, min_points=3,
                  min_radius_mm=1.0, max_radius_mm=1.0, plane_tol_mm=0.0, uses=uses,
                  pass_index=pass_index, cell_mm=cell_mm)
    return out if with_kept else out[0]


def fit_arcs(tp: Toolpath, points, radius_mm: float, *, tol_mm: float, plane: int = PLANE_ZX,
             min_points: int = 4, min_radius_mm: float = 0.5, max_radius_mm: float = 500.0,
             plane_tol_mm: float = 1e-6, reduce_lines: bool = True, uses=(USE_CUT,),
             pass_index: np.ndarray | None = None, cell_mm: float | None = None) -> Toolpath:
    """Replace runs of consecutive FEED moves of ``tp`` (ball centres, area frame, mm) that lie in
    one plane of kind ``plane`` (default G18: y const, passes along X; points within
    ``plane_tol_mm`` of the run start's plane) by circular arcs (ARC_CW / ARC_CCW, centre, that
    plane) through at least ``min_points`` CL points (ends included): every CL point of the run
    within ``tol_mm`` of the arc and in order along it, at most 180 degrees per move, radius in
    [``min_radius_mm``, ``max_radius_mm``] (mm; the default maximum, 500 mm, is the posts'
    ``PostOptions.max_arc_radius_mm``: a larger arc would be printed as chords anyway), clearance
    >= R - tol from ``points`` (module docstring).
    With ``reduce_lines`` the points not taken by arcs are reduced as :func:`reduce_cl` does, with
    the same tolerance against the same original points (an arc is taken where it reaches farther
    than the straight move); else they stay as they were. ``uses``, ``pass_index``: as in
    :func:`reduce_cl`. Returns a new :class:`Toolpath`."""
    return _reduce(tp, points, radius_mm, tol_mm, lines_=reduce_lines, arcs=True, plane=plane,
                   min_points=min_points, min_radius_mm=min_radius_mm, max_radius_mm=max_radius_mm,
                   plane_tol_mm=plane_tol_mm, uses=uses, pass_index=pass_index, cell_mm=cell_mm)[0]


__all__ = ["BinnedCloud", "fit_arcs", "reduce_cl"]
