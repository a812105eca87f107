"""Numba kernels of the exact gouge confirmation (:mod:`planning.simulate.gouge` holds the public
function and the formulas; everything here works on plain arrays it prepares).

**Moves and pieces.** The feed moves of every tool, one array (``S`` tips at the start, ``E`` at the
end, ``A`` unit axes; M moves). Each move is cut into ``n = max(1, ceil(length / PIECE_MM))`` equal
pieces, mid point ``mid = s + ((k + 1/2) / n) (e - s)`` (the same operations as the numpy code before,
so the same bits), half length ``half``. A tool gives *layers*:

* ``NEAR`` (a ball-end cutter's ball): a piece's point is its mid point, a move is a candidate when
  one of its pieces lies within ``rq`` of the point (the rule of :mod:`planning.simulate.gouge`), its
  depth is ``R - dist(p, centre segment)``; ``pball`` keeps the ball's centre at each piece's mid;
* ``SIDE`` (the fluted cylinder above that ball, radius R, from the ball's centre up to ``L - R``)
  and ``FLAT`` (a flat or bull-nose end mill's cylinder, radius Rt, up to L): a piece's point is the
  centre of the cylinder at its mid, and a move is measured when the point lies within the sphere
  ``hypot(radius, length / 2) + half`` of one of its pieces and within ``radius + half`` of that
  piece's axis segment: outside all of them the point is never inside the cylinder (-inf). A SIDE
  move that turns the axis (``A0``, the axis it starts with, differs from ``A``) has both radii and
  the bound widened by ``tw = hypot(L, R) |A0 - A|`` and is sampled with its turning axis
  (:func:`_side_turning`).

A layer's pieces are sorted by the cell of a uniform grid (``lo``, ``cell``, ``dims``; cell number
``(ix * ny + iy) * nz + iz``, a counting sort), ``cstart`` the first piece of every cell, so the cells
of one (ix, iy) column within a z range are one run of pieces. NEAR layers come first.

**Points.** A point visits a layer's columns ring by ring around its own (the nearest first), the
z range of each within the search radius, and measures each move once (a stamp per move and layer,
per chunk of points). The cylinders are sampled as :mod:`planning.simulate.gouge` says (65 samples
on the part of the move where the point is within the radius of the axis).

**Bounds** (each skip needs the bound below the point's deepest depth so far by more than
:data:`BOUND_SLACK_MM`, far above the rounding of either side, so the maximum is unchanged):

* a cylinder's samples: none can be inside when the axial height ``h`` (linear along the move)
  stays outside [0, L] (with :data:`H_SLACK_MM`); none reads deeper than ``Rt - min r`` (the least
  radial distance over the part of the move, in closed form), nor, for a flat end, than ``max h``;
* a cylinder piece: over the piece's part of the move the depth is at most ``radius + half`` minus
  the radial distance at its mid (a flat end: and at most ``h + half``);
* a ball piece: at most ``R + half`` minus the distance to the ball's centre at its mid, so cells
  and rings farther than ``2 R + half - best`` are passed over. A move passed over on every piece
  within ``rq`` may still have its deepest point on a piece beyond ``rq``, where the depth is below
  the layer's *floor* ``2 R + PIECE_MM / 2 - rq = 2 R - reach``: a point whose result is not above
  the highest floor is measured again without these ball bounds (the floor is negative once the
  flutes are longer than ``sqrt(3) R``, so such a point is not cut; it is rare).

So the result is the maximum over the same candidate moves as measuring every pair, whatever the
order of the moves or the thread count.

**Parallel.** The points, sorted along a grid, are dealt in blocks of :data:`BLOCK` to ``nchunk``
chunks, chunk ``c`` taking blocks ``c, c + nchunk, ...`` (every chunk spans the whole part, so the
static split of ``prange`` over the chunks is balanced); each chunk has its own stamps. The pieces
are filled in parallel over the moves (:func:`fill_pieces`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

#: Layer modes (module docstring): the ball of a ball-end cutter; the side of the fluted cylinder above
#: that ball; the cylinder of a flat or bull-nose end mill (bottom face and side).
NEAR, SIDE, FLAT = 0, 1, 2
#: Points per block (consecutive along the grid order).
BLOCK = 16
#: A bound skips only when it is below the point's best depth by more than this (mm); a bound and the
#: depths it bounds differ by rounding only (~1e-12 mm at 1 m from the origin).
BOUND_SLACK_MM = 1e-7
#: A cylinder's samples are all outside axially when ``h`` misses [0, L] by more than this (mm).
H_SLACK_MM = 1e-7
#: Added to the radii of a cylinder piece's bounding sphere and axis capsule (mm), above the rounding.
SPHERE_SLACK_MM = 1e-6

_NEG_INF = -np.inf


@njit(cache=True, inline="always")
def _dot(x0, x1, x2, y0, y1, y2):
    return x0 * y0 + x1 * y1 + x2 * y2


@njit(cache=True, inline="always")
def _ball(px, py, pz, sx, sy, sz, vx, vy, vz, w0x, w0y, w0z, R):
    """``R`` minus the distance from ``p`` to the segment from ``s`` along ``v`` (the ball's centres;
    ``w0 = p - s``)."""
    L2 = _dot(vx, vy, vz, vx, vy, vz)
    t = _dot(w0x, w0y, w0z, vx, vy, vz) / max(L2, 1e-300)
    t = min(max(t, 0.0), 1.0)
    qx, qy, qz = sx + t * vx, sy + t * vy, sz + t * vz
    dx, dy, dz = px - qx, py - qy, pz - qz
    return R - math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True, inline="always")
def _cylinder(vx, vy, vz, w0x, w0y, w0z, ax, ay, az, Rt, L, side_only, f, best):
    """Depth of ``p`` inside the cylinder (radius ``Rt``, from the base up to ``L`` along the unit axis
    ``a``) whose base moves from ``s`` along ``v`` (``w0 = p - s``), sampled at the ``f`` fractions of
    the part of the move where ``p`` is within ``Rt`` of the axis: the nearer of the bottom face and
    the side (the side only with ``side_only``); ``-inf`` where never inside, or where a bound says the
    depth stays below ``best - BOUND_SLACK_MM`` (module docstring)."""
    va = _dot(vx, vy, vz, ax, ay, az)
    wa = _dot(w0x, w0y, w0z, ax, ay, az)
    # the axial height h(t) = wa - t va over the whole move: outside [0, L] throughout, never inside
    if max(wa, wa - va) < -H_SLACK_MM or min(wa, wa - va) > L + H_SLACK_MM:
        return _NEG_INF
    vvx, vvy, vvz = vx - va * ax, vy - va * ay, vz - va * az            # the move across the axis
    wwx, wwy, wwz = w0x - wa * ax, w0y - wa * ay, w0z - wa * az
    A = _dot(vvx, vvy, vvz, vvx, vvy, vvz)
    B = -2.0 * _dot(wwx, wwy, wwz, vvx, vvy, vvz)
    C = _dot(wwx, wwy, wwz, wwx, wwy, wwz) - Rt * Rt
    disc = B * B - 4.0 * A * C
    moving = A > 1e-18
    if moving:
        if not disc >= 0.0:
            return _NEG_INF
        root = math.sqrt(max(disc, 0.0))
        t0 = (-B - root) / (2.0 * max(A, 1e-300))
        t1 = (-B + root) / (2.0 * max(A, 1e-300))
    else:
        if not C <= 0.0:
            return _NEG_INF
        t0, t1 = 0.0, 1.0
    t0 = min(max(t0, 0.0), 1.0)
    t1 = min(max(t1, 0.0), 1.0)
    if not t1 >= t0:
        return _NEG_INF
    # bounds over t in [t0, t1]: h(t) = wa - t va (linear), r(t) = |ww - t vv| (least at tc)
    h0 = wa - t0 * va
    h1 = wa - t1 * va
    hlo, hhi = min(h0, h1), max(h0, h1)
    if hhi < -H_SLACK_MM or hlo > L + H_SLACK_MM:
        return _NEG_INF
    tc = t0
    if moving:
        tc = min(max(-B / (2.0 * A), t0), t1)
    rx, ry, rz = wwx - tc * vvx, wwy - tc * vvy, wwz - tc * vvz
    bound = Rt - math.sqrt(rx * rx + ry * ry + rz * rz)
    if not side_only:
        bound = min(bound, min(hhi, L))
    if bound < best - BOUND_SLACK_MM:
        return _NEG_INF
    dt = t1 - t0
    out = _NEG_INF
    lim = Rt + 1e-12
    for k in range(f.shape[0]):
        t = t0 + dt * f[k]
        wx, wy, wz = w0x - t * vx, w0y - t * vy, w0z - t * vz             # p - q(t)
        h = _dot(wx, wy, wz, ax, ay, az)
        dx, dy, dz = wx - h * ax, wy - h * ay, wz - h * az
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        if h >= 0.0 and h <= L and r <= lim:
            d = Rt - r
            if not side_only:
                d = min(h, d)
            if d > out:
                out = d
    return out


@njit(cache=True)
def _side_turning(vx, vy, vz, w0x, w0y, w0z, a0x, a0y, a0z, ax, ay, az, Rt, L, w, f):
    """Depth of ``p`` inside the side of a ball's flutes (radius ``Rt``, from the ball's centre up to ``L``)
    on a step that turns the axis from ``a0`` to ``a`` while the centre runs from ``s`` along ``v``
    (``w0 = p - s``): the axis at ``t`` is ``a0 + t (a - a0)`` normalised (the great circle between
    them), sampled at the ``f`` fractions of the part of the step where ``p`` lies within ``Rt + w`` of
    the line along ``a`` (``w``: how far the turned flutes stray from the cylinder along ``a``, module
    docstring); ``-inf`` where never inside."""
    va = _dot(vx, vy, vz, ax, ay, az)
    wa = _dot(w0x, w0y, w0z, ax, ay, az)
    vvx, vvy, vvz = vx - va * ax, vy - va * ay, vz - va * az
    wwx, wwy, wwz = w0x - wa * ax, w0y - wa * ay, w0z - wa * az
    A = _dot(vvx, vvy, vvz, vvx, vvy, vvz)
    B = -2.0 * _dot(wwx, wwy, wwz, vvx, vvy, vvz)
    rw = Rt + w
    C = _dot(wwx, wwy, wwz, wwx, wwy, wwz) - rw * rw
    disc = B * B - 4.0 * A * C
    if A > 1e-18:
        if not disc >= 0.0:
            return _NEG_INF
        root = math.sqrt(max(disc, 0.0))
        t0 = (-B - root) / (2.0 * A)
        t1 = (-B + root) / (2.0 * A)
    else:
        if not C <= 0.0:
            return _NEG_INF
        t0, t1 = 0.0, 1.0
    t0 = min(max(t0, 0.0), 1.0)
    t1 = min(max(t1, 0.0), 1.0)
    if not t1 >= t0:
        return _NEG_INF
    dt = t1 - t0
    out = _NEG_INF
    lim = Rt + 1e-12
    for k in range(f.shape[0]):
        t = t0 + dt * f[k]
        bx, by, bz = a0x + t * (ax - a0x), a0y + t * (ay - a0y), a0z + t * (az - a0z)
        nb = math.sqrt(bx * bx + by * by + bz * bz)
        if not nb > 1e-12:
            continue
        bx, by, bz = bx / nb, by / nb, bz / nb
        wx, wy, wz = w0x - t * vx, w0y - t * vy, w0z - t * vz             # p - centre(t)
        h = _dot(wx, wy, wz, bx, by, bz)
        dx, dy, dz = wx - h * bx, wy - h * by, wz - h * bz
        r = math.sqrt(dx * dx + dy * dy + dz * dz)
        if h >= 0.0 and h <= L and r <= lim:
            out = max(out, Rt - r)
    return out


# ------------------------------------------------------------------------------ the layers' pieces

@njit(cache=True)
def box(s, e, a, shift):
    """(lo, hi): the box of the segments ``s + shift a -> e + shift a``."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for m in range(s.shape[0]):
        for c in range(3):
            u = s[m, c] + shift * a[m, c]
            v = e[m, c] + shift * a[m, c]
            lo[c] = min(lo[c], u, v)
            hi[c] = max(hi[c], u, v)
    return lo, hi


