"""Facet and vertex normals of meshes and their orientation (planning.normals.facets): Chui, Chiu
and Yu 2008 eq. 8 on vertices with known facets, outward normals on closed and open meshes whose
windings were scrambled."""

from __future__ import annotations

import numpy as np
import pytest

from planning.errors import ParameterError
from planning.normals.facets import facet_normals, orient_outward, vertex_normals


def _cube(lo=(0.0, 0.0, 0.0), size=1.0):
    V = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float) * size + np.asarray(lo)
    # outward quads (index = 4x + 2y + z), two triangles each
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    F = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    return V, F


def _icosphere(n=2, centre=(0.0, 0.0, 0.0), radius=1.0):
    t = (1 + 5 ** 0.5) / 2
    V = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    F = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
                  [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
                  [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    V /= np.linalg.norm(V, axis=1)[:, None]
    for _ in range(n):
        e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
        u, inv = np.unique(e, axis=0, return_inverse=True)
        mid = V[u[:, 0]] + V[u[:, 1]]
        mid /= np.linalg.norm(mid, axis=1)[:, None]
        m = inv.reshape(3, -1).T + len(V)
        V = np.concatenate([V, mid])
        a, b, c = F.T
        ab, bc, ca = m.T
        F = np.concatenate([np.stack(s, 1) for s in ((a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca))])
    return V * radius + np.asarray(centre), F


def _scramble(F, seed):
    flip = np.random.default_rng(seed).random(F.shape[0]) < 0.5
    return np.where(flip[:, None], F[:, ::-1], F)


def _consistent(F):
    """Every undirected edge run once each way (closed, consistently wound)."""
    he = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    s = {tuple(e) for e in he.tolist()}
    return len(s) == len(he) and all((b, a) in s for a, b in s)


@pytest.mark.parametrize("seed", range(3))
def test_cube_outward_after_scrambling(seed):
    V, F = _cube()
    Fs = _scramble(F, seed)
    Fo = orient_outward(V, Fs)
    assert _consistent(Fo)
    assert np.array_equal(np.sort(Fo, axis=1), np.sort(F, axis=1))       # the same facets, in order
    n = facet_normals(V, Fo)
    c = V[Fo].mean(axis=1) - 0.5
    # each facet's normal is the axis of the face it lies on, pointing out
    axis = np.zeros_like(c)
    k = np.argmax(np.abs(c), axis=1)
    axis[np.arange(len(k)), k] = np.sign(c[np.arange(len(k)), k])
    assert np.allclose(n, axis, atol=1e-15)
    # a cube turned inside out is turned back
    assert np.array_equal(orient_outward(V, F[:, ::-1]), orient_outward(V, F))


@pytest.mark.parametrize("seed", range(3))
def test_icosphere_and_two_components(seed):
    V1, F1 = _icosphere(2, centre=(0, 0, 0), radius=3.0)
    V2, F2 = _cube(lo=(10, 0, 0), size=2.0)
    V = np.concatenate([V1, V2])
    F = np.concatenate([_scramble(F1, seed), (F2 + len(V1))[:, ::-1]])      # the cube wholly inside out
    Fo = orient_outward(V, F)
    assert _consistent(Fo)
    n = facet_normals(V, Fo)
    c = V[Fo].mean(axis=1)
    sph = np.arange(len(F1))
    assert np.all(np.einsum("ij,ij->i", n[sph], c[sph]) > 0)
    cub = np.arange(len(F1), len(F))
    assert np.all(np.einsum("ij,ij->i", n[cub], c[cub] - [11, 1, 1]) > 0)
    vn = vertex_normals(V, Fo)
    # on the sphere the mean of the facet normals is close to radial
    assert np.all(np.einsum("ij,ij->i", vn[:len(V1)], V1 / 3.0) > np.cos(np.radians(3)))
    assert np.allclose(np.linalg.norm(vn, axis=1), 1.0)


def test_open_components_face_away_from_their_centroid():
    V, F = _icosphere(2, radius=5.0)
    cap = F[V[F].mean(axis=1)[:, 2] > 1.0]                 # an open cap of the sphere
    Fo = orient_outward(V, _scramble(cap, 4))
    n = facet_normals(V, Fo)
    assert np.all(np.einsum("ij,ij->i", n, V[Fo].mean(axis=1)) > 0)           # away from the sphere's centre
    # a flat patch has no majority: it faces +Z
    g = np.arange(4.0)
    X, Y = np.meshgrid(g, g, indexing="ij")
    Vp = np.stack([X.ravel(), Y.ravel(), np.zeros(16)], 1)
    a = (np.arange(3)[:, None] * 4 + np.arange(3)[None, :]).ravel()
    Fp = np.concatenate([np.stack([a, a + 5, a + 4], 1), np.stack([a, a + 1, a + 5], 1)])     # facing -Z
    assert np.all(facet_normals(Vp, Fp)[:, 2] == -1.0)
    assert np.all(facet_normals(Vp, orient_outward(Vp, _scramble(Fp, 1)))[:, 2] == 1.0)


def test_vertex_normal_is_the_unweighted_mean_of_facet_normals():
    # vertex 0 on three facets of very different areas, in the planes z = 0, x = 0 and x + y + z = 0
    V = np.array([[0, 0, 0], [100, 0, 0], [0, 100, 0], [0, 0, 1], [0, 1, 0],
                  [1, -1, 0], [0, 1, -1], [7, 7, 7]], float)
    F = np.array([[0, 1, 2], [0, 3, 4], [0, 5, 6]])
    fn = facet_normals(V, F)
    assert np.allclose(fn[0], [0, 0, 1]) and np.allclose(fn[1], [-1, 0, 0])
    assert np.allclose(fn[2], np.array([1, 1, 1]) / np.sqrt(3))
    m = (fn[0] + fn[1] + fn[2]) / 3.0                      # eq. 8
    vn = vertex_normals(V, F)
    assert np.allclose(vn[0], m / np.linalg.norm(m), atol=1e-15)
    assert np.allclose(vn[1], fn[0]) and np.allclose(vn[3], fn[1])
    assert np.all(np.isnan(vn[7]))                         # on no facet


def test_degenerate_facets_and_opposite_normals():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [5, 5, 5]], float)
    F = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 1]])        # a zero-area facet; the first facet twice, reversed
    fn = facet_normals(V, F)
    assert np.all(np.isnan(fn[1])) and np.allclose(fn[0], -fn[2])
    vn = vertex_normals(V, F)
    assert np.all(np.isnan(vn[0])) and np.all(np.isnan(vn[3])) and np.all(np.isnan(vn[4]))


