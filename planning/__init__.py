"""scanmill planning core: pure functions on numpy arrays (no web, no database).

The packages, in the order the data flows (:func:`planning.pipeline.run_plan` calls them in turn;
docs/design.md "The pipeline" describes each):

1. ``inputs``        file bytes -> points (N,3) in mm: readers per format, validation, reference samples
2. ``normals``       sphere throwing: sampled points and outward normals (Makki 2010 §2.1)
3. ``orientations``  candidate tool axes on the Gaussian sphere, machine kinematics and rotary travel (§2.2.1-2.2.2)
4. ``visibility``    tool cone, X/Y/Z travel, tool and holder against fixtures and the cloud (§2.2.3-2.2.4)
5. ``setups``        the fewest orientations covering the part with the least overlap, solved exactly (§3.1)
6. ``areas``         one set-up per point (§3.1)
7. ``toolpath``      per-area roughing and ball-end finishing in the set-up's frame (Sood 2015, Popescu 2014, ...)
8. ``post``          neutral JSON moves and G-code dialects for 3+2 machining
9. ``report``        plan.json, plan.npz, the segmentation PLY and the PNG preview

``geometry`` (rasters, bases, the tool assembly, fixtures, collision queries) may be used by every
stage and uses none; ``errors`` holds the typed errors every stage raises; ``budget`` estimates the
memory a plan will need from its parameters, before it runs.
"""

# First, before any module here defines an @njit(cache=True) kernel: numba's cache directory (outside the
# source tree) and threading layer (planning/kernel_cache.py).
from planning import kernel_cache as _kernel_cache  # noqa: E402, F401