@njit(parallel=True, cache=True)
def fill_pieces(s, e, a, length, n, off, base, shift, shift2, lo, cell, dims, key, cen, cen2, half, owner):
    """The pieces of every move ``m`` (``n[m]`` of them from ``off[m]``; tips ``s -> e``, axis ``a``,
    length ``length[m]``): piece ``k``'s mid point ``mid = s + ((k + 1/2) / n) (e - s)``, its point
    ``cen = mid + shift a`` and its cell ``key`` in the grid (``lo``, ``cell``, ``dims``), ``cen2 = mid
    + shift2 a`` (when ``cen2`` has rows), the half length ``half``, the move ``owner = base + m``."""
    two = cen2.shape[0] > 0
    nx, ny, nz = dims[0], dims[1], dims[2]
    for m in prange(s.shape[0]):
        nm = n[m]
        h = 0.5 * length[m] / nm
        for k in range(nm):
            q = off[m] + k
            fr = (k + 0.5) / nm
            mx = s[m, 0] + fr * (e[m, 0] - s[m, 0])
            my = s[m, 1] + fr * (e[m, 1] - s[m, 1])
            mz = s[m, 2] + fr * (e[m, 2] - s[m, 2])
            cx, cy, cz = mx + shift * a[m, 0], my + shift * a[m, 1], mz + shift * a[m, 2]
            cen[q, 0], cen[q, 1], cen[q, 2] = cx, cy, cz
            if two:
                cen2[q, 0] = mx + shift2 * a[m, 0]
                cen2[q, 1] = my + shift2 * a[m, 1]
                cen2[q, 2] = mz + shift2 * a[m, 2]
            ix = min(max(int(math.floor((cx - lo[0]) / cell)), 0), nx - 1)
            iy = min(max(int(math.floor((cy - lo[1]) / cell)), 0), ny - 1)
            iz = min(max(int(math.floor((cz - lo[2]) / cell)), 0), nz - 1)
            key[q] = (ix * ny + iy) * nz + iz
            half[q] = h
            owner[q] = base + m


