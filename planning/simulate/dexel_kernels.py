"""Numba kernels of the tri-dexel stock (:mod:`planning.simulate.dexel` holds the model and the
public functions; everything here works on its plain arrays).

Storage (one model): three families of rays, family ``f`` running along axis ``f`` on the grid of
the two other axes ``ua = (f+1) % 3`` (index ``i``) and ``va = (f+2) % 3`` (row ``j``), ray
``(i, j)`` at ``u = lo[ua] + (i + 1/2) res``, ``v = lo[va] + (j + 1/2) res``, global ray number
``base[f] + j * n[ua] + i``. Ray ``r`` holds ``cnt[r]`` sorted disjoint intervals
``pool[off[r] : off[r] + cnt[r]]`` (absolute coordinates along its axis) in a block of ``cap[r]``
slots. The rays are dealt to *tasks*: per family, the rows ``j = q mod jmod`` (``jmod``: the
threads; interleaved, so a tool path's work is spread over all tasks wherever it runs; ordered
residue-major so the parallel loop's static split gives every thread each family). A task owns a
contiguous region of the pool ``[.., t_end)`` whose free space starts at ``t_top``: a ray that
outgrows its block moves to a block twice as large at ``t_top``; when the region is full the task
stops at that move and reports it (``t_status`` 1, ``t_next`` the move), the caller repacks the pool
with more room and runs again (removal is idempotent, so the partly done move is simply redone).
Material is therefore never dropped on overflow.

A task walks the moves dealt to it in program order and touches only its own rays, so tasks run in
parallel (threads, the GIL released) without locks and the per-move figures are exact in program
order.

Skipping empty space: every row is cut into segments of :data:`SEG` rays and the segments into
tiles of :data:`TROWS` rows, each with the lowest lower end and highest upper end of its rays'
material (refreshed between kernel calls; cutting only shrinks material, so stale bounds are
conservative). A piece whose extent along the rays misses every tile under it, a segment, and a ray
whose material misses that extent (binary search) are skipped before any exact interval.

Swept pieces (the convex pieces of a tool moving in a straight line at a fixed axis): the ray
``p(s) = o + s e`` meets the piece at offset ``t d`` (``t`` in [0, 1]) when ``g(s, t) <= 0`` (radial
quadric, convex) and, for a cylinder, ``z0 <= h(s, t) <= z1`` (axial, linear). The feasible set in
``(s, t)`` is convex and compact, so its ``s``-range is one interval whose ends are attained at
candidate points: the vertices of the linear constraints, their lines' crossings with ``g = 0``,
and the quadric's own extreme-``s`` points; the feasible candidates' min and max are the interval
(:func:`swept_interval`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

#: Intervals shorter than this (mm) are dropped (floating-point slivers of a cut).
EPS_LEN = 1e-9
#: Feasibility tolerances of the candidate points: along the move (t), along the axis (mm).
EPS_T = 1e-9
EPS_H = 1e-7

#: Piece kinds.
CYL, SPH = 0, 1
#: Rays per row segment (a segment keeps the bounds of its rays' material, to skip empty ones),
#: and rows per tile (a tile: TROWS rows of a segment column, bounds of the same kind).
SEG = 16
TROWS = 16
#: Move mode bits: cut with the cutting pieces; measure the non-cutting pieces; measure the cutting
#: pieces; add the cutting pieces (union; constructors).
M_CUT, M_HOLDER, M_TOOL, M_ADD = 1, 2, 4, 8

_INF = np.inf


# ------------------------------------------------------------------------------------ geometry

@njit(cache=True)
def _quad_roots(a, b, c):
    """Roots of a x^2 + 2 b x + c = 0 (n, x1, x2)."""
    scale = abs(a) + abs(b) + abs(c)
    if scale == 0.0:
        return 0, 0.0, 0.0
    if abs(a) <= 1e-14 * scale:
        if abs(b) <= 1e-300:
            return 0, 0.0, 0.0
        x = -c / (2.0 * b)
        return 1, x, x
    disc = b * b - a * c
    if disc < 0.0:
        return 0, 0.0, 0.0
    q = -(b + math.copysign(math.sqrt(disc), b))
    x1 = q / a
    x2 = c / q if q != 0.0 else x1
    return 2, x1, x2


@njit(cache=True)
def _feasible(s, t, AA, AB, BB, uA, uB, c0, tolg, has_h, h0, hs, ht, z0, z1):
    if t < -EPS_T or t > 1.0 + EPS_T:
        return False
    if has_h:
        h = h0 + hs * s + ht * t
        if h < z0 - EPS_H or h > z1 + EPS_H:
            return False
    g = AA * s * s + 2.0 * AB * s * t + BB * t * t + 2.0 * uA * s + 2.0 * uB * t + c0
    return g <= tolg


@njit(cache=True)
def swept_interval(AA, AB, BB, uA, uB, c0, R, has_h, h0, hs, ht, z0, z1):
    """The s-interval of {(s, t): g(s, t) <= 0, 0 <= t <= 1 [, z0 <= h(s, t) <= z1]} where
    g = AA s^2 + 2 AB s t + BB t^2 + 2 uA s + 2 uB t + c0 (convex: AA, BB >= 0, AA BB >= AB^2) and
    h = h0 + hs s + ht t. Returns (found, s_lo, s_hi). R: the radius (tolerance scale)."""
    lo = _INF
    hi = -_INF
    tolg = 2e-7 * R + 1e-12
    if has_h:
        if abs(hs) <= 1e-12 and abs(ht) <= 1e-12:
            if h0 < z0 - EPS_H or h0 > z1 + EPS_H:
                return False, 0.0, 0.0
            has_h = False
    # 1. vertices of t in {0,1} x h in {z0, z1}
    if has_h and abs(hs) > 1e-12:
        for it in range(2):
            tk = float(it)
            for iz in range(2):
                zk = z0 if iz == 0 else z1
                s = (zk - h0 - ht * tk) / hs
                if _feasible(s, tk, AA, AB, BB, uA, uB, c0, tolg, False, h0, hs, ht, z0, z1):
                    lo = min(lo, s)
                    hi = max(hi, s)
    # 2. the lines crossing the quadric: t = 0, t = 1, h = z0, h = z1
    nl = 4 if has_h else 2
    for il in range(nl):
        if il < 2:
            p0s, p0t, vs, vt = 0.0, float(il), 1.0, 0.0
        else:
            zk = z0 if il == 2 else z1
            if abs(hs) >= abs(ht):
                p0s, p0t, vs, vt = (zk - h0) / hs, 0.0, -ht / hs, 1.0
            else:
                p0s, p0t, vs, vt = 0.0, (zk - h0) / ht, 1.0, -hs / ht
        a2 = AA * vs * vs + 2.0 * AB * vs * vt + BB * vt * vt
        b1 = (AA * p0s + AB * p0t + uA) * vs + (AB * p0s + BB * p0t + uB) * vt
        cc = AA * p0s * p0s + 2.0 * AB * p0s * p0t + BB * p0t * p0t + 2.0 * uA * p0s + 2.0 * uB * p0t + c0
        nr, x1, x2 = _quad_roots(a2, b1, cc)
        for ir in range(nr):
            lam = x1 if ir == 0 else x2
            s = p0s + lam * vs
            t = p0t + lam * vt
            if _feasible(s, t, AA, AB, BB, uA, uB, c0, tolg, has_h, h0, hs, ht, z0, z1):
                lo = min(lo, s)
                hi = max(hi, s)
    # 3. the quadric's extreme-s points (a proper ellipse only)
    det = AA * BB - AB * AB
    if BB > 0.0 and AA > 0.0 and det > 1e-10 * AA * BB:
        cs = -(BB * uA - AB * uB) / det
        ct = (AB * uA - AA * uB) / det
        k = -(uA * cs + uB * ct) - c0
        if k >= 0.0:
            fct = math.sqrt(k / (det * BB))
            for sg in (-1.0, 1.0):
                s = cs + sg * BB * fct
                t = ct - sg * AB * fct
                if _feasible(s, t, AA, AB, BB, uA, uB, c0, tolg, has_h, h0, hs, ht, z0, z1):
                    lo = min(lo, s)
                    hi = max(hi, s)
    if lo > hi:
        return False, 0.0, 0.0
    return True, lo, hi


@njit(cache=True)
def cyl_pre(AA, AB, BB, hs, ht):
    """Per-piece constants of :func:`cyl_interval` (the parts of the swept-cylinder problem that do
    not depend on the ray): (has_h, by_t, vs, vt, inv_hs, a2_h, det, cs_u, cs_v, ct_u, ct_v, kden).
    ``has_h``: the axial constraint involves s or t; ``by_t``: the h-lines are parametrised by t."""
    has_h = abs(hs) > 1e-12 or abs(ht) > 1e-12
    by_t = abs(hs) >= abs(ht)
    inv_hs = 1.0 / hs if abs(hs) > 1e-12 else 0.0
    if by_t and abs(hs) > 1e-12:
        vs, vt = -ht / hs, 1.0
    elif abs(ht) > 1e-12:
        vs, vt = 1.0, -hs / ht
    else:
        vs, vt = 0.0, 0.0
    a2_h = AA * vs * vs + 2.0 * AB * vs * vt + BB * vt * vt
    det = AA * BB - AB * AB
    ok_ext = BB > 0.0 and AA > 0.0 and det > 1e-10 * AA * BB
    if ok_ext:
        cs_u, cs_v = -BB / det, AB / det          # cs = cs_u uA + cs_v uB
        ct_u, ct_v = AB / det, -AA / det          # ct = ct_u uA + ct_v uB
        kden = 1.0 / (det * BB)
    else:
        cs_u = cs_v = ct_u = ct_v = kden = 0.0
    return has_h, by_t, vs, vt, inv_hs, a2_h, ok_ext, cs_u, cs_v, ct_u, ct_v, kden


@njit(cache=True)
def cyl_interval(AA, AB, BB, uA, uB, c0, R, h0, hs, ht, z0, z1,
                 has_h, by_t, vs, vt, inv_hs, a2_h, ok_ext, cs_u, cs_v, ct_u, ct_v, kden):
    """:func:`swept_interval` with the axial constraint, the per-piece constants from
    :func:`cyl_pre`: each candidate is checked only against the constraints it is not built on."""
    lo = _INF
    hi = -_INF
    tolg = 2e-7 * R + 1e-12
    if not has_h:
        if h0 < z0 - EPS_H or h0 > z1 + EPS_H:
            return False, 0.0, 0.0
    # vertices t in {0, 1} x h in {z0, z1}: check g
    if has_h and inv_hs != 0.0:
        for it in range(2):
            tk = float(it)
            for iz in range(2):
                s = ((z0 if iz == 0 else z1) - h0 - ht * tk) * inv_hs
                g = AA * s * s + 2.0 * AB * s * tk + BB * tk * tk + 2.0 * uA * s + 2.0 * uB * tk + c0
                if g <= tolg:
                    lo = min(lo, s)
                    hi = max(hi, s)
    # t = 0, 1 against g = 0: check h
    if AA > 0.0:
        for it in range(2):
            tk = float(it)
            b1 = AB * tk + uA
            cc = BB * tk * tk + 2.0 * uB * tk + c0
            disc = b1 * b1 - AA * cc
            if disc >= 0.0:
                sq = math.sqrt(disc)
                for sg in (-1.0, 1.0):
                    s = (-b1 + sg * sq) / AA
                    if has_h:
                        h = h0 + hs * s + ht * tk
                        if h < z0 - EPS_H or h > z1 + EPS_H:
                            continue
                    lo = min(lo, s)
                    hi = max(hi, s)
    # h = z0, z1 against g = 0: check t
    if has_h and a2_h > 0.0:
        for iz in range(2):
            zk = z0 if iz == 0 else z1
            if by_t:
                p0s, p0t = (zk - h0) * inv_hs, 0.0
            else:
                p0s, p0t = 0.0, (zk - h0) / ht
            b1 = (AA * p0s + AB * p0t + uA) * vs + (AB * p0s + BB * p0t + uB) * vt
            cc = AA * p0s * p0s + 2.0 * AB * p0s * p0t + BB * p0t * p0t + 2.0 * uA * p0s + 2.0 * uB * p0t + c0
            disc = b1 * b1 - a2_h * cc
            if disc >= 0.0:
                sq = math.sqrt(disc)
                for sg in (-1.0, 1.0):
                    lam = (-b1 + sg * sq) / a2_h
                    t = p0t + lam * vt
                    if t < -EPS_T or t > 1.0 + EPS_T:
                        continue
                    s = p0s + lam * vs
                    lo = min(lo, s)
                    hi = max(hi, s)
    # the quadric's extreme-s points: check t and h
    if ok_ext:
        cs = cs_u * uA + cs_v * uB
        ct = ct_u * uA + ct_v * uB
        k = -(uA * cs + uB * ct) - c0
        if k >= 0.0:
            fct = math.sqrt(k * kden)
            for sg in (-1.0, 1.0):
                s = cs + sg * BB * fct
                t = ct - sg * AB * fct
                if t < -EPS_T or t > 1.0 + EPS_T:
                    continue
                if has_h:
                    h = h0 + hs * s + ht * t
                    if h < z0 - EPS_H or h > z1 + EPS_H:
                        continue
                lo = min(lo, s)
                hi = max(hi, s)
    if lo > hi:
        return False, 0.0, 0.0
    return True, lo, hi


@njit(cache=True)
def _sphere_iv(wf, ww, R2, lo, hi):
    """Widen [lo, hi] by the ray s e (e a unit axis, w = o - centre) inside a sphere."""
    disc = wf * wf - ww + R2
    if disc >= 0.0:
        h = math.sqrt(disc)
        lo = min(lo, -wf - h)
        hi = max(hi, -wf + h)
    return lo, hi


@njit(cache=True)
def capsule_interval(wf, ww, df, wd, dd, R2):
    """The s-interval of the ray o + s e (e the unit axis f) inside the capsule of radius
    sqrt(R2) around the segment c -> c + d, from w = o - c: ``wf = w_f``, ``ww = |w|^2``,
    ``df = d_f``, ``wd = w.d``, ``dd = |d|^2``. Returns (found, lo, hi): the end spheres and the
    body (the infinite cylinder between the end planes)."""
    lo = _INF
    hi = -_INF
    lo, hi = _sphere_iv(wf, ww, R2, lo, hi)
    if dd > 0.0:
        # w1 = w - d: w1_f = wf - df, |w1|^2 = ww - 2 wd + dd
        lo, hi = _sphere_iv(wf - df, ww - 2.0 * wd + dd, R2, lo, hi)
        A = 1.0 - df * df / dd
        if A > 1e-12:
            B = wf - wd * df / dd
            C = ww - wd * wd / dd - R2
            disc = B * B - A * C
            if disc >= 0.0:
                h = math.sqrt(disc)
                s0 = (-B - h) / A
                s1 = (-B + h) / A
                # along the segment: t(s) = (wd + s df) / dd in [0, 1]
                if df > 0.0:
                    s0 = max(s0, -wd / df)
                    s1 = min(s1, (dd - wd) / df)
                elif df < 0.0:
                    s0 = max(s0, (dd - wd) / df)
                    s1 = min(s1, -wd / df)
                elif wd < 0.0 or wd > dd:
                    s0 = _INF
                if s0 <= s1:
                    lo = min(lo, s0)
                    hi = max(hi, s1)
    if lo > hi:
        return False, 0.0, 0.0
    return True, lo, hi


@njit(cache=True)
def _clip_lin(alpha, beta, xl, xh):
    """Intersect [xl, xh] with {x: alpha x + beta >= 0}."""
    if alpha > 0.0:
        xl = max(xl, -beta / alpha)
    elif alpha < 0.0:
        xh = min(xh, -beta / alpha)
    elif beta < 0.0:
        xl = _INF
    return xl, xh


@njit(cache=True)
def hline_capsule(pu, pv, qu, qv, R, y, lo, hi):
    """Widen [lo, hi] by the u-range where the horizontal line v = y meets the 2D capsule of radius
    R around the segment p-q."""
    for e in range(2):
        cu = pu if e == 0 else qu
        cv = pv if e == 0 else qv
        dy = y - cv
        if abs(dy) <= R:
            h = math.sqrt(R * R - dy * dy)
            lo = min(lo, cu - h)
            hi = max(hi, cu + h)
    du = qu - pu
    dv = qv - pv
    L2 = du * du + dv * dv
    if L2 > 0.0:
        xl, xh = -_INF, _INF
        b0 = (y - pv) * dv - pu * du
        xl, xh = _clip_lin(du, b0, xl, xh)
        xl, xh = _clip_lin(-du, L2 - b0, xl, xh)
        RL = R * math.sqrt(L2)
        c1 = du * (y - pv) + dv * pu
        xl, xh = _clip_lin(-dv, c1 + RL, xl, xh)
        xl, xh = _clip_lin(dv, RL - c1, xl, xh)
        if xl <= xh:
            lo = min(lo, xl)
            hi = max(hi, xh)
    return lo, hi


# ------------------------------------------------------------------------------------ interval lists

@njit(cache=True)
def _first_above(pool, o, c, a):
    """First k in [0, c) with pool[o + k, 1] > a (c when none)."""
    lo_k = 0
    hi_k = c
    while lo_k < hi_k:
        mid = (lo_k + hi_k) >> 1
        if pool[o + mid, 1] > a:
            hi_k = mid
        else:
            lo_k = mid + 1
    return lo_k


@njit(cache=True)
def _grow_ray(pool, off, cnt, cap, r, need, task, t_top, t_end):
    """Move ray r to a block of at least ``need`` slots in its task's free space (False: full)."""
    newcap = max(2 * cap[r], need, 2)
    if t_top[task] + newcap > t_end[task]:
        return False
    o = off[r]
    no = t_top[task]
    for k in range(cnt[r]):
        pool[no + k, 0] = pool[o + k, 0]
        pool[no + k, 1] = pool[o + k, 1]
    off[r] = no
    cap[r] = newcap
    t_top[task] = no + newcap
    return True


