"""Stage 2, normals by sphere throwing (Makki 2010 §2.1).

Entry: :func:`planning.normals.throwing.sphere_throwing` (points -> sampled points and outward normals).

Entry: :func:`sphere_throwing` (points, mm -> sampled point indices and outward unit normals,
:class:`NormalsResult`), in :mod:`planning.normals.throwing`.
"""

from planning.normals.throwing import NormalsResult, sphere_throwing

__all__ = ["NormalsResult", "sphere_throwing"]
