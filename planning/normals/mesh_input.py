"""Stage 2 for meshes: the points a mesh is planned on, and their normals from its facets (issue 18).

:func:`mesh_cloud` turns a :class:`~planning.inputs.Cloud` that carries triangles (STL, OBJ, PLY with
faces, a structured E57 scan, a relief image) into the cloud the point stages run on: its vertices
followed by points on its edges and facets (:func:`planning.inputs.facet_points.points_on_facets`,
``input.mesh_sample_mm`` apart at most). The faces still index the vertices, which come first, so
the finishing ball can rest on the triangles (:mod:`planning.toolpath.surface`).

:func:`facet_point_normals` gives every one of those points an outward unit normal from the
triangles (``normals.method = facets``): the winding is made consistent and outward per connected
component (:func:`planning.normals.facets.orient_outward`); a vertex gets the normalised mean of its
facets' unit normals (Chui, Chiu and Yu 2008, eq. 8: :func:`planning.normals.facets.vertex_normals`),
a point inside a facet that facet's normal, a point on an edge the normalised mean of its (one or
two) facets' normals.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from planning.errors import InputError
from planning.inputs import Cloud
from planning.inputs.facet_points import FacetPoints, points_on_facets
from planning.normals.facets import facet_normals, orient_outward, vertex_normals


def mesh_cloud(cloud: Cloud, spacing_mm: float, max_points: int) -> tuple[Cloud, FacetPoints | None]:
    """``cloud`` with its points extended by points on its facets (module docstring), and those
    :class:`FacetPoints`; ``cloud`` unchanged and None when it carries no triangles. Normals read from
    the file stay on the vertices; the new points have none (NaN rows)."""
    faces = getattr(cloud, "faces", None)
    if faces is None or len(faces) == 0:
        return cloud, None
    fp = points_on_facets(cloud.points, faces, spacing_mm, max_points)
    normals = None
    if cloud.normals is not None:
        normals = np.full((fp.points.shape[0], 3), np.nan)
        normals[:fp.n_vertices] = cloud.normals
    return replace(cloud, points=fp.points, normals=normals), fp


def facet_point_normals(cloud: Cloud, facets: FacetPoints | None) -> tuple[np.ndarray, np.ndarray]:
    """``(sample_index, normals)``: the points of ``cloud`` (as :func:`mesh_cloud` made it) with a normal
    from the triangles, and those (n,3) unit outward normals (module docstring). Raises
    :class:`InputError` ``missing_faces`` for a cloud without triangles."""
    if facets is None or cloud.faces is None or len(cloud.faces) == 0:
        raise InputError("normals.method is 'facets' but the file carries no triangles (STL, OBJ, PLY with faces, a "
                         "structured E57 scan or an image); use normals.method = sphere_throwing",
                         code="missing_faces")
    nv = facets.n_vertices
    verts = cloud.points[:nv]
    faces = orient_outward(verts, cloud.faces)
    fn = facet_normals(verts, faces)
    out = np.full((cloud.points.shape[0], 3), np.nan)
    out[:nv] = vertex_normals(verts, faces)
    par = facets.parents[nv:]
    acc = np.zeros((par.shape[0], 3))
    for col in range(2):
        ok = par[:, col] >= 0
        acc[ok] += fn[par[ok, col]]
    length = np.linalg.norm(acc, axis=1)
    good = length > 1e-12
    acc[good] /= length[good, None]
    acc[~good] = np.nan
    out[nv:] = acc
    keep = np.flatnonzero(np.isfinite(out).all(axis=1))
    return keep.astype(np.int64), out[keep]