@njit(cache=True)
def subtract(pool, off, cnt, cap, r, a, b, task, t_top, t_end):
    """Remove [a, b] from ray r. Returns the length removed, or -1 when the ray must grow and its
    task's region is full (nothing changed then)."""
    c = cnt[r]
    o = off[r]
    k = _first_above(pool, o, c, a)
    if k == c or pool[o + k, 0] >= b:
        return 0.0
    k2 = k
    removed = 0.0
    while k2 < c and pool[o + k2, 0] < b:
        removed += min(pool[o + k2, 1], b) - max(pool[o + k2, 0], a)
        k2 += 1
    llo = pool[o + k, 0]
    rhi = pool[o + k2 - 1, 1]
    left = llo < a - EPS_LEN
    right = rhi > b + EPS_LEN
    nnew = int(left) + int(right)
    newc = c - (k2 - k) + nnew
    if newc > cap[r]:
        if not _grow_ray(pool, off, cnt, cap, r, newc, task, t_top, t_end):
            return -1.0
        o = off[r]
    shift = k + nnew - k2
    if shift > 0:
        for q in range(c - 1, k2 - 1, -1):
            pool[o + q + shift, 0] = pool[o + q, 0]
            pool[o + q + shift, 1] = pool[o + q, 1]
    elif shift < 0:
        for q in range(k2, c):
            pool[o + q + shift, 0] = pool[o + q, 0]
            pool[o + q + shift, 1] = pool[o + q, 1]
    w = k
    if left:
        pool[o + w, 0] = llo
        pool[o + w, 1] = a
        w += 1
    if right:
        pool[o + w, 0] = b
        pool[o + w, 1] = rhi
    cnt[r] = newc
    return removed