@njit(cache=True)
def sort_pieces(key, ncell, cen, cen2, half, owner, at, cstart, cat, pcen, pball, phalf, powner):
    """Counting sort of one layer's pieces by cell, into the shared arrays from piece ``at``
    (``pball`` too when ``cen2`` has rows); ``cstart[cat + c]`` = the first piece of cell ``c``
    (absolute), ``cstart[cat + ncell]`` = past the last."""
    count = np.zeros(ncell + 1, np.int64)
    for q in range(key.shape[0]):
        count[key[q] + 1] += 1
    for c in range(ncell):
        count[c + 1] += count[c]
    for c in range(ncell + 1):
        cstart[cat + c] = at + count[c]
    two = cen2.shape[0] > 0
    for q in range(key.shape[0]):
        d = at + count[key[q]]
        count[key[q]] += 1
        pcen[d, 0], pcen[d, 1], pcen[d, 2] = cen[q, 0], cen[q, 1], cen[q, 2]
        if two:
            pball[d, 0], pball[d, 1], pball[d, 2] = cen2[q, 0], cen2[q, 1], cen2[q, 2]
        phalf[d] = half[q]
        powner[d] = owner[q]


# --------------------------------------------------------------------------------- the points

@njit(cache=True)
def _scan_layer(px, py, pz, sid, g, best, prune, S, E, A, A0, lmode, lrad, llen, lsearch, lrho, lsoff, lhalf, lo, cell,
                dims, lcoff, cstart, pcen, pball, phalf, powner, f, stamp):
    """``best`` raised by the depths of layer ``g``'s candidates at ``p`` (stamp ``sid``); and whether a
    ball piece was passed over by its bound (``prune``)."""
    r = lsearch[g]
    c = cell[g]
    nx, ny, nz = dims[g, 0], dims[g, 1], dims[g, 2]
    ox, oy, oz = lo[g, 0], lo[g, 1], lo[g, 2]
    ix0 = max(int(math.floor((px - r - ox) / c)), 0)
    ix1 = min(int(math.floor((px + r - ox) / c)), nx - 1)
    iy0 = max(int(math.floor((py - r - oy) / c)), 0)
    iy1 = min(int(math.floor((py + r - oy) / c)), ny - 1)
    if ix0 > ix1 or iy0 > iy1:
        return best, False
    mode = lmode[g]
    R = lrad[g]
    L = llen[g]
    rho = lrho[g]
    soff = lsoff[g]
    c0 = lcoff[g]
    near = mode == NEAR
    skipped = False
    # the columns ring by ring around the point's, the nearest first (an early deep reading prunes more)
    ixp = min(max(int(math.floor((px - ox) / c)), ix0), ix1)
    iyp = min(max(int(math.floor((py - oy) / c)), iy0), iy1)
    nring = max(ixp - ix0, ix1 - ixp, iyp - iy0, iy1 - iyp)
    for ring in range(nring + 1):
        for ix in range(max(ixp - ring, ix0), min(ixp + ring, ix1) + 1):
            step = 1 if (ix == ixp - ring or ix == ixp + ring) else 2 * ring
            for iy in range(iyp - ring, iyp + ring + 1, max(step, 1)):
                if iy < iy0 or iy > iy1:
                    continue
                T = r
                if near and prune and best > _NEG_INF:
                    # a ball piece whose mid point lies farther than T cannot beat best (the depth over
                    # its part of the move is at most 2 R + half - that distance)
                    T = min(r, 2.0 * R + lhalf[g] - best + BOUND_SLACK_MM)
                    if T < r:
                        skipped = True
                    gx = max(abs(px - (ox + (ix + 0.5) * c)) - 0.5 * c, 0.0)
                    gy = max(abs(py - (oy + (iy + 0.5) * c)) - 0.5 * c, 0.0)
                    if T < 0.0 or gx * gx + gy * gy > T * T:
                        continue
                iz0 = max(int(math.floor((pz - T - oz) / c)), 0)
                iz1 = min(int(math.floor((pz + T - oz) / c)), nz - 1)
                if iz0 > iz1:
                    continue
                col = c0 + (ix * ny + iy) * nz
                if near:
                    pr = prune and best > _NEG_INF
                    for q in range(cstart[col + iz0], cstart[col + iz1 + 1]):
                        if pr:
                            # the ball's depth over the piece's part of the move is at most R + half minus
                            # the distance to the ball's centre at the piece's mid point
                            t = R + phalf[q] - best + BOUND_SLACK_MM
                            ex, ey, ez = pball[q, 0] - px, pball[q, 1] - py, pball[q, 2] - pz
                            if t < 0.0 or ex * ex + ey * ey + ez * ez > t * t:
                                skipped = True
                                continue
                        dx, dy, dz = pcen[q, 0] - px, pcen[q, 1] - py, pcen[q, 2] - pz
                        if dx * dx + dy * dy + dz * dz > rho * rho:
                            continue
                        m = powner[q]
                        if stamp[soff + m] == sid:
                            continue
                        stamp[soff + m] = sid
                        ax, ay, az = A[m, 0], A[m, 1], A[m, 2]
                        sx, sy, sz = S[m, 0] + R * ax, S[m, 1] + R * ay, S[m, 2] + R * az
                        vx, vy, vz = (E[m, 0] + R * ax) - sx, (E[m, 1] + R * ay) - sy, (E[m, 2] + R * az) - sz
                        d = _ball(px, py, pz, sx, sy, sz, vx, vy, vz, px - sx, py - sy, pz - sz, R)
                        if d > best:
                            best = d
                            pr = prune
                    continue
                for q in range(cstart[col + iz0], cstart[col + iz1 + 1]):
                    m = powner[q]
                    ax, ay, az = A[m, 0], A[m, 1], A[m, 2]
                    # a step of the flutes that turns the axis (from A0): they stray at most tw from
                    # the cylinder along its end axis (module docstring), which the tests below widen by
                    tw = 0.0
                    if mode == SIDE and (A0[m, 0] != ax or A0[m, 1] != ay or A0[m, 2] != az):
                        ex, ey, ez = A0[m, 0] - ax, A0[m, 1] - ay, A0[m, 2] - az
                        tw = math.hypot(L, R) * math.sqrt(ex * ex + ey * ey + ez * ez) + SPHERE_SLACK_MM
                    dx, dy, dz = pcen[q, 0] - px, pcen[q, 1] - py, pcen[q, 2] - pz
                    rr = rho + phalf[q] + tw
                    if dx * dx + dy * dy + dz * dz > rr * rr:
                        continue
                    if stamp[soff + m] == sid:
                        continue
                    # the cylinder over the piece's part of the move lies within R + half of its axis at
                    # the piece's mid point (the segment of length L about pcen): else never inside; and
                    # reads at most R + half - the radial distance there (a flat end: and at most the
                    # height + half)
                    hh = -_dot(dx, dy, dz, ax, ay, az)
                    wx, wy, wz = -dx - hh * ax, -dy - hh * ay, -dz - hh * az
                    r2 = wx * wx + wy * wy + wz * wz
                    over = max(abs(hh) - 0.5 * L - tw, 0.0)
                    lim = R + phalf[q] + SPHERE_SLACK_MM + tw
                    if r2 + over * over > lim * lim:
                        continue
                    if best > _NEG_INF:
                        bound = R + phalf[q] + tw - math.sqrt(r2)
                        if mode == FLAT:
                            bound = min(bound, hh + 0.5 * L + phalf[q])
                        if bound < best - BOUND_SLACK_MM:
                            continue
                    stamp[soff + m] = sid
                    if mode == FLAT:
                        sx, sy, sz = S[m, 0], S[m, 1], S[m, 2]
                        d = _cylinder(E[m, 0] - sx, E[m, 1] - sy, E[m, 2] - sz, px - sx, py - sy, pz - sz,
                                      ax, ay, az, R, L, False, f, best)
                    else:                        # the side of the ball's flutes, from the ball's centres
                        sx, sy, sz = S[m, 0] + R * ax, S[m, 1] + R * ay, S[m, 2] + R * az
                        vx, vy, vz = (E[m, 0] + R * ax) - sx, (E[m, 1] + R * ay) - sy, (E[m, 2] + R * az) - sz
                        if tw > 0.0:
                            d = _side_turning(vx, vy, vz, px - sx, py - sy, pz - sz, A0[m, 0], A0[m, 1], A0[m, 2],
                                              ax, ay, az, R, L, tw, f)
                        else:
                            d = _cylinder(vx, vy, vz, px - sx, py - sy, pz - sz, ax, ay, az, R, L, True, f, best)
                    if d > best:
                        best = d
        if near and prune and best > _NEG_INF and ring * c > 2.0 * R + lhalf[g] - best + BOUND_SLACK_MM:
            skipped = skipped or ring < nring       # every further ring lies beyond the bound
            break
    return best, skipped


