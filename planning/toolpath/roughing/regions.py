"""A level's clearing region, its connected components and its boundary loops (Z-level roughing,
:mod:`planning.toolpath.roughing`; raster cells of side h mm in the area frame). Stage: per level,
after the forbidden map (:mod:`planning.toolpath.roughing.maps`) and before the clearing pieces
(:mod:`planning.toolpath.roughing.clearing`).

The clearing region of a level: the allowed cells whose centre lies within ``g = Rt - h`` of the
stock box (the disc still reaches h into the stock; skins beside the part are reachable). Its
connected components (8-connected; union-find over the region's runs of cells along y, numbered
as :func:`scipy.ndimage.label` numbers them) are cut one after another
(:mod:`planning.toolpath.roughing.ordering`). The boundary of the region (for Tchanchane & Bey's offset
contour) comes from marching squares through the midpoints between a region cell centre and a
cell outside it, region cells 8-connected, the region on the left of the travel. Cost per level:
one pass over the raster (the region and its runs), then the boundary from the runs (only the
2 x 2 blocks that can be mixed).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from planning.toolpath.roughing.common import _argsort_stable


@njit(cache=True, nogil=True)
def _find(parent, a):
    """Root of ``a`` in the union-find forest ``parent`` (path halving)."""
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@njit(cache=True, nogil=True)
def _region_runs(G, thr, inbox, region):
    """A level's region and its components: ``region = inbox & (G <= thr)`` (the forbidden cells
    are those with ``G > thr``). The region's runs along y per row
    (``rows[i]:rows[i + 1]`` index the runs of row i, cells ``j0[r] .. j1[r] - 1``) and their
    8-connected components (union-find on the runs of neighbouring rows), numbered from 1 in the
    raster order of their first cell (as ``scipy.ndimage.label``). Returns (rows, j0, j1, comp)."""
    nx, ny = region.shape
    rows = np.empty(nx + 1, np.int64)
    nr = 0
    for i in range(nx):
        rows[i] = nr
        rr = region[i]
        ib = inbox[i]
        gi = G[i]
        prev = False
        for j in range(ny):
            v = ib[j] and not gi[j] > thr
            rr[j] = v
            nr += v and not prev
            prev = v
    rows[nx] = nr
    j0 = np.empty(nr, np.int64)
    j1 = np.empty(nr, np.int64)
    for i in range(nx):
        rr = region[i]
        k = rows[i]
        prev = False
        for j in range(ny):
            v = rr[j]
            if v and not prev:
                j0[k] = j
            elif prev and not v:
                j1[k] = j
                k += 1
            prev = v
        if prev:
            j1[k] = ny
    parent = np.arange(nr)
    for i in range(1, nx):
        a, ae = rows[i - 1], rows[i]
        b, be = rows[i], rows[i + 1]
        while a < ae and b < be:
            if j0[a] <= j1[b] and j0[b] <= j1[a]:         # touching, diagonals included
                ra = _find(parent, a)
                rb = _find(parent, b)
                if ra != rb:
                    if ra < rb:
                        parent[rb] = ra
                    else:
                        parent[ra] = rb
            if j1[a] < j1[b]:
                a += 1
            else:
                b += 1
    comp = np.zeros(nr, np.int64)
    lab = np.zeros(nr, np.int64)
    nxt = 1
    for r in range(nr):
        root = _find(parent, r)
        if lab[root] == 0:
            lab[root] = nxt
            nxt += 1
        comp[r] = lab[root]
    return rows, j0, j1, comp


@njit(cache=True, nogil=True)
def _comp_at(rows, j0, j1, comp, i, j):
    """Component of cell (i, j) (0 when not in the region), from :func:`_region_runs`."""
    lo = rows[i]
    hi = rows[i + 1]
    while lo < hi:                      # first run of the row ending after j
        mid = (lo + hi) // 2
        if j1[mid] <= j:
            lo = mid + 1
        else:
            hi = mid
    if lo < rows[i + 1] and j0[lo] <= j:
        return comp[lo]
    return 0


# ----------------------------------------------------------------------------------------------
# Marching squares on the clearing region: oriented boundary loops
# ----------------------------------------------------------------------------------------------

@njit(cache=True, nogil=True)
def _march(region, rows, j0, j1):
    """Boundary loops of the True cells of ``region`` (nx, ny), the cells outside the raster
    counting as False, the True cells on the left of the travel, 8-connected (marching squares).
    In the raster padded by one cell (NX = nx + 2, NY = ny + 2), edges of the dual grid:
    horizontal H(i, j) between cells (i, j), (i+1, j): id ``i * NY + j``; vertical V(i, j) between
    (i, j), (i, j+1): id ``NH + i * (NY - 1) + j``, NH = (NX - 1) NY. Loops start at their smallest
    edge id, in increasing order of it. Only the 2 x 2 blocks that can be mixed are visited, found
    from the region's runs (``rows``, ``j0``, ``j1`` from :func:`_region_runs`): the blocks at a
    run's ends and those over the columns where the two rows differ. Returns (edge ids in loop
    order, loop start offsets); in three parts: :func:`_mixed_blocks` (the blocks of a row that
    can be mixed), :func:`_row_pairs` (their boundary pairs) and :func:`_chain_loops`."""
    nx, ny = region.shape
    NX = nx + 2
    NY = ny + 2
    NH = (NX - 1) * NY
    cap = 4096
    src = np.empty(cap, np.int64)
    dst = np.empty(cap, np.int64)
    n = 0
    b = np.zeros(4, np.int64)
    e = np.empty(4, np.int64)
    mark = np.full(NY, -1, np.int64)
    cand = np.empty(NY, np.int64)
    bnd = np.empty(2 * NY + 2, np.int64)
    for i in range(NX - 1):
        # padded rows i and i + 1 are region rows i - 1 (A) and i (B)
        a0 = rows[i - 1] if i >= 1 else 0
        a1 = rows[i] if i >= 1 else 0
        b0 = rows[i] if i < nx else 0
        b1 = rows[i + 1] if i < nx else 0
        if a0 == a1 and b0 == b1:
            continue
        nc = _mixed_blocks(i, a0, a1, b0, b1, j0, j1, NY, mark, cand, bnd)
        if n + 2 * nc > cap:                      # a block adds at most two pairs
            cap = 2 * (n + 2 * nc)
            src = _grown(src, n, cap)
            dst = _grown(dst, n, cap)
        n = _row_pairs(region, i, cand, nc, NY, NH, b, e, src, dst, n)
    return _chain_loops(src, dst, n)


@njit(cache=True, nogil=True)
def _grown(a, n, cap):
    """A new int64 array of ``cap`` entries holding the first ``n`` of ``a`` (growing a buffer)."""
    out = np.empty(cap, np.int64)
    for q in range(n):
        out[q] = a[q]
    return out


@njit(cache=True, nogil=True)
def _mixed_blocks(i, a0, a1, b0, b1, j0, j1, NY, mark, cand, bnd):
    """For :func:`_march`, padded row i over region rows i - 1 (A: runs ``a0:a1``) and i (B: runs
    ``b0:b1``): the 2 x 2 blocks that can be mixed, the blocks at the ends of the runs and those
    over the columns where A and B differ, written to ``cand``; returns their number. ``mark``
    (NY): the last row that took each block; ``bnd`` (2 NY + 2): scratch."""
    nc = 0
    nbd = 0                                   # run ends of A and of B, merged in order
    pa = 2 * a0
    pb = 2 * b0
    while pa < 2 * a1 or pb < 2 * b1:
        va = (j0[pa // 2] if pa % 2 == 0 else j1[pa // 2]) if pa < 2 * a1 else NY
        vb = (j0[pb // 2] if pb % 2 == 0 else j1[pb // 2]) if pb < 2 * b1 else NY
        if va <= vb:
            bnd[nbd] = va
            pa += 1
        else:
            bnd[nbd] = vb
            pb += 1
        nbd += 1
    for q in range(nbd):                      # the blocks at the ends of the runs
        jj = bnd[q]
        if mark[jj] != i:
            mark[jj] = i
            cand[nc] = jj
            nc += 1
    # columns where A and B differ: between consecutive boundaries both rows are constant
    bs = bnd
    ra = a0
    rb = b0
    for q in range(nbd - 1):
        p0 = bs[q]
        p1 = bs[q + 1]
        if p1 == p0:
            continue
        while ra < a1 and j1[ra] <= p0:
            ra += 1
        while rb < b1 and j1[rb] <= p0:
            rb += 1
        ina = ra < a1 and j0[ra] <= p0
        inb = rb < b1 and j0[rb] <= p0
        if ina != inb:                        # region columns p0 .. p1 - 1: blocks p0 .. p1
            for jj in range(p0, p1 + 1):
                if mark[jj] != i:
                    mark[jj] = i
                    cand[nc] = jj
                    nc += 1
    return nc


@njit(cache=True, nogil=True)
def _row_pairs(region, i, cand, nc, NY, NH, b, e, src, dst, n):
    """For :func:`_march`: the boundary pairs (edge in -> edge out, the True cells on the left) of
    the 2 x 2 blocks of padded cells (i, j) .. (i + 1, j + 1), j in ``cand[:nc]``, written from
    ``src[n]``, ``dst[n]`` (room for two per block is left there); returns the new count. ``b``,
    ``e`` (4,): scratch."""
    nx, ny = region.shape
    for q in range(nc):
        j = cand[q]
        b[0] = 1 if (i >= 1 and j >= 1 and region[i - 1, j - 1]) else 0
        b[1] = 1 if (i < nx and j >= 1 and region[i, j - 1]) else 0
        b[2] = 1 if (i < nx and j < ny and region[i, j]) else 0
        b[3] = 1 if (i >= 1 and j < ny and region[i - 1, j]) else 0
        sm = b[0] + b[1] + b[2] + b[3]
        if sm == 0 or sm == 4:
            continue
        e[0] = i * NY + j                       # c0 -> c1 (bottom)
        e[1] = NH + (i + 1) * (NY - 1) + j      # c1 -> c2 (right)
        e[2] = i * NY + j + 1                   # c2 -> c3 (top)
        e[3] = NH + i * (NY - 1) + j            # c3 -> c0 (left)
        for k in range(4):
            if b[k] == 1 and b[(k + 1) % 4] == 0:
                for d in range(1, 4):
                    m = (k + d) % 4
                    if b[m] == 0 and b[(m + 1) % 4] == 1:
                        src[n] = e[k]
                        dst[n] = e[m]
                        n += 1
                        break
    return n


@njit(cache=True, nogil=True)
def _chain_loops(src, dst, n):
    """For :func:`_march`: the pairs ``src[:n] -> dst[:n]`` chained into loops, each starting at
    its smallest edge id, in increasing order of it. Returns (edge ids in loop order, loop start
    offsets)."""
    order = _argsort_stable(src[:n].astype(np.float64))
    ks = src[:n][order]
    kd = dst[:n][order]
    out = np.empty(n, np.int64)
    starts = np.empty(n + 1, np.int64)
    seen = np.zeros(n, np.bool_)
    m = 0
    nl = 0
    for p0 in range(n):
        if seen[p0]:
            continue
        starts[nl] = m
        nl += 1
        p = p0
        while not seen[p]:
            seen[p] = True
            out[m] = ks[p]
            m += 1
            lo = 0                              # the pair leaving from edge kd[p] (ids are unique)
            hi = n
            while lo < hi:
                mid = (lo + hi) // 2
                if ks[mid] < kd[p]:
                    lo = mid + 1
                else:
                    hi = mid
            p = lo
    starts[nl] = m
    return out[:m], starts[:nl + 1]


@njit(cache=True, nogil=True)
def _edge_cells(edges, region, G, thr):
    """For boundary edges from :func:`_march`: the region cell's flat index, whether the other cell is
    forbidden (``G > thr``; a cell outside the raster is not), and the crossing's doubled integer coordinates
    (x = x0 + gx h / 2, y = y0 + gy h / 2)."""
    nx, ny = region.shape
    NY = ny + 2
    NH = (nx + 1) * NY
    n = edges.shape[0]
    cell = np.empty(n, np.int64)
    keep = np.empty(n, np.bool_)
    gx = np.empty(n, np.int64)
    gy = np.empty(n, np.int64)
    for k in range(n):
        ed = edges[k]
        if ed < NH:
            i, j = ed // NY, ed % NY
            i2, j2 = i + 1, j
            gx[k], gy[k] = 2 * i, 2 * j - 1
        else:
            i, j = (ed - NH) // (NY - 1), (ed - NH) % (NY - 1)
            i2, j2 = i, j + 1
            gx[k], gy[k] = 2 * i - 1, 2 * j
        first_in = 1 <= i <= nx and 1 <= j <= ny and region[i - 1, j - 1]
        ri, rj, oi, oj = (i, j, i2, j2) if first_in else (i2, j2, i, j)
        cell[k] = (ri - 1) * ny + (rj - 1)
        keep[k] = 1 <= oi <= nx and 1 <= oj <= ny and G[oi - 1, oj - 1] > thr
    return cell, keep, gx, gy