@njit(cache=True)
def add(pool, off, cnt, cap, r, a, b, task, t_top, t_end):
    """Union [a, b] into ray r. Returns the length added, or -1 when the region is full."""
    if b - a <= EPS_LEN:
        return 0.0
    c = cnt[r]
    o = off[r]
    # intervals touching [a, b]: hi >= a and lo <= b
    k = 0
    lo_k = 0
    hi_k = c
    while lo_k < hi_k:
        mid = (lo_k + hi_k) >> 1
        if pool[o + mid, 1] >= a:
            hi_k = mid
        else:
            lo_k = mid + 1
    k = lo_k
    k2 = k
    covered = 0.0
    na = a
    nb = b
    while k2 < c and pool[o + k2, 0] <= b:
        covered += min(pool[o + k2, 1], b) - max(pool[o + k2, 0], a)
        na = min(na, pool[o + k2, 0])
        nb = max(nb, pool[o + k2, 1])
        k2 += 1
    newc = c - (k2 - k) + 1
    if newc > cap[r]:
        if not _grow_ray(pool, off, cnt, cap, r, newc, task, t_top, t_end):
            return -1.0
        o = off[r]
    shift = k + 1 - k2
    if shift > 0:
        for q in range(c - 1, k2 - 1, -1):
            pool[o + q + shift, 0] = pool[o + q, 0]
            pool[o + q + shift, 1] = pool[o + q, 1]
    elif shift < 0:
        for q in range(k2, c):
            pool[o + q + shift, 0] = pool[o + q, 0]
            pool[o + q + shift, 1] = pool[o + q, 1]
    pool[o + k, 0] = na
    pool[o + k, 1] = nb
    cnt[r] = newc
    return (b - a) - covered


@njit(cache=True)
def overlap(pool, off, cnt, r, a, b):
    """Length of ray r's material inside [a, b]."""
    c = cnt[r]
    o = off[r]
    k = _first_above(pool, o, c, a)
    tot = 0.0
    while k < c and pool[o + k, 0] < b:
        tot += min(pool[o + k, 1], b) - max(pool[o + k, 0], a)
        k += 1
    return tot


# ------------------------------------------------------------------------------------ one move

@njit(cache=True)
def _seg_index(f, j, i, sbase, nseg):
    return sbase[f] + j * nseg[f] + i // SEG


