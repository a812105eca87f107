"""Tri-dexel stock model and material removal (issue 15), in the part frame, lengths in mm.

**Model.** :class:`TriDexel`: three families of parallel rays, along X, Y and Z, on square grids of
spacing ``r = resolution_mm`` over a domain box ``[lo, lo + n r]`` (every axis cut into ``n`` cells;
the rays run through the cell centres, so the three families share one lattice of nodes
``lo + (i + 1/2) r``). Each ray holds the material on its line as sorted disjoint intervals, EXACT
along the line (the cuts are computed analytically, see below); between rays nothing is known.
Storage, growth and parallelism: :mod:`planning.simulate.dexel_kernels` (a ray that outgrows its
block is moved, never truncated: no material is ever dropped).

**Volume.** Family ``k``'s volume is ``r^2 x`` (sum of its interval lengths), the midpoint rule
over the cells of its grid. Its error is bounded by the boundary's lateral slope:
``|V_k - V| <= (r/2) * integral over the surface of (|n_u| + |n_v|) dA`` (``u, v`` the grid axes,
``n`` the unit normal), e.g. ``r * h * (w_u + w_v)`` for a box of height ``h`` along the rays; for
smooth surfaces away from silhouettes the error is second order in ``r`` (the linear part cancels).
The three families agree within the sum of their two bounds. :meth:`TriDexel.volume_mm3` is their
mean.

**Cutting** (:func:`cut`, :func:`simulate_moves`): every move is a straight segment of the tool tip
at a fixed unit axis (tip towards spindle). The tool (:class:`~planning.simulate.motion.ToolShape`)
is a union of convex pieces: ball = sphere (centre ``R`` above the tip) + cylinder ``[R, flute]``
(the sphere's top half is counted as cutting even when the flutes are shorter than ``2R``); flat =
cylinder ``[0, flute]``; bull-nose = the inner disc and the torus as a stack of cylinders
whose radii are the torus' radius at each slice's top (so the stack contains the torus; it
overcuts by at most ``rc * dtheta / 2``, ``dtheta = pi/2 / slices``, slices chosen so this is
``<= bull_tol_mm``, default ``r / 4``) + cylinder ``[rc, flute]``; non-cutting pieces: the shape's
``pieces`` (shank, holder; ``z1 = inf`` is cut off where it leaves the domain). A convex piece swept
along a segment is convex, so each ray meets it in one interval, computed in closed form
(:mod:`planning.simulate.dexel_kernels`: ``capsule_interval`` for the ball, ``cyl_interval`` for a
cylinder, both checked against ``swept_interval`` and brute force in the tests); only the rays of
the grid rows whose line meets the piece's projected sweep (a parallelogram grown by the radius)
are visited, and of those only the ones with material within the piece's extent along them.

**Collision depth** (:func:`collide`, :func:`simulate_moves`): per move, over the rays of each
family, the largest length of material inside a measured swept piece. The reported depth is that
length on the family most parallel to the tool axis times the |cos| of its angle to the axis (the
material's extent along the axis: how far the piece is buried); where that family sees nothing but
another does (a contact thinner than the ray spacing across the axis-parallel rays, e.g. a holder
grazing a wall), the smallest such length among the others (the penetration measured across it).
Zero when no ray of any family meets material inside the sweep. A contact is seen when some ray
of some family passes through the overlap: guaranteed when the overlap is at least ``r`` wide
across one family's grid; thinner (grazing) overlaps may be missed between rays. Depths saturate
at ``depth_cap_mm`` (default :data:`DEPTH_CAP_MM`): a family's scan stops at the first ray that
shows that much, so a buried holder does not cost every ray of its footprint.

**Deviation** (:func:`signed_deviation`, bound :func:`deviation_bound_mm`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, wait
from dataclasses import dataclass

import numba
import numpy as np

from planning.progress import Progress, Throttled
from planning.simulate import dexel_kernels as K
from planning.simulate.motion import FEED, RAPID, ToolShape

#: Default ray spacing (mm); see BENCHMARKS.md (bench/bench_dexel.py) for the speed behind it.
RESOLUTION_MM = 0.5
#: Collision depths saturate here (mm): the scan of a move's rays stops at the first ray that
#: shows this much (a buried holder would otherwise cost every ray of its footprint).
DEPTH_CAP_MM = 5.0
#: Moves per kernel call (bounds the scratch: tasks x 2 x CHUNK doubles).
CHUNK = 1 << 16
#: Fewer moves than this run in the calling thread (a planner's single checks: a column, a rapid).
INLINE_MOVES = 16
#: Tasks (interleaved row sets) per family and thread (``numba.config.NUMBA_NUM_THREADS`` at
#: construction); the kernels run on ``numba.get_num_threads()`` threads.
_TASKS_PER_THREAD = 1


def _grid(lo, hi, res):
    lo = np.asarray(lo, float).reshape(3)
    hi = np.asarray(hi, float).reshape(3)
    if not (res > 0 and np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
        raise ValueError(f"bad domain {lo}..{hi} or resolution {res}")
    n = np.maximum(1, np.ceil((hi - lo) / res - 1e-9)).astype(np.int64)
    return lo, n


def _domain(solid_lo, solid_hi, res, domain_lo, domain_hi):
    """The given domain, or the solid's box grown by one ray spacing."""
    if domain_lo is None:
        domain_lo = np.asarray(solid_lo, float) - res
    if domain_hi is None:
        domain_hi = np.asarray(solid_hi, float) + res
    return _grid(domain_lo, domain_hi, float(res))


