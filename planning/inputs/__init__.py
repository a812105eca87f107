"""Stage 1, the cloud: readers per file format, validation, and the reference samples.

Entry: :func:`read_cloud` (bytes or a path -> :class:`Cloud`, points in mm) in
:mod:`planning.inputs.cloud`, which detects the format and dispatches to the readers
:mod:`planning.inputs.ply`, :mod:`planning.inputs.pcd` and :mod:`planning.inputs.text` (XYZ/CSV/TXT);
:func:`validate_points` (:mod:`planning.inputs.validate`) checks any ``(N, 3)`` array of points in mm.
The reference clouds generated in code are the subpackage :mod:`planning.inputs.samples`
(:func:`~planning.inputs.samples.make_sample`). Writing a cloud to PLY is
:func:`planning.report.files.write_ply`.
"""

from planning.inputs.cloud import FORMATS, UNIT_SCALE, Cloud, read_cloud, validate_points

__all__ = ["FORMATS", "UNIT_SCALE", "Cloud", "read_cloud", "validate_points"]
