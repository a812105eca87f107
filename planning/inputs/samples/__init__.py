"""Stage 1, reference clouds generated in code (docs/design.md "Reference cases"): nothing large is committed.

Every sample is a :class:`Sample` with points in millimetres, the exact outward unit normal of the
underlying surface at each point (before any noise), a one-line description and a ``meta`` dict
holding the generation parameters and the known answers a test can check against. The same
arguments always give the same arrays (all randomness comes from ``numpy.random.default_rng(seed)``).

- :func:`half_sphere` - Makki et al. 2010 §3.2: 2537 simulated points on a half sphere, density
  not uniform, exact normals, no noise (the paper's first use case: two set-ups, tool 10 mm,
  cone [10, 80] deg).
- :func:`femur_like` - the paper's second case: a bone-like closed surface about 400 mm long,
  "scanned" from 8 directions with Gaussian noise along each view (paper: 1,033,760 points,
  45 points/mm^2, 8 sensor orientations). The surface is a smooth union of implicit primitives;
  :func:`femur_implicit` evaluates it, so a test can measure how far a point lies from it.
- :func:`slot` - a block with a straight slot (or a closed pocket) cut in its top: the floor is
  reachable only by tool axes close to the slot's vertical plane.
- :func:`post_wall` - a plate with a cylindrical post standing a known gap away from a wall.
- :func:`draft_slot` - a block with a deep, narrow slot whose walls lean out: with a narrow tool
  cone no fixed axis finishes its floor and both walls, one pass direction with an axis per
  position does (simultaneous 5-axis, issue 19).
- :func:`filleted_box` - a 60 x 40 x 20 mm box with its top and vertical edges rounded (10 mm
  fillets): the part a new user would bring.
- :func:`range_scan` - a simulated multi-view range scan of the femur, the half sphere, the slot
  block or the filleted box (``shape``; registered also as ``range_femur``, ``range_half_sphere``,
  ``range_slot``, ``range_filleted_box``): per view a grid of rays in scan lines (0.3 mm along,
  0.6 mm across), the first hit on the exact surface, holes where the surface turns away, noise
  along the rays, a few outliers and small registration errors between the views; the part is
  scaled so that about ``n_points`` (40,000) are recorded. :func:`shape_distance` measures how far
  a point lies from the shape scanned.

Frames: millimetres, z up. The femur, the slot block, the post plate and the filleted box stand on
the table: the lowest point of the exact surface at z = 0 and the bounding box centred in x and y
(the slot and the post lie on x = 0); the half sphere is centred at the origin, z >= 0.

Modules: :mod:`~planning.inputs.samples.common` (:class:`Sample`, argument checks),
:mod:`~planning.inputs.samples.hemisphere` (:func:`half_sphere`),
:mod:`~planning.inputs.samples.primitives` (implicit sphere, ellipsoid, capsule, bent tube),
:mod:`~planning.inputs.samples.femur` (:func:`femur_like`, :func:`femur_implicit`),
:mod:`~planning.inputs.samples.scanner` (the simulated scanner views of the femur),
:mod:`~planning.inputs.samples.prismatic` (:func:`slot`, :func:`post_wall`, :func:`draft_slot`),
:mod:`~planning.inputs.samples.filleted` (:func:`filleted_box`),
:mod:`~planning.inputs.samples.rangescan` (:func:`range_scan`); this package holds the registry
:data:`SAMPLES` and :func:`make_sample`.
"""

from __future__ import annotations

from collections.abc import Callable

from planning.errors import ParameterError
from planning.inputs.samples.common import Sample
from planning.inputs.samples.femur import (
    FEMUR_DIMENSIONS_MM,
    femur_implicit,
    femur_like,
)
from planning.inputs.samples.filleted import filleted_box, filleted_box_inner_box
from planning.inputs.samples.hemisphere import half_sphere
from planning.inputs.samples.prismatic import (
    draft_slot,
    post_wall,
    slot,
    slot_floor_max_tilt_deg,
)
from planning.inputs.samples.rangescan import (
    RANGE_SHAPES,
    range_femur,
    range_filleted_box,
    range_half_sphere,
    range_scan,
    range_slot,
    shape_distance,
)

__all__ = [
    "FEMUR_DIMENSIONS_MM",
    "RANGE_SHAPES",
    "SAMPLES",
    "Sample",
    "draft_slot",
    "femur_implicit",
    "femur_like",
    "filleted_box",
    "filleted_box_inner_box",
    "half_sphere",
    "make_sample",
    "post_wall",
    "range_femur",
    "range_filleted_box",
    "range_half_sphere",
    "range_scan",
    "range_slot",
    "shape_distance",
    "slot",
    "slot_floor_max_tilt_deg",
]


#: Generator of each reference sample, by name.
SAMPLES: dict[str, Callable[..., Sample]] = {
    "half_sphere": half_sphere,
    "femur_like": femur_like,
    "slot": slot,
    "post_wall": post_wall,
    "filleted_box": filleted_box,
    "draft_slot": draft_slot,
    "range_scan": range_scan,
    "range_femur": range_femur,
    "range_half_sphere": range_half_sphere,
    "range_slot": range_slot,
    "range_filleted_box": range_filleted_box,
}


def make_sample(name: str, **kwargs) -> Sample:
    """Generate the reference sample ``name`` (a key of :data:`SAMPLES`) with ``kwargs``.

    An unknown name, or an argument the generator does not take, raises :class:`ParameterError`
    listing what is accepted.
    """
    gen = SAMPLES.get(name) if isinstance(name, str) else None
    if gen is None:
        raise ParameterError(f"sample = {name!r}: unknown; must be one of {', '.join(SAMPLES)}",
                             parameter="sample", value=repr(name), allowed=list(SAMPLES))
    import inspect
    accepted = list(inspect.signature(gen).parameters)
    bad = [k for k in kwargs if k not in accepted]
    if bad:
        raise ParameterError(f"sample {name!r} takes no argument {', '.join(bad)}; it takes "
                             f"{', '.join(accepted)}", parameter=bad[0], value=repr(kwargs[bad[0]]),
                             allowed=accepted)
    return gen(**kwargs)
