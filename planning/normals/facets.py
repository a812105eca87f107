"""Normals of a triangle mesh (meshes as inputs; Chui, Chiu and Yu 2008 §3.3).

* :func:`facet_normals`: the unit normal of each facet by the right-hand rule on its winding,
  ``(B - A) x (C - A) / |...|`` (NaN for a facet of zero area).
* :func:`vertex_normals`: Chui et al. eq. 8, the local surface normal of a vertex is the mean of the
  normals of its ``q`` incident facets, ``n_i = (sum_j n_mj) / q``, unweighted (neither by area
  nor by angle: the paper says so, and its Fig. 22 shows plain facet normals). The paper then offsets
  the contact point by R along ``n_i``, which needs a unit vector, so the mean is normalised here.
  Facets of zero area have no normal and are left out of ``q``; a vertex on no facet (or whose
  facet normals cancel) gets NaN.
* :func:`orient_outward`: files often wind their facets inconsistently, and then facet and vertex
  normals point both ways. It makes the winding consistent over each connected component (facets
  joined by shared edges) and outward: closed components (every edge shared by exactly two facets)
  get a positive signed volume; open ones face away from the component's centroid for the
  (area-weighted) majority of their facets, and a component with no majority (a flat patch) faces
  +Z. Consistency comes from one connected-components pass on the orientation double cover (each
  facet as itself and flipped; two facets sharing an edge agree when they run it in opposite
  directions), so no per-facet Python loop; a component that cannot be oriented (a Moebius strip,
  some non-manifold fans) is oriented along a breadth-first spanning tree instead, and the facets
  where it then disagrees with a neighbour are unavoidable.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components

from planning.errors import ParameterError


def _mesh(vertices, faces):
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces)
    if V.ndim != 2 or V.shape[1] != 3:
        raise ParameterError("vertices must be a (V,3) array")
    if F.ndim != 2 or F.shape[1] != 3 or (F.size and not np.issubdtype(F.dtype, np.integer)):
        raise ParameterError("faces must be a (T,3) array of vertex indices")
    F = F.astype(np.int64, copy=False)
    if F.size and (F.min() < 0 or F.max() >= V.shape[0]):
        raise ParameterError(f"faces: vertex indices must be in [0, {V.shape[0]})")
    return V, F


def _cross(V, F):
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return np.cross(B - A, C - A)


def facet_normals(vertices, faces) -> np.ndarray:
    """(T,3) unit normal of each facet, right-hand rule on its winding; NaN rows for zero area."""
    V, F = _mesh(vertices, faces)
    n = _cross(V, F)
    ln = np.linalg.norm(n, axis=1)
    out = np.full_like(n, np.nan)
    ok = ln > 0
    out[ok] = n[ok] / ln[ok, None]
    return out


def vertex_normals(vertices, faces) -> np.ndarray:
    """(V,3) unit vertex normals: the normalised mean of the unit normals of the facets incident to
    each vertex (Chui et al. 2008 eq. 8, unweighted); NaN for vertices on no facet of non-zero area
    (a facet that names a vertex twice has zero area, so it counts for none)."""
    V, F = _mesh(vertices, faces)
    fn = facet_normals(V, F)
    ok = np.all(np.isfinite(fn), axis=1)
    F, fn = F[ok], fn[ok]
    vi = F.ravel()                                   # one incidence per (facet, corner)
    nr = np.repeat(fn, 3, axis=0)
    s = np.zeros((V.shape[0], 3))
    np.add.at(s, vi, nr)
    q = np.bincount(vi, minlength=V.shape[0]).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s / q[:, None]                    # eq. 8
        ln = np.linalg.norm(mean, axis=1)
        out = mean / ln[:, None]
    out[~(ln > 1e-12)] = np.nan
    return out


def _edge_graph(F):
    """Pairs of facets sharing an undirected edge: (i, j, same) with ``same`` true where both run
    the edge in the same direction (then one of them must be flipped), and the count of facets on
    each undirected edge of each facet (T,3)."""
    T = F.shape[0]
    a = F.reshape(-1)
    b = np.roll(F, -1, axis=1).reshape(-1)             # half-edges (F0,F1), (F1,F2), (F2,F0)
    face = np.repeat(np.arange(T), 3)
    keep = a != b
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    fwd = a < b
    key = lo.astype(np.int64) * (int(max(F.max(), 0)) + 1) + hi
    key = np.where(keep, key, -1 - np.arange(3 * T))   # degenerate edges pair with nothing
    order = np.argsort(key, kind="stable")
    ks = key[order]
    new = np.ones(ks.size, dtype=bool)
    new[1:] = ks[1:] != ks[:-1]
    grp = np.cumsum(new) - 1
    gstart = np.flatnonzero(new)
    count = np.bincount(grp)
    # every facet on an edge joins the edge's first facet (a star over non-manifold fans)
    head = order[gstart[grp]]
    other = order
    m = other != head
    i, j = face[head[m]], face[other[m]]
    same = fwd[head[m]] == fwd[other[m]]
    per_halfedge = np.empty(3 * T, np.int64)
    per_halfedge[order] = count[grp]
    per_halfedge[~keep] = 0
    return i, j, same, per_halfedge.reshape(T, 3)


def orient_outward(vertices, faces) -> np.ndarray:
    """Faces (T,3) int64, a copy of ``faces`` with some rows' winding reversed so that each connected
    component (facets joined by shared edges) is wound consistently and outward: positive signed
    volume for closed components, for open ones the area-weighted majority of facets facing away
    from the component's centroid (+Z when there is none). See the module docstring."""
    V, F = _mesh(vertices, faces)
    T = F.shape[0]
    if T == 0:
        return F.copy()
    i, j, same, per_edge = _edge_graph(F)
    # components of the facet graph
    g = coo_matrix((np.ones(i.size), (i, j)), shape=(T, T))
    ncomp, comp = connected_components(g, directed=False)
    # the double cover: node f (as wound) and T + f (flipped); opposite directions join f-g and
    # f'-g', same directions join f-g' and f'-g
    src = np.concatenate([i, i + T])
    dst = np.concatenate([np.where(same, j + T, j), np.where(same, j, j + T)])
    gd = coo_matrix((np.ones(src.size), (src, dst)), shape=(2 * T, 2 * T))
    _, lab = connected_components(gd, directed=False)
    root = np.full(ncomp, T)
    np.minimum.at(root, comp, np.arange(T))             # lowest facet of each component
    flip = lab[:T] != lab[root[comp]]
    bad = lab[:T] == lab[T:]                            # f and its flip joined: not orientable
    if bad.any():
        gs = (g + g.T).tocsr()
        badc = np.unique(comp[bad])
        inb = np.isin(comp[i], badc)
        par = {}
        for a, b, sm in zip(i[inb].tolist(), j[inb].tolist(), same[inb].tolist()):
            par.setdefault((a, b), sm)
            par.setdefault((b, a), sm)
        for c in badc:
            r = root[c]
            order, pred = breadth_first_order(gs, r, directed=False, return_predecessors=True)
            flip[r] = False
            for f in order[1:]:
                p = pred[f]
                flip[f] = flip[p] ^ par[(p, f)]
    Fo = np.where(flip[:, None], F[:, ::-1], F)
    # outward, per component
    A, B, C = V[Fo[:, 0]], V[Fo[:, 1]], V[Fo[:, 2]]
    cr = np.cross(B - A, C - A)
    area = 0.5 * np.linalg.norm(cr, axis=1)
    closed = np.bincount(comp, weights=np.any(per_edge != 2, axis=1).astype(np.float64), minlength=ncomp) == 0
    cen_f = (A + B + C) / 3.0
    wsum = np.bincount(comp, weights=area, minlength=ncomp)
    cen = np.stack([np.bincount(comp, weights=area * cen_f[:, k], minlength=ncomp) for k in range(3)], 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cen = np.where(wsum[:, None] > 0, cen / wsum[:, None], 0.0)
    # signed volume about the component's centroid (the same for any origin when closed)
    rel = [X - cen[comp] for X in (A, B, C)]
    vol = np.bincount(comp, weights=np.einsum("ij,ij->i", rel[0], np.cross(rel[1], rel[2])) / 6.0,
                      minlength=ncomp)
    # open: area-weighted vote of the facets facing away from the centroid
    face_away = np.sign(np.einsum("ij,ij->i", cr, cen_f - cen[comp]))
    vote = np.bincount(comp, weights=area * face_away, minlength=ncomp)
    up = np.bincount(comp, weights=cr[:, 2], minlength=ncomp)
    score = np.where(closed, vol, np.where(vote != 0, vote, up))
    inward = score < 0
    Fo = np.where(inward[comp][:, None], Fo[:, ::-1], Fo)
    return np.ascontiguousarray(Fo, dtype=np.int64)


__all__ = ["facet_normals", "orient_outward", "vertex_normals"]