@njit(cache=True)
def _piece(op, f, jres, jmod, task, lo, res, n, base, sbase, nseg, seg_lo, seg_hi, tbase, tile_lo, tile_hi, dirty,
           off, cnt, cap, pool, t_top, t_end, P, d, a, kind, z0, z1, R, capf):
    """Apply one swept piece to the rays of a task (rows ``j = jres mod jmod`` of family f): op 0
    cut, 1 measure (stops at the first ray whose overlap reaches ``capf``), 2 add. Returns
    (status, length removed / added, largest overlap, rays evaluated). Marks ``dirty`` every row
    segment whose rays it cut or added to (:func:`refresh_dirty` recomputes only those)."""
    ua = (f + 1) % 3
    va = (f + 2) % 3
    nu = n[ua]
    rb = base[f]
    da = d[0] * a[0] + d[1] * a[1] + d[2] * a[2]
    dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    if kind == CYL:
        ext_f = R * math.sqrt(max(0.0, 1.0 - a[f] * a[f]))
        ext_v = R * math.sqrt(max(0.0, 1.0 - a[va] * a[va]))
        ext_u = R * math.sqrt(max(0.0, 1.0 - a[ua] * a[ua]))
        za = z0
        zb = z1
    else:
        ext_f = R
        ext_v = R
        ext_u = R
        za = z0
        zb = z0
    # the piece's axis ends at t = 0 and t = 1, projected: corners 0 (za, t0), 1 (zb, t0),
    # 2 (zb, t1), 3 (za, t1)
    cu0 = P[ua] + za * a[ua]
    cv0 = P[va] + za * a[va]
    cu1 = P[ua] + zb * a[ua]
    cv1 = P[va] + zb * a[va]
    cu2 = cu1 + d[ua]
    cv2 = cv1 + d[va]
    cu3 = cu0 + d[ua]
    cv3 = cv0 + d[va]
    f0 = P[f] + za * a[f]
    f1 = P[f] + zb * a[f]
    fmin = min(f0, f1, f0 + d[f], f1 + d[f]) - ext_f
    fmax = max(f0, f1, f0 + d[f], f1 + d[f]) + ext_f
    vmin = min(cv0, cv1, cv2, cv3) - ext_v
    vmax = max(cv0, cv1, cv2, cv3) + ext_v
    umin = min(cu0, cu1, cu2, cu3) - ext_u
    umax = max(cu0, cu1, cu2, cu3) + ext_u
    jlo = max(0, int(math.ceil((vmin - lo[va]) / res - 0.5)))
    jhi = min(n[va] - 1, int(math.floor((vmax - lo[va]) / res - 0.5)))
    total = 0.0
    maxov = 0.0
    visits = 0
    if op != 2:
        # the tiles under the piece's bounding box: any material within its extent along the rays?
        ilo0 = max(0, int(math.ceil((umin - lo[ua]) / res - 0.5)))
        ihi0 = min(nu - 1, int(math.floor((umax - lo[ua]) / res - 0.5)))
        if jlo > jhi or ilo0 > ihi0:
            return 0, total, maxov, visits
        any_tile = False
        for tj in range(jlo // TROWS, jhi // TROWS + 1):
            tb = tbase[f] + tj * nseg[f]
            for ts in range(ilo0 // SEG, ihi0 // SEG + 1):
                if tile_lo[tb + ts] <= fmax and tile_hi[tb + ts] >= fmin:
                    any_tile = True
                    break
            if any_tile:
                break
        if not any_tile:
            return 0, total, maxov, visits
    jlo += (jres - jlo) % jmod
    if kind == CYL:
        AA = 1.0 - a[f] * a[f]
        AB = -(d[f] - da * a[f])
        BB = max(0.0, dd - da * da)
        hs = a[f]
        ht = -da
    else:
        AA = 1.0
        AB = -d[f]
        BB = dd
        hs = 0.0
        ht = 0.0
    R2 = R * R
    (has_h, by_t, vs, vt, inv_hs, a2_h, ok_ext, cs_u, cs_v, ct_u, ct_v, kden) = cyl_pre(AA, AB, BB, hs, ht)
    flo = lo[f]
    fhi = lo[f] + n[f] * res
    for j in range(jlo, jhi + 1, jmod):
        vj = lo[va] + (j + 0.5) * res
        ul = _INF
        uh = -_INF
        ul, uh = hline_capsule(cu0, cv0, cu1, cv1, R, vj, ul, uh)
        if kind == CYL:
            ul, uh = hline_capsule(cu1, cv1, cu2, cv2, R, vj, ul, uh)
            ul, uh = hline_capsule(cu2, cv2, cu3, cv3, R, vj, ul, uh)
            ul, uh = hline_capsule(cu3, cv3, cu0, cv0, R, vj, ul, uh)
        else:
            ul, uh = hline_capsule(cu0, cv0, cu3, cv3, R, vj, ul, uh)
        ul = max(ul, umin)
        uh = min(uh, umax)
        if ul > uh:
            continue
        ilo = max(0, int(math.ceil((ul - lo[ua]) / res - 0.5)))
        ihi = min(nu - 1, int(math.floor((uh - lo[ua]) / res - 0.5)))
        rowbase = rb + j * nu
        w_v = vj - P[va]
        i = ilo
        while i <= ihi:
            sg = _seg_index(f, j, i, sbase, nseg)
            iend = min(ihi, (i // SEG) * SEG + SEG - 1)
            if op != 2 and (seg_lo[sg] > fmax or seg_hi[sg] < fmin):
                i = iend + 1
                continue
            for ii in range(i, iend + 1):
                r = rowbase + ii
                c = cnt[r]
                if op != 2:
                    if c == 0:
                        continue
                    o = off[r]
                    k = _first_above(pool, o, c, fmin)
                    if k == c or pool[o + k, 0] > fmax:
                        continue
                ui = lo[ua] + (ii + 0.5) * res
                # w = o - P (cylinder: the tip at t = 0; sphere: the centre at t = 0)
                w_f = -P[f]
                w_u = ui - P[ua]
                w_vv = w_v
                if kind == SPH:
                    w_f -= z0 * a[f]
                    w_u -= z0 * a[ua]
                    w_vv -= z0 * a[va]
                wd = w_f * d[f] + w_u * d[ua] + w_vv * d[va]
                ww = w_f * w_f + w_u * w_u + w_vv * w_vv
                visits += 1
                if kind == CYL:
                    h0 = w_f * a[f] + w_u * a[ua] + w_vv * a[va]
                    uA = w_f - h0 * a[f]
                    uB = -(wd - h0 * da)
                    c0 = (ww - h0 * h0) - R2
                    ok, s0, s1 = cyl_interval(AA, AB, BB, uA, uB, c0, R, h0, hs, ht, z0, z1, has_h, by_t, vs, vt,
                                              inv_hs, a2_h, ok_ext, cs_u, cs_v, ct_u, ct_v, kden)
                else:
                    ok, s0, s1 = capsule_interval(w_f, ww, d[f], wd, dd, R2)
                if not ok:
                    continue
                if op == 0:
                    rem = subtract(pool, off, cnt, cap, r, s0, s1, task, t_top, t_end)
                    if rem < 0.0:
                        return 1, total, maxov, visits
                    dirty[sg] = 1
                    total += rem
                elif op == 1:
                    ov = overlap(pool, off, cnt, r, s0, s1)
                    if ov > maxov:
                        maxov = ov
                        if maxov >= capf:
                            return 0, total, maxov, visits
                else:
                    s0 = max(s0, flo)
                    s1 = min(s1, fhi)
                    if s1 > s0:
                        ad = add(pool, off, cnt, cap, r, s0, s1, task, t_top, t_end)
                        if ad < 0.0:
                            return 1, total, maxov, visits
                        dirty[sg] = 1
                        total += ad
                        seg_lo[sg] = min(seg_lo[sg], s0)
                        seg_hi[sg] = max(seg_hi[sg], s1)
            i = iend + 1
    return 0, total, maxov, visits


@njit(cache=True)
def _move(m, f, jres, jmod, task, lo, res, n, base, sbase, nseg, seg_lo, seg_hi, tbase, tile_lo, tile_hi, dirty,
          off, cnt, cap, pool, t_top, t_end, start, dvec, axv, mode, zcap, pk, pz0, pz1, pr, pcut, grow, depth_cap):
    """One move on one task's rays (``grow[m]``: added to the radius and to both axial ends of the
    pieces it measures). The overlap measured saturates at ``depth_cap`` (divided by the |cos| of
    the tool axis on the family most parallel to it). Returns (status, length removed, largest
    overlap, rays evaluated)."""
    P = start[m]
    d = dvec[m]
    a = axv[m]
    md = mode[m]
    da = d[0] * a[0] + d[1] * a[1] + d[2] * a[2]
    # measuring before cutting when the tool moves towards its spindle (the shank leads)
    meas_first = da > 0.0
    capf = depth_cap
    af = abs(a[f])
    if af >= abs(a[(f + 1) % 3]) and af >= abs(a[(f + 2) % 3]) and af > 0.0:
        capf = depth_cap / af
    removed = 0.0
    maxov = 0.0
    visits = 0
    for phase in range(3):
        for k in range(pk.shape[0]):
            op = -1
            if phase == 1:
                if pcut[k] and (md & M_CUT):
                    op = 0
                elif pcut[k] and (md & M_ADD):
                    op = 2
            elif (phase == 0) == meas_first:
                if (pcut[k] and (md & M_TOOL)) or ((not pcut[k]) and (md & (M_HOLDER | M_TOOL))):
                    op = 1
            if op < 0 or (op == 1 and maxov >= capf):
                continue
            R = pr[k]
            z0 = pz0[k]
            z1 = min(pz1[k], zcap[m])
            if op == 1:
                R += grow[m]
                if pk[k] == CYL:
                    z0 -= grow[m]
                    z1 += grow[m]
            if pk[k] == CYL and z1 <= z0:
                continue
            st, tot, ov, vis = _piece(op, f, jres, jmod, task, lo, res, n, base, sbase, nseg, seg_lo, seg_hi,
                                      tbase, tile_lo, tile_hi, dirty, off, cnt, cap, pool, t_top, t_end, P, d, a,
                                      pk[k], z0, z1, R, capf)
            visits += vis
            removed += tot
            maxov = max(maxov, ov)
            if st != 0:
                return st, removed, maxov, visits
    return 0, removed, maxov, visits


@njit(nogil=True, cache=True)
def run_task(t, lo, res, n, base, sbase, nseg, seg_lo, seg_hi, tbase, tile_lo, tile_hi, dirty, off, cnt, cap, pool,
             t_fam, t_res, t_mod, t_top, t_end, t_next, t_status, mptr, midx, start, dvec, axv, mode, zcap,
             pk, pz0, pz1, pr, pcut, grow, depth_cap, removed, depth, visits):
    """Task t walks its moves ``midx[mptr[t]:mptr[t+1]]`` from ``t_next[t]`` (module docstring);
    tasks run concurrently on threads (the GIL released). ``removed`` (T, M) length removed/added
    per move on this task's rays, ``depth`` (T, M) largest overlap, ``visits`` (T,) rays evaluated."""
    f = t_fam[t]
    q = t_next[t]
    st = 0
    nvis = 0
    while q < mptr[t + 1]:
        m = midx[q]
        st, rem, ov, vis = _move(m, f, t_res[t], t_mod[t], t, lo, res, n, base, sbase, nseg, seg_lo, seg_hi,
                                 tbase, tile_lo, tile_hi, dirty, off, cnt, cap, pool, t_top, t_end, start, dvec,
                                 axv, mode, zcap, pk, pz0, pz1, pr, pcut, grow, depth_cap)
        removed[t, m] += rem
        depth[t, m] = max(depth[t, m], ov)
        nvis += vis
        if st != 0:
            break
        q += 1
        t_next[t] = q              # read by the caller's progress while the task runs
    visits[t] += nvis
    t_next[t] = q
    t_status[t] = st


@njit(cache=True)
def assign_moves(lo, res, n, t_fam, t_res, t_mod, start, dvec, axv, zcap, pk, pz0, pz1, pr, grow):
    """Deal every move to the tasks that own a grid row its swept bounding box meets (program
    order kept). Returns (mptr (T+1,), midx)."""
    M = start.shape[0]
    T = t_fam.shape[0]
    hi = np.empty(3)
    for k in range(3):
        hi[k] = lo[k] + n[k] * res
    rows = np.empty((M, 3, 2), dtype=np.int64)
    counts = np.zeros(T + 1, dtype=np.int64)
    bl = np.empty(3)
    bh = np.empty(3)
    for m in range(M):
        for k in range(3):
            bl[k] = _INF
            bh[k] = -_INF
        for q in range(pk.shape[0]):
            R = pr[q] + grow[m]
            z0 = pz0[q]
            z1 = min(pz1[q], zcap[m])
            if pk[q] == CYL:
                z0 -= grow[m]
                z1 += grow[m]
                if z1 <= z0:
                    continue
            else:
                z1 = z0
            for k in range(3):
                ext = R * math.sqrt(max(0.0, 1.0 - axv[m, k] ** 2)) if pk[q] == CYL else R
                for tq in range(2):
                    for zz in range(2):
                        x = start[m, k] + tq * dvec[m, k] + (z0 if zz == 0 else z1) * axv[m, k]
                        bl[k] = min(bl[k], x - ext)
                        bh[k] = max(bh[k], x + ext)
        inside = True
        for k in range(3):
            if bh[k] < lo[k] or bl[k] > hi[k]:
                inside = False
        for f in range(3):
            va = (f + 2) % 3
            if not inside:
                rows[m, f, 0] = 0
                rows[m, f, 1] = -1
                continue
            jl = max(0, int(math.ceil((bl[va] - lo[va]) / res - 0.5)))
            jh = min(n[va] - 1, int(math.floor((bh[va] - lo[va]) / res - 0.5)))
            rows[m, f, 0] = jl
            rows[m, f, 1] = jh
        for t in range(T):
            f = t_fam[t]
            jl = rows[m, f, 0]
            jh = rows[m, f, 1]
            if jl <= jh and jl + (t_res[t] - jl) % t_mod[t] <= jh:
                counts[t + 1] += 1
    mptr = np.cumsum(counts)
    fill = mptr[:-1].copy()
    midx = np.empty(mptr[-1], dtype=np.int64)
    for m in range(M):
        for t in range(T):
            f = t_fam[t]
            jl = rows[m, f, 0]
            jh = rows[m, f, 1]
            if jl <= jh and jl + (t_res[t] - jl) % t_mod[t] <= jh:
                midx[fill[t]] = m
                fill[t] += 1
    return mptr, midx


# ------------------------------------------------------------------------------------ layout

@njit(cache=True)
def repack(off, cnt, cap, pool, t_fam, t_res, t_mod, base, n, t_top, t_end, t_status, min_slack, frac):
    """A new pool: every task's rays packed in ray order (blocks of their capacity), the task's
    free space after them: at least the used space and twice what it had for a task that
    overflowed, else what it had, and at least ``frac`` x used and ``min_slack`` intervals.
    Returns (off, pool, t_top, t_end); ``cap`` kept."""
    T = t_fam.shape[0]
    size = 0
    region = np.empty(T, dtype=np.int64)
    for t in range(T):
        f = t_fam[t]
        nu = n[(f + 1) % 3]
        nv = n[(f + 2) % 3]
        used = 0
        for j in range(t_res[t], nv, t_mod[t]):
            for r in range(base[f] + j * nu, base[f] + (j + 1) * nu):
                used += cap[r]
        free = t_end[t] - t_top[t]
        if t_status[t] != 0:
            free = max(used, free * 2)
        region[t] = used + max(free, int(frac * used), min_slack)
        size += region[t]
    noff = np.empty_like(off)
    npool = np.empty((size, 2))
    ntop = np.empty(T, dtype=np.int64)
    nend = np.empty(T, dtype=np.int64)
    pos = 0
    for t in range(T):
        f = t_fam[t]
        nu = n[(f + 1) % 3]
        nv = n[(f + 2) % 3]
        first = pos
        for j in range(t_res[t], nv, t_mod[t]):
            for r in range(base[f] + j * nu, base[f] + (j + 1) * nu):
                o = off[r]
                for k in range(cnt[r]):
                    npool[pos + k, 0] = pool[o + k, 0]
                    npool[pos + k, 1] = pool[o + k, 1]
                noff[r] = pos
                pos += cap[r]
        ntop[t] = pos
        pos = first + region[t]
        nend[t] = pos
    return noff, npool, ntop, nend


@njit(cache=True, nogil=True, inline="always")
def _segment_bounds(row0, s, nu, off, cnt, pool):
    """(lowest lower end, highest upper end) of the material of segment ``s`` (rays ``s * SEG`` to
    ``(s + 1) * SEG``) of the ray row starting at ray ``row0``; (+inf, -inf) when empty."""
    lo_ = _INF
    hi_ = -_INF
    for i in range(s * SEG, min(nu, (s + 1) * SEG)):
        r = row0 + i
        c = cnt[r]
        if c > 0:
            lo_ = min(lo_, pool[off[r], 0])
            hi_ = max(hi_, pool[off[r] + c - 1, 1])
    return lo_, hi_


@njit(parallel=True, cache=True)
def refresh_segments(n, base, sbase, nseg, off, cnt, pool, seg_lo, seg_hi, tbase, tile_lo, tile_hi):
    """Recompute every row segment's and tile's material bounds (the lowest lower end and highest
    upper end of its rays; +inf/-inf when empty). Cutting only shrinks material, so bounds between
    refreshes stay conservative."""
    for f in range(3):
        nu = n[(f + 1) % 3]
        nv = n[(f + 2) % 3]
        for j in prange(nv):
            for s in range(nseg[f]):
                sg = sbase[f] + j * nseg[f] + s
                seg_lo[sg], seg_hi[sg] = _segment_bounds(base[f] + j * nu, s, nu, off, cnt, pool)
    for f in range(3):
        nv = n[(f + 2) % 3]
        for tj in prange((nv + TROWS - 1) // TROWS):
            for s in range(nseg[f]):
                lo_ = _INF
                hi_ = -_INF
                for j in range(tj * TROWS, min(nv, (tj + 1) * TROWS)):
                    sg = sbase[f] + j * nseg[f] + s
                    lo_ = min(lo_, seg_lo[sg])
                    hi_ = max(hi_, seg_hi[sg])
                tile_lo[tbase[f] + tj * nseg[f] + s] = lo_
                tile_hi[tbase[f] + tj * nseg[f] + s] = hi_


@njit(cache=True)
def refresh_dirty(n, base, sbase, nseg, off, cnt, pool, seg_lo, seg_hi, tbase, tile_lo, tile_hi, dirty):
    """:func:`refresh_segments` for the segments flagged in ``dirty`` (u1, one per segment) and the
    tiles holding them only; the flags are cleared. The bounds of a segment none of whose rays
    changed are already exact, so the result equals a full refresh. Returns the segments redone."""
    done = 0
    for f in range(3):
        nu = n[(f + 1) % 3]
        nv = n[(f + 2) % 3]
        ns = nseg[f]
        for tj in range((nv + TROWS - 1) // TROWS):
            j0 = tj * TROWS
            j1 = min(nv, j0 + TROWS)
            for s in range(ns):
                hit = False
                for j in range(j0, j1):
                    sg = sbase[f] + j * ns + s
                    if dirty[sg] == 0:
                        continue
                    dirty[sg] = 0
                    hit = True
                    done += 1
                    seg_lo[sg], seg_hi[sg] = _segment_bounds(base[f] + j * nu, s, nu, off, cnt, pool)
                if hit:
                    lo_ = _INF
                    hi_ = -_INF
                    for j in range(j0, j1):
                        sg = sbase[f] + j * ns + s
                        lo_ = min(lo_, seg_lo[sg])
                        hi_ = max(hi_, seg_hi[sg])
                    tile_lo[tbase[f] + tj * ns + s] = lo_
                    tile_hi[tbase[f] + tj * ns + s] = hi_
    return done


# ------------------------------------------------------------------------------------ builders

@njit(cache=True)
def union_csr(ptr_a, iv_a, ptr_b, iv_b):
    """Per ray the union of two sorted interval lists (CSR in, CSR out)."""
    R = ptr_a.shape[0] - 1
    out_ptr = np.zeros(R + 1, dtype=np.int64)
    out = np.empty((iv_a.shape[0] + iv_b.shape[0], 2))
    pos = 0
    for r in range(R):
        ia = ptr_a[r]
        ib = ptr_b[r]
        ea = ptr_a[r + 1]
        eb = ptr_b[r + 1]
        have = False
        clo = 0.0
        chi = 0.0
        while ia < ea or ib < eb:
            if ib >= eb or (ia < ea and iv_a[ia, 0] <= iv_b[ib, 0]):
                x0 = iv_a[ia, 0]
                x1 = iv_a[ia, 1]
                ia += 1
            else:
                x0 = iv_b[ib, 0]
                x1 = iv_b[ib, 1]
                ib += 1
            if have and x0 <= chi:
                chi = max(chi, x1)
            else:
                if have:
                    out[pos, 0] = clo
                    out[pos, 1] = chi
                    pos += 1
                clo = x0
                chi = x1
                have = True
        if have:
            out[pos, 0] = clo
            out[pos, 1] = chi
            pos += 1
        out_ptr[r + 1] = pos
    return out_ptr, out[:pos].copy()


@njit(cache=True)
def _edge_sign(pu, pv, qu, qv, xu, xv):
    """Sign of the canonical edge function of edge (p, q) at x, with the tie broken by the
    perturbation x + (eps, eps^2): consistent for the two triangles sharing the edge."""
    if (pu > qu) or (pu == qu and pv > qv):
        pu, qu = qu, pu
        pv, qv = qv, pv
    e = (qu - pu) * (xv - pv) - (qv - pv) * (xu - pu)
    if e > 0.0:
        return 1
    if e < 0.0:
        return -1
    # d/d(eps) of E(x + (eps, eps^2)) = (qu - pu) eps^2 - (qv - pv) eps
    if qv != pv:
        return 1 if -(qv - pv) > 0.0 else -1
    return 1 if (qu - pu) > 0.0 else -1


@njit(cache=True)
def mesh_crossings(V, F, lo, res, n, f):
    """Crossings of family f's rays with a triangle mesh: (ptr (R_f+1,), coords). A ray through an
    edge or a vertex is counted in exactly one of the triangles that share it (perturbation)."""
    ua = (f + 1) % 3
    va = (f + 2) % 3
    nu = n[ua]
    nv = n[va]
    R = nu * nv
    counts = np.zeros(R + 1, dtype=np.int64)
    for pass_ in range(2):
        if pass_ == 1:
            ptr = np.cumsum(counts)
            coords = np.empty(ptr[-1])
            fill = ptr[:-1].copy()
        for tri in range(F.shape[0]):
            a = F[tri, 0]
            b = F[tri, 1]
            c = F[tri, 2]
            au, av, af = V[a, ua], V[a, va], V[a, f]
            bu, bv, bf = V[b, ua], V[b, va], V[b, f]
            cu_, cv_, cf = V[c, ua], V[c, va], V[c, f]
            area = (bu - au) * (cv_ - av) - (bv - av) * (cu_ - au)
            if area == 0.0:
                continue
            s_ab = _edge_sign(au, av, bu, bv, cu_, cv_)
            s_bc = _edge_sign(bu, bv, cu_, cv_, au, av)
            s_ca = _edge_sign(cu_, cv_, au, av, bu, bv)
            i0 = max(0, int(math.ceil((min(au, bu, cu_) - lo[ua]) / res - 0.5)))
            i1 = min(nu - 1, int(math.floor((max(au, bu, cu_) - lo[ua]) / res - 0.5)))
            j0 = max(0, int(math.ceil((min(av, bv, cv_) - lo[va]) / res - 0.5)))
            j1 = min(nv - 1, int(math.floor((max(av, bv, cv_) - lo[va]) / res - 0.5)))
            for j in range(j0, j1 + 1):
                y = lo[va] + (j + 0.5) * res
                for i in range(i0, i1 + 1):
                    x = lo[ua] + (i + 0.5) * res
                    if _edge_sign(au, av, bu, bv, x, y) != s_ab:
                        continue
                    if _edge_sign(bu, bv, cu_, cv_, x, y) != s_bc:
                        continue
                    if _edge_sign(cu_, cv_, au, av, x, y) != s_ca:
                        continue
                    r = j * nu + i
                    if pass_ == 0:
                        counts[r + 1] += 1
                    else:
                        # barycentric weights
                        wa = ((bu - x) * (cv_ - y) - (bv - y) * (cu_ - x)) / area
                        wb = ((cu_ - x) * (av - y) - (cv_ - y) * (au - x)) / area
                        wc = 1.0 - wa - wb
                        coords[fill[r]] = wa * af + wb * bf + wc * cf
                        fill[r] += 1
    return ptr, coords


@njit(cache=True)
def pair_crossings(ptr, coords, flo, fhi):
    """Sort each ray's crossings and pair them into intervals (clipped to [flo, fhi]). Returns
    (out_ptr, intervals, number of rays with an odd count)."""
    R = ptr.shape[0] - 1
    out_ptr = np.zeros(R + 1, dtype=np.int64)
    out = np.empty((coords.shape[0] // 2 + 1, 2))
    pos = 0
    odd = 0
    for r in range(R):
        c = coords[ptr[r]:ptr[r + 1]].copy()
        c.sort()
        if c.shape[0] % 2 == 1:
            odd += 1
        for k in range(c.shape[0] // 2):
            x0 = max(c[2 * k], flo)
            x1 = min(c[2 * k + 1], fhi)
            if x1 - x0 > EPS_LEN:
                if pos > 0 and out_ptr[r] < pos and x0 <= out[pos - 1, 1]:
                    out[pos - 1, 1] = max(out[pos - 1, 1], x1)
                else:
                    out[pos, 0] = x0
                    out[pos, 1] = x1
                    pos += 1
        out_ptr[r + 1] = pos
    return out_ptr, out[:pos].copy(), odd


@njit(cache=True)
def shell_crossings(ptr, coords, flo, fhi, half):
    """Each ray's crossings widened to [c - half, c + half] (clipped to [flo, fhi], merged):
    (out_ptr, intervals)."""
    R = ptr.shape[0] - 1
    out_ptr = np.zeros(R + 1, dtype=np.int64)
    out = np.empty((coords.shape[0], 2))
    pos = 0
    for r in range(R):
        c = coords[ptr[r]:ptr[r + 1]].copy()
        c.sort()
        for k in range(c.shape[0]):
            x0 = max(c[k] - half, flo)
            x1 = min(c[k] + half, fhi)
            if x1 - x0 > EPS_LEN:
                if out_ptr[r] < pos and x0 <= out[pos - 1, 1]:
                    out[pos - 1, 1] = max(out[pos - 1, 1], x1)
                else:
                    out[pos, 0] = x0
                    out[pos, 1] = x1
                    pos += 1
        out_ptr[r + 1] = pos
    return out_ptr, out[:pos].copy()


# ------------------------------------------------------------------------------------ read-back

@njit(cache=True)
def _boundary_near(pool, off, cnt, r, x, side, win):
    """The interval end of the given side (1: upper ends, 0: lower ends) nearest x within win on
    ray r: (found, coordinate, inside) where inside tells whether x is in material."""
    c = cnt[r]
    o = off[r]
    k = _first_above(pool, o, c, x)  # first interval with hi > x
    inside = k < c and pool[o + k, 0] <= x
    best = _INF
    bx = 0.0
    for q in range(max(0, k - 1), min(c, k + 2)):
        y = pool[o + q, side]
        dist = abs(y - x)
        if dist <= win and dist < best:
            best = dist
            bx = y
    return best < _INF, bx, inside


@njit(parallel=True, cache=True)
def deviation(lo, res, n, base, off, cnt, pool, pts, nrm, max_mm, out, out_hi):
    """Signed deviation of points from the material surface (see dexel.signed_deviation): ``out``
    interpolated over the 4 rays around each point, ``out_hi`` the highest of their readings."""
    N = pts.shape[0]
    for p in prange(N):
        nx, ny, nz = nrm[p, 0], nrm[p, 1], nrm[p, 2]
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        if not (ln > 1e-12) or not math.isfinite(pts[p, 0] + pts[p, 1] + pts[p, 2]):
            out[p] = np.nan
            out_hi[p] = np.nan
            continue
        f = 0
        best = abs(nx)
        if abs(ny) > best:
            f = 1
            best = abs(ny)
        if abs(nz) > best:
            f = 2
        cf = nrm[p, f] / ln
        ua = (f + 1) % 3
        va = (f + 2) % 3
        outside = False
        for k in range(3):
            if pts[p, k] < lo[k] - res or pts[p, k] > lo[k] + (n[k] + 1) * res:
                outside = True
        if outside:
            out[p] = np.nan
            out_hi[p] = np.nan
            continue
        side = 1 if cf > 0.0 else 0
        fu = (pts[p, ua] - lo[ua]) / res - 0.5
        fv = (pts[p, va] - lo[va]) / res - 0.5
        i0 = int(math.floor(fu))
        j0 = int(math.floor(fv))
        al = fu - i0
        be = fv - j0
        x = pts[p, f]
        win = (max_mm + 2.0 * res) / abs(cf)
        zs = 0.0
        ws = 0.0
        hi = -np.inf
        w_in = 0.0
        w_out = 0.0
        for dj in range(2):
            for di in range(2):
                w = (al if di else 1.0 - al) * (be if dj else 1.0 - be)
                i = i0 + di
                j = j0 + dj
                if i < 0 or j < 0 or i >= n[ua] or j >= n[va]:
                    w_out += w
                    continue
                r = base[f] + j * n[ua] + i
                found, bx, inside = _boundary_near(pool, off, cnt, r, x, side, win)
                if found:
                    zs += w * bx
                    ws += w
                    hi = max(hi, (bx - x) * cf)
                elif inside:
                    w_in += w
                else:
                    w_out += w
        if ws > 1e-9:
            dev = (zs / ws - x) * cf
        elif w_in >= w_out:
            dev = max_mm
        else:
            dev = -max_mm
        out[p] = min(max_mm, max(-max_mm, dev))
        out_hi[p] = min(max_mm, max(-max_mm, hi)) if ws > 1e-9 else out[p]


@njit(parallel=True, cache=True)
def occupancy(lo, res, n, base, off, cnt, pool, step):
    """Material at the lattice nodes (every ``step``-th ray and node) read on the Z rays:
    (nx, ny, nz) uint8."""
    nx = (n[0] + step - 1) // step
    ny = (n[1] + step - 1) // step
    nz = (n[2] + step - 1) // step
    occ = np.zeros((nx, ny, nz), dtype=np.uint8)
    for ii in prange(nx):
        i = ii * step
        for jj in range(ny):
            j = jj * step
            r = base[2] + j * n[0] + i
            o = off[r]
            c = cnt[r]
            k = 0
            for kk in range(nz):
                z = lo[2] + (kk * step + 0.5) * res
                while k < c and pool[o + k, 1] < z:
                    k += 1
                if k < c and pool[o + k, 0] <= z:
                    occ[ii, jj, kk] = 1
    return occ


@njit(cache=True)
def snap_vertices(verts, lo, res, n, base, off, cnt, pool, step):
    """Move marching-cubes vertices (lattice index space, on edge midpoints) to the exact crossing
    of the ray that runs along their edge; a vertex whose ray shows no crossing there stays."""
    out = np.empty((verts.shape[0], 3))
    for q in range(verts.shape[0]):
        for k in range(3):
            out[q, k] = lo[k] + (verts[q, k] * step + 0.5) * res
        f = -1
        for k in range(3):
            fr = verts[q, k] - math.floor(verts[q, k])
            if abs(fr - 0.5) < 0.25:
                f = k
        if f < 0:
            continue
        ua = (f + 1) % 3
        va = (f + 2) % 3
        i = int(round(verts[q, ua])) * step
        j = int(round(verts[q, va])) * step
        if i < 0 or j < 0 or i >= n[ua] or j >= n[va]:
            continue
        x0 = lo[f] + (math.floor(verts[q, f]) * step + 0.5) * res
        x1 = x0 + step * res
        r = base[f] + j * n[ua] + i
        o = off[r]
        mid = 0.5 * (x0 + x1)
        best = _INF
        for k in range(cnt[r]):
            for sd in range(2):
                y = pool[o + k, sd]
                if x0 < y < x1 and abs(y - mid) < best:
                    best = abs(y - mid)
                    out[q, f] = y
        if best < _INF:
            # keep the vertex strictly inside its edge (no zero-length triangle sides)
            eps = 1e-3 * step * res
            out[q, f] = min(max(out[q, f], x0 + eps), x1 - eps)
    return out


# ------------------------------------------------------------------------------------ column rise

@njit(cache=True, inline="always")
def _hull_bottom(rho, pk, pz0, pr, grow):
    """The lowest height (mm along the tool axis from the tip) of the tool's pieces grown by ``grow``
    at distance ``rho`` from the axis (the radius-monotone hull of the tool: every piece counts from
    its bottom up); inf when no piece reaches that far out."""
    best = _INF
    for k in range(pk.shape[0]):
        R = pr[k] + grow
        if rho > R:
            continue
        if pk[k] == SPH:
            z = pz0[k] - math.sqrt(max(0.0, R * R - rho * rho))
        else:
            z = pz0[k] - grow
        if z < best:
            best = z
    return best


@njit(cache=True, inline="always")
def _seg_dist(px, py, dl):
    """Distance in the plane from (px, py) to the segment from (0, 0) to (dl, 0), dl >= 0."""
    x = min(max(px, 0.0), dl)
    return math.sqrt((px - x) * (px - x) + py * py)


@njit(cache=True, inline="always")
def _clip_quad(a, b, c, lo_t, hi_t):
    """[lo_t, hi_t] cut to where a t^2 + 2 b t + c <= 0 (a >= 0); (1, 0) when empty."""
    if a <= 1e-12:
        if c <= 0.0:
            return lo_t, hi_t
        return 1.0, 0.0
    disc = b * b - a * c
    if disc < 0.0:
        return 1.0, 0.0
    sq = math.sqrt(disc)
    return max(lo_t, (-b - sq) / a), min(hi_t, (-b + sq) / a)


@njit(cache=True)
def _rise_one(q, lo, res, n, base, off, cnt, pool, tips, ax, length, sweep, pk, pz0, pz1, pr, grow, tol, reach,
              sbase, nseg, seg_lo, seg_hi):
    """:func:`column_rise` for query ``q``. A row segment of SEG rays (``sbase``, ``nseg``, ``seg_lo``,
    ``seg_hi``: the model's bounds of the material along its rays, +inf/-inf when empty) whose material
    lies wholly outside the swept column's extent along the rays (grown by the largest radius and a ray
    spacing) is passed over without reading its rays: none of them can meet the tool."""
    S = length[q]
    rmax = 0.0
    zbot = _INF
    ztop = -_INF
    for k in range(pk.shape[0]):
        rmax = max(rmax, pr[k] + grow)
        if pk[k] == SPH:
            zbot = min(zbot, pz0[k] - pr[k] - grow)
            ztop = max(ztop, pz0[k] + pr[k] + grow)
        else:
            zbot = min(zbot, pz0[k] - grow)
            ztop = max(ztop, pz1[k] + grow)
    # material touched lies between zbot and S + ztop along the axis (from the tip)
    zlim = min(S + ztop, reach)
    # the plane across the axis: e1 along the sweep (any direction when there is none), e2 = ax x e1;
    # the reference point sweeps from (0, 0) to (dl, 0) in it
    D0, D1, D2 = sweep[q, 0], sweep[q, 1], sweep[q, 2]
    dl = math.sqrt(D0 * D0 + D1 * D1 + D2 * D2)
    if dl > 1e-12:
        e10, e11, e12 = D0 / dl, D1 / dl, D2 / dl
    else:
        dl = 0.0
        k = 0
        if abs(ax[1]) < abs(ax[k]):
            k = 1
        if abs(ax[2]) < abs(ax[k]):
            k = 2
        # a unit vector across the axis: the least aligned axis less its component along ax
        e10 = (1.0 if k == 0 else 0.0) - ax[k] * ax[0]
        e11 = (1.0 if k == 1 else 0.0) - ax[k] * ax[1]
        e12 = (1.0 if k == 2 else 0.0) - ax[k] * ax[2]
        m = math.sqrt(e10 * e10 + e11 * e11 + e12 * e12)
        e10, e11, e12 = e10 / m, e11 / m, e12 / m
    e20 = ax[1] * e12 - ax[2] * e11
    e21 = ax[2] * e10 - ax[0] * e12
    e22 = ax[0] * e11 - ax[1] * e10
    e1 = (e10, e11, e12)
    e2 = (e20, e21, e22)
    # best is the highest position found so far at which the tool meets material; met only below the
    # start (s < 0) is not on the way
    best = 0.0
    met = False
    stack_a = np.empty(64)
    stack_b = np.empty(64)
    w = np.empty(3)
    r2 = rmax * rmax
    for f in range(3):
        ua = (f + 1) % 3
        va = (f + 2) % 3
        uf = ax[f]
        bx = e1[f]
        by = e2[f]
        a = bx * bx + by * by          # the ray's speed across the axis (1 - uf^2)
        # bounding box of the swept column (both ends of the sweep, zbot to zlim up the axis), grown
        lo_u = _INF
        hi_u = -_INF
        lo_v = _INF
        hi_v = -_INF
        lo_f = _INF
        hi_f = -_INF
        for lam in (0.0, 1.0):
            for zz in (zbot, zlim):
                cu = tips[q, ua] + lam * sweep[q, ua] + zz * ax[ua]
                cv = tips[q, va] + lam * sweep[q, va] + zz * ax[va]
                cf = tips[q, f] + lam * sweep[q, f] + zz * ax[f]
                lo_u = min(lo_u, cu)
                hi_u = max(hi_u, cu)
                lo_v = min(lo_v, cv)
                hi_v = max(hi_v, cv)
                lo_f = min(lo_f, cf)
                hi_f = max(hi_f, cf)
        # along the rays every point of the tool lies within rmax of that parallelogram
        lo_f -= rmax + res
        hi_f += rmax + res
        i0 = max(0, int(math.ceil((lo_u - rmax - lo[ua]) / res - 0.5)))
        i1 = min(n[ua] - 1, int(math.floor((hi_u + rmax - lo[ua]) / res - 0.5)))
        j0 = max(0, int(math.ceil((lo_v - rmax - lo[va]) / res - 0.5)))
        j1 = min(n[va] - 1, int(math.floor((hi_v + rmax - lo[va]) / res - 0.5)))
        for j in range(j0, j1 + 1):
            i_at = i0
            while i_at <= i1:
                sg = sbase[f] + j * nseg[f] + i_at // SEG
                i_end = min(i1, (i_at // SEG) * SEG + SEG - 1)
                if seg_lo[sg] > hi_f or seg_hi[sg] < lo_f:
                    i_at = i_end + 1
                    continue
                first = i_at
                i_at = i_end + 1
                for i in range(first, i_end + 1):
                    r = base[f] + j * n[ua] + i
                    c = cnt[r]
                    if c == 0:
                        continue
                    # the ray O + t e_f (O at 0 along f), w = O - tip: across the axis at
                    # (ax_, ay_) + t (bx, by), along it at zw + t uf
                    w[f] = -tips[q, f]
                    w[ua] = lo[ua] + (i + 0.5) * res - tips[q, ua]
                    w[va] = lo[va] + (j + 0.5) * res - tips[q, va]
                    zw = w[0] * ax[0] + w[1] * ax[1] + w[2] * ax[2]
                    ax_ = w[0] * e1[0] + w[1] * e1[1] + w[2] * e1[2]
                    ay_ = w[0] * e2[0] + w[1] * e2[1] + w[2] * e2[2]
                    # where the ray is within rmax of the sweep across the axis (a convex set: one interval,
                    # the hull of the two end discs and the strip between them)
                    ta, tb = _clip_quad(a, ax_ * bx + ay_ * by, ax_ * ax_ + ay_ * ay_ - r2, -_INF, _INF)
                    if dl > 0.0:
                        t1a, t1b = _clip_quad(a, (ax_ - dl) * bx + ay_ * by, (ax_ - dl) * (ax_ - dl) + ay_ * ay_ - r2,
                                              -_INF, _INF)
                        if t1a <= t1b:
                            if ta <= tb:
                                ta, tb = min(ta, t1a), max(tb, t1b)
                            else:
                                ta, tb = t1a, t1b
                        # the strip: 0 <= ax_ + t bx <= dl and |ay_ + t by| <= rmax
                        sa, sb = _clip_quad(by * by, ay_ * by, ay_ * ay_ - r2, -_INF, _INF)
                        if abs(bx) > 1e-12:
                            x1 = -ax_ / bx
                            x2 = (dl - ax_) / bx
                            sa = max(sa, min(x1, x2))
                            sb = min(sb, max(x1, x2))
                        elif ax_ < 0.0 or ax_ > dl:
                            sa, sb = 1.0, 0.0
                        if sa <= sb:
                            if ta <= tb:
                                ta, tb = min(ta, sa), max(tb, sb)
                            else:
                                ta, tb = sa, sb
                    if not ta <= tb:
                        continue
                    # between zbot and zlim along the axis
                    if abs(uf) > 1e-12:
                        t1 = (zbot - zw) / uf
                        t2 = (zlim - zw) / uf
                        ta = max(ta, min(t1, t2))
                        tb = min(tb, max(t1, t2))
                    elif zw < zbot or zw > zlim:
                        continue
                    if not ta < tb:
                        continue
                    o = off[r]
                    k = _first_above(pool, o, c, ta)
                    while k < c and pool[o + k, 0] < tb:
                        s0 = max(pool[o + k, 0], ta)
                        s1 = min(pool[o + k, 1], tb)
                        k += 1
                        if not s0 < s1:
                            continue
                        stack_a[0] = s0
                        stack_b[0] = s1
                        top = 1
                        while top > 0:
                            top -= 1
                            x0 = stack_a[top]
                            x1 = stack_b[top]
                            # the nearest point of the piece to the sweep across the axis: an end of the
                            # piece, the point of it nearest an end of the sweep, or where they cross
                            tv = x0
                            dmin = _seg_dist(ax_ + x0 * bx, ay_ + x0 * by, dl)
                            dd = _seg_dist(ax_ + x1 * bx, ay_ + x1 * by, dl)
                            if dd < dmin:
                                dmin, tv = dd, x1
                            if a > 1e-12:
                                for cx in (0.0, dl):
                                    tt = min(max(-((ax_ - cx) * bx + ay_ * by) / a, x0), x1)
                                    dd = _seg_dist(ax_ + tt * bx, ay_ + tt * by, dl)
                                    if dd < dmin:
                                        dmin, tv = dd, tt
                                if dl > 0.0 and abs(by) > 1e-12:
                                    tt = -ay_ / by
                                    if x0 <= tt <= x1 and 0.0 <= ax_ + tt * bx <= dl:
                                        dmin, tv = 0.0, tt
                            hb = _hull_bottom(dmin, pk, pz0, pr, grow)
                            if hb == _INF:
                                continue
                            upper = max(zw + x0 * uf, zw + x1 * uf) - hb
                            if upper < best or (upper == best and met):
                                continue
                            # lower: the height needed at the ends and at the nearest point
                            lower = zw + tv * uf - hb
                            for x in (x0, x1):
                                hx = _hull_bottom(_seg_dist(ax_ + x * bx, ay_ + x * by, dl), pk, pz0, pr, grow)
                                if hx < _INF:
                                    lower = max(lower, zw + x * uf - hx)
                            if upper - lower <= tol or top >= 62:
                                best = upper
                                met = True
                            else:
                                mid = 0.5 * (x0 + x1)
                                stack_a[top] = x0
                                stack_b[top] = mid
                                stack_a[top + 1] = mid
                                stack_b[top + 1] = x1
                                top += 2
                        if met and best >= S:
                            return S
    return best if met else -_INF


@njit(cache=True)
def column_rise(lo, res, n, base, off, cnt, pool, tips, ax, length, sweep, pk, pz0, pz1, pr, grow, tol, reach,
                sbase, nseg, seg_lo, seg_hi, out):
    """Per query ``q`` the highest position ``s`` in ``[0, length[q]]`` (mm along the unit tool axis
    ``ax`` from the tip ``tips[q]``) at which the tool's pieces (``pk``, ``pz0``, ``pz1``, ``pr`` as
    :func:`planning.simulate.dexel.tool_pieces`), grown by ``grow``, meet the material on a ray
    anywhere along ``sweep[q]`` (a vector across the axis: the tip at ``tips[q] + l sweep[q] + s ax``,
    ``l`` in [0, 1]; zero: a column); -inf when no position does. The tool is taken as its
    radius-monotone hull (a piece counts from its bottom up to the top of the highest one), so the
    answer is never below the exact one and at most ``tol`` above it: along each interval of
    material the height ``s = z - bottom(rho)`` (``z`` along the axis, ``rho`` its distance across
    the axis from the sweep) is bounded by the highest ``z`` less the bottom at the nearest point,
    and halved until that bound is within ``tol`` of the value at the piece's ends and nearest
    point. ``reach``: a length along the axis beyond which the domain holds nothing (bounds an
    infinite holder)."""
    for q in range(tips.shape[0]):
        out[q] = _rise_one(q, lo, res, n, base, off, cnt, pool, tips, ax, length, sweep, pk, pz0, pz1, pr, grow,
                           tol, reach, sbase, nseg, seg_lo, seg_hi)


@njit(parallel=True, cache=True)
def column_rise_parallel(lo, res, n, base, off, cnt, pool, tips, ax, length, sweep, pk, pz0, pz1, pr, grow, tol,
                         reach, sbase, nseg, seg_lo, seg_hi, out):
    """:func:`column_rise` over the queries on every thread."""
    for q in prange(tips.shape[0]):
        out[q] = _rise_one(q, lo, res, n, base, off, cnt, pool, tips, ax, length, sweep, pk, pz0, pz1, pr, grow,
                           tol, reach, sbase, nseg, seg_lo, seg_hi)
