"""Stage 7, tool paths per area, in the area's frame (tool axis = +Z): roughing by Z levels (Popescu 2014,
Tchanchane & Bey), ball-end finishing by ball drop on the whole cloud (Sood 2015, Makki 2010 §4), CL
reduction and arcs, and the gouge check of the final moves.

Entry: :func:`planning.toolpath.area_paths.area_toolpaths` (labelled cloud and chosen axes -> one
:class:`~planning.toolpath.area_paths.AreaPaths` per area).
"""