@njit(cache=True)
def _point_depth(px, py, pz, i, S, E, A, A0, lmode, lrad, llen, lsearch, lrho, lsoff, lhalf, lfloor, lo, cell, dims,
                 lcoff, cstart, pcen, pball, phalf, powner, f, stamp):
    """The deepest depth of point ``p`` (index ``i``) over the candidates of every layer; measured again
    without the ball bounds when the result is at or below the floor of a ball layer (module docstring)."""
    floor = _NEG_INF
    for g in range(lmode.shape[0]):
        if lmode[g] == NEAR:
            floor = max(floor, lfloor[g])
    best = _NEG_INF
    for attempt in range(2):
        prune = attempt == 0
        sid = 2 * i + attempt
        best = _NEG_INF
        skipped = False
        for g in range(lmode.shape[0]):
            best, sk = _scan_layer(px, py, pz, sid, g, best, prune, S, E, A, A0, lmode, lrad, llen, lsearch, lrho, lsoff,
                                   lhalf, lo, cell, dims, lcoff, cstart, pcen, pball, phalf, powner, f, stamp)
            skipped = skipped or sk
        if not skipped or best > floor + BOUND_SLACK_MM:
            break
    return best


@njit(parallel=True, cache=True)
def penetration(pts, order, nchunk, S, E, A, A0, lmode, lrad, llen, lsearch, lrho, lsoff, lhalf, lfloor, lo, cell, dims,
                lcoff, cstart, pcen, pball, phalf, powner, f, out):
    """``out[order[j]]`` = the depth of point ``pts[order[j]]`` (module docstring): blocks of
    :data:`BLOCK` consecutive ``order`` entries, dealt round-robin to ``nchunk`` chunks run in
    parallel, each with its own stamps (two per move: the ball or the cylinder, and the side of the
    ball's flutes)."""
    n = order.shape[0]
    nblock = (n + BLOCK - 1) // BLOCK
    M = S.shape[0]
    for c in prange(nchunk):
        stamp = np.full(2 * M, -1, np.int32)
        for blk in range(c, nblock, nchunk):
            for j in range(blk * BLOCK, min(n, (blk + 1) * BLOCK)):
                i = order[j]
                out[i] = _point_depth(pts[i, 0], pts[i, 1], pts[i, 2], i, S, E, A, A0, lmode, lrad, llen, lsearch, lrho,
                                      lsoff, lhalf, lfloor, lo, cell, dims, lcoff, cstart, pcen, pball, phalf,
                                      powner, f, stamp)
