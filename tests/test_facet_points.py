"""Points laid on a mesh's facets (issue 18): no spot of a facet farther than the spacing from a point, the
vertices first, parents that name the facets a point lies on, the cap on the count, and the count the
service estimates memory from equal to what the plan builds."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from mesh_files import cube_mesh, sphere_mesh
from planning.inputs.facet_points import planned_point_count, points_on_facets


def _on_triangles(V, F, n_per=400, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.random((F.shape[0], n_per, 2))
    flip = u.sum(axis=2) > 1
    u[flip] = 1 - u[flip]
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return (a[:, None] + u[..., :1] * (b - a)[:, None] + u[..., 1:] * (c - a)[:, None]).reshape(-1, 3)


def test_every_spot_of_every_facet_is_near_a_point_and_points_lie_on_their_facets():
    V, F = cube_mesh(20.0)
    s = 1.0
    fp = points_on_facets(V, F, s)
    assert np.array_equal(fp.points[:8], V) and fp.n_vertices == 8
    d, _ = cKDTree(fp.points).query(_on_triangles(V, F))
    assert d.max() <= s                            # lattice cells are at most s across
    # each non-vertex point lies in the plane of (each of) its parent facets
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    for col in range(2):
        k = np.flatnonzero(fp.parents[:, col] >= 0)
        f = fp.parents[k, col]
        off = np.einsum("ij,ij->i", fp.points[k] - V[F[f, 0]], n[f])
        assert np.abs(off).max() < 1e-9
    assert (fp.parents[:8] == -1).all() and (fp.parents[8:, 0] >= 0).all()
    # the shared diagonal's points have both facets of their face of the cube
    both = fp.parents[:, 1] >= 0
    assert both.any()


def test_cap_widens_the_spacing_and_count_matches():
    V, F = sphere_mesh(16, 32, 25.0)
    for s, cap in ((0.5, 2_000_000), (0.2, 20_000)):
        fp = points_on_facets(V, F, s, max_points=cap)
        assert fp.points.shape[0] <= cap
        # the estimate is what the plan builds, or the cap where the spacing had to widen to fit it
        assert planned_point_count(V, F, s, cap) == (fp.points.shape[0] if fp.spacing_mm == s else cap)
    fp = points_on_facets(V, F, 0.2, max_points=20_000)
    assert fp.spacing_mm > 0.2 and fp.points.shape[0] > 10_000
    assert planned_point_count(V, F, 0.5) == points_on_facets(V, F, 0.5).points.shape[0]
    assert planned_point_count(V, None, 0.5) == V.shape[0]
