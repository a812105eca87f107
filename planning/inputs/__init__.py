"""Stage 1, the cloud: readers per file format, validation, and the reference samples.

Entry: :func:`planning.inputs.cloud.read_cloud` (bytes or a path -> :class:`~planning.inputs.cloud.Cloud`, points in mm).
"""
