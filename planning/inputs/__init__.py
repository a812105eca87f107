"""Stage 1, the cloud: readers per file format, validation, and the reference samples.

Entry: :func:`read_input` (a file and the plan's ``input`` parameters -> :class:`Cloud`) and
:func:`read_cloud` (bytes or a path -> :class:`Cloud`, points in mm, faces where the file has them) in
:mod:`planning.inputs.cloud`, which detects the format and dispatches to the readers
:mod:`planning.inputs.ply`, :mod:`planning.inputs.pcd`, :mod:`planning.inputs.text` (XYZ/CSV/TXT),
:mod:`planning.inputs.stl`, :mod:`planning.inputs.obj`, :mod:`planning.inputs.las` (LAS/LAZ),
:mod:`planning.inputs.e57` and :mod:`planning.inputs.relief` (images as reliefs);
:func:`validate_points` (:mod:`planning.inputs.validate`) checks any ``(N, 3)`` array of points in mm,
:func:`validate_faces` the triangles of a mesh.
The reference clouds generated in code are the subpackage :mod:`planning.inputs.samples`
(:func:`~planning.inputs.samples.make_sample`). Writing a cloud to PLY is
:func:`planning.report.files.write_ply`.
"""

from planning.inputs.cloud import (
                                   FORMATS,
                                   UNIT_SCALE,
                                   Cloud,
                                   read_cloud,
                                   read_input,
                                   validate_faces,
                                   validate_points,
)

__all__ = ["FORMATS", "UNIT_SCALE", "Cloud", "read_cloud", "read_input", "validate_faces", "validate_points"]