def test_moebius_strip_is_wound_along_a_tree():
    k = 20
    th = np.linspace(0, 2 * np.pi, k, endpoint=False)
    V = np.array([[(1 + s * np.cos(t / 2)) * np.cos(t), (1 + s * np.cos(t / 2)) * np.sin(t), s * np.sin(t / 2)]
                  for t in th for s in (-0.3, 0.3)])
    F = []
    for q in range(k):
        a, b = 2 * q, 2 * q + 1
        c, d = (2 * q + 2) % (2 * k), (2 * q + 3) % (2 * k)
        if q == k - 1:
            c, d = d, c
        F += [[a, b, d], [a, d, c]]
    F = np.array(F)
    Fo = orient_outward(V, _scramble(F, 2))
    assert np.array_equal(np.sort(Fo, axis=1), np.sort(F, axis=1))
    he = np.concatenate([Fo[:, [0, 1]], Fo[:, [1, 2]], Fo[:, [2, 0]]])
    # one seam must remain: at most one interior edge run twice the same way
    _, cnt = np.unique(he, axis=0, return_counts=True)
    assert cnt.max() == 2 and (cnt == 2).sum() == 1


def test_bad_input():
    with pytest.raises(ParameterError):
        facet_normals(np.zeros((3, 2)), [[0, 1, 2]])
    with pytest.raises(ParameterError):
        vertex_normals(np.zeros((3, 3)), [[0, 1, 3]])
    with pytest.raises(ParameterError):
        orient_outward(np.zeros((3, 3)), [[0.0, 1.0, 2.0]])
    assert orient_outward(np.zeros((3, 3)), np.zeros((0, 3), np.int64)).shape == (0, 3)