class TriDexel:
    """Tri-dexel model (module docstring). Build with :meth:`empty`, :meth:`box`,
    :meth:`cylinder`, :meth:`from_mesh`; combine with :meth:`union`. Two models can be combined
    only on the same grid (same ``lo``, ``n`` and resolution)."""

    def __init__(self, lo, resolution_mm: float, n, csrs, _bounds_of: TriDexel | None = None):
        self.lo = np.asarray(lo, float).copy()
        self.res = float(resolution_mm)
        self.n = np.asarray(n, np.int64).copy()
        nrays = [int(self.n[(f + 1) % 3] * self.n[(f + 2) % 3]) for f in range(3)]
        self.base = np.concatenate([[0], np.cumsum(nrays)]).astype(np.int64)
        # tasks: per family, the rows j = res mod jmod (interleaved: a tool path's work is spread
        # over all of them wherever it runs)
        nth = max(1, numba.config.NUMBA_NUM_THREADS)
        jmod = max(1, _TASKS_PER_THREAD * nth)
        # residue-major order: the parallel loop's static split gives each thread every family
        fam, rs, md = [], [], []
        for q in range(jmod):
            for f in range(3):
                nv = int(self.n[(f + 2) % 3])
                if q < min(jmod, nv):
                    fam.append(f)
                    rs.append(q)
                    md.append(min(jmod, nv))
        self.t_fam = np.array(fam, np.int64)
        self.t_res = np.array(rs, np.int64)
        self.t_mod = np.array(md, np.int64)
        # row segments of SEG rays with their material bounds
        self.nseg = np.array([-(-int(self.n[(f + 1) % 3]) // K.SEG) for f in range(3)], np.int64)
        self.sbase = np.concatenate([[0], np.cumsum([self.nseg[f] * self.n[(f + 2) % 3] for f in range(3)])]
                                    ).astype(np.int64)
        self.seg_lo = np.empty(int(self.sbase[3]))
        self.seg_hi = np.empty(int(self.sbase[3]))
        ntile = [self.nseg[f] * -(-int(self.n[(f + 2) % 3]) // K.TROWS) for f in range(3)]
        self.tbase = np.concatenate([[0], np.cumsum(ntile)]).astype(np.int64)
        self.tile_lo = np.empty(int(self.tbase[3]))
        self.tile_hi = np.empty(int(self.tbase[3]))
        # the segments whose rays the kernels changed since the last refresh
        self.dirty = np.zeros(int(self.sbase[3]), np.uint8)
        # pool from the per-family CSR lists
        ptrs, ivs, shift = [], [], 0
        for f, (ptr, iv) in enumerate(csrs):
            ptr = np.asarray(ptr, np.int64)
            if ptr.shape[0] != nrays[f] + 1:
                raise ValueError("CSR does not match the grid")
            ptrs.append(ptr[:-1] + shift)
            ivs.append(np.asarray(iv, float).reshape(-1, 2))
            shift += int(ptr[-1])
        off = np.concatenate(ptrs).astype(np.int64)
        pool = np.concatenate(ivs) if shift else np.zeros((0, 2))
        cnt = np.diff(np.concatenate([off, [shift]])).astype(np.int64)
        cap = np.maximum(2, cnt).astype(np.int64)
        T = self.t_fam.shape[0]
        zero = np.zeros(T, np.int64)
        self.cnt = cnt
        self.cap = cap
        self.off, self.pool, self.t_top, self.t_end = K.repack(
            off, cnt, cap, pool, self.t_fam, self.t_res, self.t_mod, self.base, self.n,
            zero, zero.copy(), zero.copy(), 256, 0.5)
        if _bounds_of is None:
            self._refresh()
        else:                                  # the same material: the same (exact) bounds
            _bounds_of._refresh_dirty()
            for name in ("seg_lo", "seg_hi", "tile_lo", "tile_hi"):
                getattr(self, name)[:] = getattr(_bounds_of, name)

    # ---------------------------------------------------------------- constructors

    @classmethod
    def empty(cls, domain_lo, domain_hi, resolution_mm: float = RESOLUTION_MM) -> TriDexel:
        """No material on the domain's grid."""
        lo, n = _grid(domain_lo, domain_hi, float(resolution_mm))
        csrs = [(np.zeros(int(n[(f + 1) % 3] * n[(f + 2) % 3]) + 1, np.int64), np.zeros((0, 2)))
                for f in range(3)]
        return cls(lo, resolution_mm, n, csrs)

    @classmethod
    def box(cls, lo, hi, resolution_mm: float = RESOLUTION_MM, domain_lo=None, domain_hi=None) -> TriDexel:
        """The axis-aligned box ``lo <= x <= hi`` (clipped to the domain; default domain: the box
        grown by one ray spacing)."""
        blo = np.asarray(lo, float).reshape(3)
        bhi = np.asarray(hi, float).reshape(3)
        dlo, n = _domain(blo, bhi, resolution_mm, domain_lo, domain_hi)
        res = float(resolution_mm)
        csrs = []
        for f in range(3):
            ua, va = (f + 1) % 3, (f + 2) % 3
            u = dlo[ua] + (np.arange(n[ua]) + 0.5) * res
            v = dlo[va] + (np.arange(n[va]) + 0.5) * res
            inside = ((v[:, None] >= blo[va]) & (v[:, None] <= bhi[va]) &
                      (u[None, :] >= blo[ua]) & (u[None, :] <= bhi[ua])).ravel()
            a = max(blo[f], dlo[f])
            b = min(bhi[f], dlo[f] + n[f] * res)
            if b - a <= K.EPS_LEN:
                inside[:] = False
            ptr = np.concatenate([[0], np.cumsum(inside)]).astype(np.int64)
            iv = np.tile([a, b], (int(inside.sum()), 1)).astype(float)
            csrs.append((ptr, iv))
        return cls(dlo, res, n, csrs)

    @classmethod
    def cylinder(cls, base, axis_unit, radius: float, height: float, resolution_mm: float = RESOLUTION_MM,
                 domain_lo=None, domain_hi=None) -> TriDexel:
        """The solid cylinder of ``radius`` from ``base`` (centre of one end disc) ``height`` along
        ``axis_unit`` (any direction; normalised here), exact on every ray."""
        b = np.asarray(base, float).reshape(3)
        a = np.asarray(axis_unit, float).reshape(3)
        a = a / np.linalg.norm(a)
        ext = radius * np.sqrt(np.maximum(0.0, 1.0 - a * a))
        ends = np.stack([b, b + height * a])
        model = cls.empty(*_box_or(ends.min(0) - ext, ends.max(0) + ext, resolution_mm, domain_lo, domain_hi),
                          resolution_mm)
        pieces = (np.array([K.CYL]), np.array([0.0]), np.array([float(height)]), np.array([float(radius)]),
                  np.array([True]))
        _run(model, b[None], b[None], a[None], pieces, np.array([K.M_ADD], np.int64))
        return model

    @classmethod
    def from_mesh(cls, vertices, faces, resolution_mm: float = RESOLUTION_MM, domain_lo=None,
                  domain_hi=None) -> TriDexel:
        """The solid bounded by a closed triangle mesh (``vertices`` (V,3), ``faces`` (F,3)): each
        ray's crossings with the triangles, sorted, taken pairwise as intervals (a ray through an
        edge or vertex is counted once, by a consistent tie rule). Raises ValueError when a ray
        crosses the surface an odd number of times (the mesh is not closed)."""
        V = np.ascontiguousarray(vertices, float).reshape(-1, 3)
        F = np.ascontiguousarray(faces, np.int64).reshape(-1, 3)
        dlo, n = _domain(V.min(0), V.max(0), resolution_mm, domain_lo, domain_hi)
        res = float(resolution_mm)
        csrs = []
        for f in range(3):
            ptr, coords = K.mesh_crossings(V, F, dlo, res, n, f)
            optr, iv, odd = K.pair_crossings(ptr, coords, dlo[f], dlo[f] + n[f] * res)
            if odd:
                raise ValueError(f"mesh is not closed: {odd} rays of family {'XYZ'[f]} cross it an odd "
                                 f"number of times")
            csrs.append((optr, iv))
        return cls(dlo, res, n, csrs)

    # ---------------------------------------------------------------- combination, queries

    @property
    def hi(self) -> np.ndarray:
        return self.lo + self.n * self.res

    @property
    def nbytes(self) -> int:
        return int(self.pool.nbytes + self.off.nbytes + self.cnt.nbytes + self.cap.nbytes)

    def same_grid(self, other: TriDexel) -> bool:
        return (self.res == other.res and np.array_equal(self.n, other.n)
                and np.allclose(self.lo, other.lo, rtol=0, atol=1e-9 * self.res))

    def csr(self, family: int) -> tuple[np.ndarray, np.ndarray]:
        """Family ``family``'s rays as CSR: (ptr (R+1,), intervals (K,2)); ray ``j * n_u + i``."""
        r0, r1 = int(self.base[family]), int(self.base[family + 1])
        cnt = self.cnt[r0:r1]
        ptr = np.concatenate([[0], np.cumsum(cnt)]).astype(np.int64)
        idx = np.repeat(self.off[r0:r1], cnt) + (np.arange(int(ptr[-1])) - np.repeat(ptr[:-1], cnt))
        return ptr, self.pool[idx].copy()

    def ray_coordinates(self, family: int) -> tuple[np.ndarray, np.ndarray]:
        """(u (n_u,), v (n_v,)): the coordinates of family ``family``'s rays on its grid axes
        ``(family+1) % 3`` and ``(family+2) % 3``."""
        ua, va = (family + 1) % 3, (family + 2) % 3
        return (self.lo[ua] + (np.arange(self.n[ua]) + 0.5) * self.res,
                self.lo[va] + (np.arange(self.n[va]) + 0.5) * self.res)

    def boundary_points(self) -> np.ndarray:
        """(M,3) points on the material's boundary, mm: both ends of every material interval of
        every ray of the three families (spacing ``resolution_mm`` across the rays of a family;
        a face parallel to a family's rays is sampled by the other two). What the tool paths of
        the next set-up read the remaining stock from (rest roughing)."""
        out = []
        for f in range(3):
            ptr, iv = self.csr(f)
            if iv.shape[0] == 0:
                continue
            ua, va = (f + 1) % 3, (f + 2) % 3
            u, v = self.ray_coordinates(f)
            ray = np.repeat(np.arange(ptr.shape[0] - 1), np.diff(ptr))
            pts = np.empty((2 * iv.shape[0], 3))
            pts[:, ua] = np.tile(u[ray % self.n[ua]], 2)
            pts[:, va] = np.tile(v[ray // self.n[ua]], 2)
            pts[:, f] = np.concatenate([iv[:, 0], iv[:, 1]])
            out.append(pts)
        return np.concatenate(out) if out else np.zeros((0, 3))

    def ray_intervals(self, family: int, i: int, j: int) -> np.ndarray:
        """The material intervals (k,2) of ray ``(i, j)`` of family ``family``."""
        r = int(self.base[family] + j * self.n[(family + 1) % 3] + i)
        o, c = int(self.off[r]), int(self.cnt[r])
        return self.pool[o:o + c].copy()

    def union(self, other: TriDexel) -> TriDexel:
        """The union of two models on the same grid (a new model)."""
        if not self.same_grid(other):
            raise ValueError("union needs two models on the same grid (build them with the same domain)")
        csrs = []
        for f in range(3):
            pa, ia = self.csr(f)
            pb, ib = other.csr(f)
            csrs.append(K.union_csr(pa, ia, pb, ib))
        return TriDexel(self.lo, self.res, self.n, csrs)

    def copy(self) -> TriDexel:
        return TriDexel(self.lo, self.res, self.n, [self.csr(f) for f in range(3)], _bounds_of=self)

    def volumes_mm3(self) -> np.ndarray:
        """(3,) the volume seen by the X, Y and Z rays (module docstring for the bound)."""
        out = np.zeros(3)
        for f in range(3):
            _, iv = self.csr(f)
            out[f] = float((iv[:, 1] - iv[:, 0]).sum()) * self.res ** 2
        return out

    def volume_mm3(self, family: int | None = None) -> float:
        """The material volume: the mean of the three families' (or one family's)."""
        v = self.volumes_mm3()
        return float(v.mean() if family is None else v[family])

    def _repack(self, status: np.ndarray) -> None:
        self.off, self.pool, self.t_top, self.t_end = K.repack(
            self.off, self.cnt, self.cap, self.pool, self.t_fam, self.t_res, self.t_mod, self.base,
            self.n, self.t_top, self.t_end, status, 256, 0.0)

    def _refresh(self) -> None:
        K.refresh_segments(self.n, self.base, self.sbase, self.nseg, self.off, self.cnt, self.pool,
                           self.seg_lo, self.seg_hi, self.tbase, self.tile_lo, self.tile_hi)
        self.dirty[:] = 0

    def _refresh_dirty(self) -> None:
        """The bounds of the segments (and their tiles) the kernels changed since the last refresh;
        the others are exact already, so this equals :meth:`_refresh`."""
        K.refresh_dirty(self.n, self.base, self.sbase, self.nseg, self.off, self.cnt, self.pool,
                        self.seg_lo, self.seg_hi, self.tbase, self.tile_lo, self.tile_hi, self.dirty)


def _box_or(lo, hi, res, domain_lo, domain_hi):
    dlo = np.asarray(lo, float) - res if domain_lo is None else np.asarray(domain_lo, float)
    dhi = np.asarray(hi, float) + res if domain_hi is None else np.asarray(domain_hi, float)
    return dlo, dhi


# -------------------------------------------------------------------------------- tools

def bull_slices(corner_radius_mm: float, tol_mm: float) -> int:
    """Slices of the bull-nose corner so that the stack overcuts by at most ``tol_mm``."""
    if corner_radius_mm <= 0:
        return 0
    return max(1, int(math.ceil(math.pi * corner_radius_mm / (4.0 * max(tol_mm, 1e-6)))))


def tool_pieces(shape: ToolShape, bull_tol_mm: float):
    """The convex pieces of a tool (module docstring): (kind, z0, z1, radius, cutting) arrays;
    a sphere has its centre at z0."""
    R = float(shape.radius_mm)
    L = float(shape.flute_length_mm)
    out = []
    if shape.kind == "ball":
        out.append((K.SPH, R, R, R, True))
        if L > R:
            out.append((K.CYL, R, L, R, True))
    elif shape.kind == "flat" or (shape.kind == "bull" and shape.corner_radius_mm <= 0):
        out.append((K.CYL, 0.0, L, R, True))
    elif shape.kind == "bull":
        rc = min(float(shape.corner_radius_mm), R)
        m = bull_slices(rc, bull_tol_mm)
        th = np.linspace(0.0, math.pi / 2, m + 1)
        z = rc * (1.0 - np.cos(th))
        for i in range(m):
            out.append((K.CYL, float(z[i]), float(min(z[i + 1], L)), R - rc + rc * math.sin(th[i + 1]), True))
        if L > rc:
            out.append((K.CYL, rc, L, R, True))
    else:
        raise ValueError(f"unknown tool kind {shape.kind!r}")
    for z0, z1, r in shape.pieces:
        if z1 > z0:
            out.append((K.CYL, float(z0), float(z1), float(r), False))
    kind = np.array([p[0] for p in out], np.int64)
    return (kind, np.array([p[1] for p in out]), np.array([p[2] for p in out]), np.array([p[3] for p in out]),
            np.array([p[4] for p in out], np.bool_))


# -------------------------------------------------------------------------------- moves

@dataclass
class MoveRun:
    """What :func:`simulate_moves` found, per move (P,): ``removed_mm3`` material removed (the
    mean of the three families' estimates; 0 for rapids); ``rapid_depth_mm`` for a rapid, how far
    its whole tool is in material (module docstring; 0: clear); ``holder_depth_mm`` for a feed move,
    how far its non-cutting pieces are in material; ``ray_visits`` rays evaluated (all moves)."""

    removed_mm3: np.ndarray
    rapid_depth_mm: np.ndarray
    holder_depth_mm: np.ndarray
    ray_visits: int


def _as_moves(start, end, axis):
    s = np.ascontiguousarray(start, float).reshape(-1, 3)
    e = np.ascontiguousarray(end, float).reshape(-1, 3)
    a = np.ascontiguousarray(axis, float).reshape(-1, 3)
    if not (s.shape == e.shape == a.shape):
        raise ValueError("start, end and axis must all be (P,3)")
    if not (np.isfinite(s).all() and np.isfinite(e).all() and np.isfinite(a).all()):
        raise ValueError("start, end and axis must be finite")
    nrm = np.linalg.norm(a, axis=1, keepdims=True)
    if np.any(~(nrm > 1e-9)):
        raise ValueError("every tool axis must be non-zero")
    return s, e, np.ascontiguousarray(a / nrm)


def _run(model: TriDexel, start, end, axis, pieces, mode, grow=None, depth_cap_mm: float = math.inf,
         chunk: int | None = None, progress: Progress | None = None, what: str = "moves"):
    """The kernel over all moves in chunks. Returns (length removed/added per move summed over the
    families, (3,P) largest overlap per family, rays evaluated). ``progress(fraction, message)`` after
    every chunk (the caller throttles it)."""
    s, e, a = _as_moves(start, end, axis)
    P = s.shape[0]
    chunk = CHUNK if chunk is None else int(chunk)
    mode = np.ascontiguousarray(np.broadcast_to(np.asarray(mode, np.int64), (P,)))
    grow = np.zeros(P) if grow is None else np.ascontiguousarray(np.broadcast_to(np.asarray(grow, float), (P,)))
    d = e - s
    pk, pz0, pz1, pr, pcut = pieces
    # how far up the axis anything can reach the domain: z = (X - P).a - t (d.a) over X in the
    # domain grown by the largest radius and t in [0, 1]
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    rmax = float(pr.max()) + float(grow.max()) if pr.size else 0.0
    box = (model.lo - rmax) + corners * (model.hi - model.lo + 2 * rmax)
    zcap = ((box @ a.T).max(0) - np.einsum("ij,ij->i", s, a) + np.maximum(0.0, -np.einsum("ij,ij->i", d, a))
            + grow + 1e-6)
    T = model.t_fam.shape[0]
    removed = np.zeros(P)
    depth = np.zeros((3, P))
    visits = 0
    for c0 in range(0, P, chunk):
        sl = slice(c0, min(P, c0 + chunk))
        cs, cd, ca, cm, cz, cg = s[sl], d[sl], a[sl], mode[sl], zcap[sl], grow[sl]
        M = cs.shape[0]
        mptr, midx = K.assign_moves(model.lo, model.res, model.n, model.t_fam, model.t_res, model.t_mod,
                                    cs, cd, ca, cz, pk, pz0, pz1, pr, cg)
        t_next = mptr[:-1].copy()
        t_status = np.zeros(T, np.int64)
        rem = np.zeros((T, M))
        dep = np.zeros((T, M))
        vis = np.zeros(T, np.int64)
        while True:
            def task(t, model=model):
                K.run_task(t, model.lo, model.res, model.n, model.base, model.sbase, model.nseg, model.seg_lo,
                           model.seg_hi, model.tbase, model.tile_lo, model.tile_hi, model.dirty, model.off, model.cnt,
                           model.cap, model.pool, model.t_fam, model.t_res, model.t_mod, model.t_top, model.t_end,
                           t_next, t_status, mptr, midx, cs, cd, ca, cm, cz, pk, pz0, pz1, pr, pcut, cg,
                           float(depth_cap_mm), rem, dep, vis)
            # one job per row residue, running its tasks of the three families: the residues share
            # the work evenly wherever the tool goes
            jobs = [[t for t in range(T) if model.t_res[t] == q and t_next[t] < mptr[t + 1]]
                    for q in range(int(model.t_mod.max()))]
            poll = None
            if progress is not None:
                def poll(c0=c0, M=M, mptr=mptr, t_next=t_next):
                    # the tasks' moves done so far (t_next moves on as they run)
                    done = float((t_next - mptr[:-1]).sum()) / max(1, int(mptr[-1]))
                    progress((c0 + done * M) / P, f"{what} {c0 + int(done * M)} of {P}")
            _map(lambda ts: [task(t) for t in ts], [j for j in jobs if j], poll, inline=M < INLINE_MOVES)
            if not t_status.any():
                break
            model._repack(t_status)
            t_status[:] = 0
        model._refresh_dirty()
        removed[sl] = rem.sum(0)
        for f in range(3):
            depth[f, sl] = dep[model.t_fam == f].max(0, initial=0.0)
        visits += int(vis.sum())
        if progress is not None:
            progress(sl.stop / P, f"{what} {sl.stop} of {P}")
    return removed, depth, visits


_POOL: ThreadPoolExecutor | None = None
_POOL_SIZE = 0


def _map(fn, items, poll: Callable[[], None] | None = None, inline: bool = False) -> None:
    """Run ``fn`` over ``items`` on ``numba.get_num_threads()`` threads (the kernels release the GIL);
    with ``poll``, on the pool even for one thread, calling ``poll()`` every 0.1 s while waiting;
    ``inline``: in this thread (a handful of moves: the pool's hand-over costs more than it saves)."""
    global _POOL, _POOL_SIZE
    nth = max(1, numba.get_num_threads())
    if poll is None and (inline or nth == 1 or len(items) <= 1):
        for it in items:
            fn(it)
        return
    if _POOL is None or _POOL_SIZE != nth:
        _POOL = ThreadPoolExecutor(max_workers=nth, thread_name_prefix="dexel")
        _POOL_SIZE = nth
    futs = [_POOL.submit(fn, it) for it in items]
    if poll is not None:
        while wait(futs, timeout=0.1).not_done:
            poll()
    for fut in futs:
        fut.result()


def _depth(dep: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Per move the collision depth from the per-family largest overlaps (module docstring)."""
    a = np.abs(_as_moves(axis, axis, axis)[2])
    P = a.shape[0]
    k = np.argmax(a, axis=1)
    rows = np.arange(P)
    along = dep[k, rows] * a[rows, k]
    seen = dep > 1e-9
    other = np.where(seen, dep, np.inf)
    other[k, rows] = np.inf
    across = np.min(other, axis=0)
    out = np.where(seen[k, rows], along, np.where(np.isfinite(across), across, 0.0))
    return out


def _modes(kind, P: int, feed_mode: int, rapid_mode: int) -> np.ndarray:
    if kind is None:
        return np.full(P, feed_mode, np.int64)
    kind = np.asarray(kind).reshape(-1)
    if kind.shape[0] != P:
        raise ValueError("kind must be (P,)")
    return np.where(kind == RAPID, rapid_mode, np.where(kind == FEED, feed_mode, 0)).astype(np.int64)


def cut(stock: TriDexel, start, end, axis, shape: ToolShape, kind=None, *, bull_tol_mm: float | None = None
        ) -> np.ndarray:
    """Remove from ``stock`` (in place) what the cutting part of ``shape`` sweeps on every FEED
    move (``kind`` (P,) of :data:`~planning.simulate.motion.FEED` / ``RAPID``; None: all feed;
    rapids cut nothing here). ``start``, ``end``: (P,3) tool tip; ``axis`` (P,3) unit tool axis.
    Returns (P,) the volume each move removed, mm^3 (mean of the three families' estimates; each
    within the bound of the module docstring applied to the removed solid)."""
    s, e, a = _as_moves(start, end, axis)
    tol = stock.res / 4 if bull_tol_mm is None else bull_tol_mm
    removed, _, _ = _run(stock, s, e, a, tool_pieces(shape, tol), _modes(kind, s.shape[0], K.M_CUT, 0))
    return removed * stock.res ** 2 / 3.0


def simulate_moves(stock: TriDexel, start, end, axis, shape: ToolShape, kind, *, rapid_clearance_mm: float = 0.0,
                   depth_cap_mm: float = DEPTH_CAP_MM, bull_tol_mm: float | None = None,
                   progress: Progress | None = None) -> MoveRun:
    """Run moves on ``stock`` in program order (in place): a FEED move cuts with the cutting part
    and measures its non-cutting pieces (shank, holder) against the stock (before its own cut
    when the tool moves towards the spindle, where the shank leads, else after it; both exact for
    the move's own sweep); a RAPID measures the whole tool, grown by ``rapid_clearance_mm``
    (radius and both ends), and cuts nothing. Depths saturate at ``depth_cap_mm``. See
    :class:`MoveRun`. ``progress(fraction of the moves done, message)``: after every chunk of
    :data:`CHUNK` moves, at most ~10 times a second (the last call, 1.0, always)."""
    s, e, a = _as_moves(start, end, axis)
    P = s.shape[0]
    kind = np.asarray(kind).reshape(-1)
    tol = stock.res / 4 if bull_tol_mm is None else bull_tol_mm
    modes = _modes(kind, P, K.M_CUT | K.M_HOLDER, K.M_HOLDER | K.M_TOOL)
    grow = np.where(kind == RAPID, float(rapid_clearance_mm), 0.0)
    removed, dep, visits = _run(stock, s, e, a, tool_pieces(shape, tol), modes, grow, depth_cap_mm,
                                progress=None if progress is None else Throttled(progress))
    depth = _depth(dep, a)
    rapid = kind == RAPID
    return MoveRun(removed_mm3=np.where(rapid, 0.0, removed * stock.res ** 2 / 3.0),
                   rapid_depth_mm=np.where(rapid, depth, 0.0), holder_depth_mm=np.where(rapid, 0.0, depth),
                   ray_visits=visits)


def collide(model: TriDexel, start, end, axis, shape: ToolShape, which="holder", *, grow_mm=0.0,
            depth_cap_mm: float = DEPTH_CAP_MM, bull_tol_mm: float | None = None,
            progress: Progress | None = None) -> np.ndarray:
    """(P,) how far the swept tool is in ``model``'s material (the stock, or the obstacles: fixtures,
    riser, table), mm; 0 when clear (module docstring: "Collision depth"). ``which``: ``"holder"``
    (the non-cutting pieces only), ``"tool"`` (the whole tool), or a (P,) bool array (True: whole
    tool). ``grow_mm`` (scalar or (P,)) enlarges the measured pieces (radius and both ends). Depths saturate at
    ``depth_cap_mm``. ``model`` is unchanged; only material inside its domain is seen.
    ``progress``: as :func:`simulate_moves`'."""
    s, e, a = _as_moves(start, end, axis)
    P = s.shape[0]
    if isinstance(which, str):
        if which not in ("holder", "tool"):
            raise ValueError("which must be 'holder', 'tool' or a (P,) bool array")
        modes = np.full(P, K.M_HOLDER | (K.M_TOOL if which == "tool" else 0), np.int64)
    else:
        w = np.asarray(which, bool).reshape(-1)
        if w.shape[0] != P:
            raise ValueError("which must be (P,)")
        modes = np.where(w, K.M_HOLDER | K.M_TOOL, K.M_HOLDER).astype(np.int64)
    tol = model.res / 4 if bull_tol_mm is None else bull_tol_mm
    grow = np.array(np.broadcast_to(np.asarray(grow_mm, dtype=np.float64), (P,)))
    _, dep, _ = _run(model, s, e, a, tool_pieces(shape, tol), modes, grow, depth_cap_mm,
                     progress=None if progress is None else Throttled(progress), what="collision checks")
    return _depth(dep, a)


#: Moves per run of :func:`collides`' first test.
RUN_MOVES = 16


def collides(model: TriDexel, start, end, axis, shape: ToolShape, which: str = "holder", *, grow_mm: float = 0.0,
             block: int = RUN_MOVES, progress: Progress | None = None) -> np.ndarray:
    """(P,) bool: ``collide(model, start, end, axis, shape, which, grow_mm=grow_mm) > 0``, the same
    answer found by runs: the moves in runs of ``block`` (in the order given, e.g. along a path), each
    run first tested as one move from its first start to its last end with the pieces grown by the
    largest distance of a move end of the run from that chord (a move's sweep lies within that
    distance of the chord: the distance to a segment is convex), and only the moves of runs that meet
    material tested one by one. A run whose moves do not share one axis is tested move by move. Where
    the material is far from most moves (the fixtures from a finishing path, the stock from the
    holder), most runs are clear and the check costs a fraction of the move-by-move one."""
    s, e, a = _as_moves(start, end, axis)
    P = s.shape[0]
    if which not in ("holder", "tool"):
        raise ValueError("which must be 'holder' or 'tool'")
    if P < 4 * block:
        return collide(model, s, e, a, shape, which, grow_mm=grow_mm, progress=progress) > 0
    first = np.arange(0, P, block)
    last = np.minimum(first + block - 1, P - 1)
    owner = np.arange(P) // block
    c0, cd = s[first], e[last] - s[first]
    L2 = np.einsum("ij,ij->i", cd, cd)

    def off_chord(q):
        rel = q - c0[owner]
        u = np.clip(np.einsum("ij,ij->i", rel, cd[owner]) / np.where(L2 > 0, L2, 1.0)[owner], 0.0, 1.0)
        return np.linalg.norm(rel - u[:, None] * cd[owner], axis=1)

    dev = np.maximum(off_chord(s), off_chord(e))
    grow = np.maximum.reduceat(dev, first) + float(grow_mm) + 1e-6
    same_axis = np.maximum.reduceat(np.abs(a - a[first][owner]).max(axis=1), first) <= 1e-12
    out = np.zeros(P, dtype=bool)
    runs = np.flatnonzero(same_axis)
    if progress is not None:
        progress(0.0, f"{first.size} runs of {block} moves")
    hit = np.ones(first.size, dtype=bool)
    if runs.size:
        hit[runs] = collide(model, c0[runs], e[last[runs]], a[first[runs]], shape, which, grow_mm=grow[runs]) > 0
    idx = np.flatnonzero(hit[owner])
    if idx.size:
        if progress is not None:
            progress(0.5, f"{idx.size} moves of {int(hit.sum())} runs that met material")
        out[idx] = collide(model, s[idx], e[idx], a[idx], shape, which, grow_mm=grow_mm) > 0
    return out


#: Queries of :func:`column_rise` below this many run on the calling thread's serial kernel.
RISE_SERIAL = 8


def column_rise(model: TriDexel, tips, axis, length_mm, shape: ToolShape, *, grow_mm: float = 0.0,
                tol_mm: float = 0.02, bull_tol_mm: float | None = None, sweep=None) -> np.ndarray:
    """(Q,) for tool tips ``tips`` (Q,3, part frame, mm) on a unit ``axis`` (3,) and lengths
    ``length_mm`` (scalar or (Q,)): the highest position ``s`` in ``[0, length]`` (mm along the axis
    from the tip) at which the whole tool (every piece, cutting or not), grown by ``grow_mm``
    (radius and both ends), meets ``model``'s material; -inf where it meets none on the way.

    So the tool moved straight up the axis from ``tip + s' axis`` to ``tip + length axis`` is clear
    of the material for every ``s' > s``: the same question as :func:`collide` with ``which="tool"``
    on those moves, answered in one pass over the rays of the column instead of a search of swept
    tests. The tool is taken as its radius-monotone hull (each piece from its bottom up to the top
    of the highest piece: a neck narrower than the tip counts as full width), so the answer is
    never below the exact one on the model's rays and at most ``tol_mm`` above it
    (:func:`planning.simulate.dexel_kernels.column_rise`).

    ``sweep`` (Q,3) or (3,): a move across the axis (its component along the axis is dropped): the
    question is then asked of a rapid from ``tip + s axis`` to ``tip + sweep + s axis`` at every
    height ``s`` (the lowest height from which every rapid up to ``length`` is clear is just above the
    answer)."""
    p = np.ascontiguousarray(tips, dtype=np.float64).reshape(-1, 3)
    Q = p.shape[0]
    a = np.asarray(axis, dtype=np.float64).reshape(3)
    nrm = float(np.linalg.norm(a))
    if not nrm > 1e-9:
        raise ValueError("the tool axis must be non-zero")
    a = np.ascontiguousarray(a / nrm)
    length = np.ascontiguousarray(np.broadcast_to(np.asarray(length_mm, dtype=np.float64), (Q,)))
    if not (np.isfinite(p).all() and np.isfinite(length).all()):
        raise ValueError("tips and lengths must be finite")
    out = np.full(Q, -np.inf)
    if Q == 0:
        return out
    if sweep is None:
        d = np.zeros((Q, 3))
    else:
        d = np.array(np.broadcast_to(np.asarray(sweep, dtype=np.float64), (Q, 3)))
        d -= np.outer(d @ a, a)
        if not np.isfinite(d).all():
            raise ValueError("sweep must be finite")
    tol = model.res / 4 if bull_tol_mm is None else bull_tol_mm
    pk, pz0, pz1, pr, _ = tool_pieces(shape, tol)
    # beyond this length along the axis from any tip the line has left the domain
    reach = (float(np.linalg.norm(model.hi - model.lo)) + float(np.abs(p - model.lo).max()) * 2.0
             + float(np.abs(d).max()) * 2.0 + 1.0)
    kern = K.column_rise if Q < RISE_SERIAL else K.column_rise_parallel
    kern(model.lo, model.res, model.n, model.base, model.off, model.cnt, model.pool, p, a,
         np.maximum(length, 0.0), np.ascontiguousarray(d), pk, pz0, np.where(np.isfinite(pz1), pz1, 1e300), pr,
         float(grow_mm), float(tol_mm), reach, model.sbase, model.nseg, model.seg_lo, model.seg_hi, out)
    return out


# -------------------------------------------------------------------------------- deviation

def deviation_bound_mm(resolution_mm: float, radius_mm: float, delta_mm: float = 0.0) -> float:
    """The bound of :func:`signed_deviation` on a surface whose radii of curvature are at least
    ``radius_mm``, for a point ``delta_mm`` off it, at the worst tilt: ``3/4 r^2 / rho +
    delta^2 / rho``."""
    return 0.75 * resolution_mm ** 2 / radius_mm + delta_mm ** 2 / radius_mm


def signed_deviation(stock: TriDexel, points, normals, max_mm: float = 5.0, highest: bool = False) -> np.ndarray:
    """(N,) signed distance (mm) from each point to the material surface, along its unit normal
    (pointing out of the part): positive = material left above the point, negative = cut below
    it (gouge), clipped at +-``max_mm``; NaN for a zero normal or a point outside the domain.

    Read on the ray family most aligned with the normal (``c = |n_k| >= 1/sqrt(3)``): on each of
    the 4 rays around the point, the material boundary of the right side (upper ends when
    ``n_k > 0``) nearest the point (within ``(max_mm + 2 r)/c``), interpolated bilinearly at the
    point and projected on the normal: ``(b - p_k) * n_k``. Exact (to rounding) for a plane. On a
    smooth surface of normal curvature at most ``kappa`` the error is at most
    ``r^2 kappa / (4 c^2)`` (bilinear interpolation: ``r^2/8 (|b_uu| + |b_vv|)`` with
    ``|b_uu|, |b_vv| <= kappa / c^3``, c taken where the ray meets the surface) plus, for a point
    off the surface by ``delta``, ``delta^2 kappa tan^2(theta) / 2`` (the ray meets the surface
    beside the normal's foot; ``theta`` the angle between the normal and the ray), so at most
    ``3/4 r^2 kappa + delta^2 kappa`` (:func:`deviation_bound_mm`): e.g. 0.021 mm at r = 0.5 mm on
    a 3 mm radius where the normal is along a ray, 0.062 mm at the worst tilt. At an edge or a cusp
    narrower than ``r`` the interpolation mixes the two sides. Rays without such a boundary near
    the point are left out of the interpolation; with none at all the point is +max_mm when in
    material, else -max_mm.

    ``highest=True`` returns instead the highest of the 4 rays' readings ``(b - p_k) n_k``: a
    point on a peak of the machined surface (a sparse cloud's ball drop dips between the points,
    so every scan point tops a small peak) reads low when interpolated; a cut below the point must
    show on all four rays to read negative here."""
    out, out_hi = deviation_pair(stock, points, normals, max_mm)
    return out_hi if highest else out


def deviation_pair(stock: TriDexel, points, normals, max_mm: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """Both readings of :func:`signed_deviation` in one pass: (interpolated, highest of the 4 rays)."""
    p = np.ascontiguousarray(points, float).reshape(-1, 3)
    nr = np.ascontiguousarray(normals, float).reshape(-1, 3)
    if p.shape != nr.shape:
        raise ValueError("points and normals must both be (N,3)")
    out = np.empty(p.shape[0])
    out_hi = np.empty(p.shape[0])
    K.deviation(stock.lo, stock.res, stock.n, stock.base, stock.off, stock.cnt, stock.pool, p, nr,
                float(max_mm), out, out_hi)
    return out, out_hi
