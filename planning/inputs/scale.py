"""Stage 1, the cloud: does the part's size make sense for the tool? (issue 18, unit and scale sanity)

A scan exported in metres and read with the default ``input.units = mm`` is a part a few hundredths of
a millimetre across. Every later stage runs on it without complaint (sphere throwing touches a handful
of points, two set-ups "cover" them) and NC programs come out. So a part is refused, before any stage
runs, when

* its largest bounding-box side is under ``input.min_part_tool_diameters`` tool diameters
  (:func:`check_part_size`, code ``part_too_small``), or
* sphere throwing finds normals for under :data:`MIN_NORMAL_SHARE` of its points
  (:func:`check_normal_share`, code ``too_few_normals``; Makki §2.1: a sphere much larger than the
  part touches only its top points),

unless ``input.accept_small_part`` is true. The messages give the extent in mm and the unit that
would make the part a plausible size (``input.units=m`` or ``in``), so the machinist can fix the
cause instead of the symptom. Both raise :class:`~planning.errors.InputError` (CLI exit 2, HTTP 422).
"""

from __future__ import annotations

import numpy as np

from planning.errors import InputError
from planning.inputs.cloud import UNIT_SCALE

#: Sphere throwing must give normals to at least this share of the points (unless accept_small_part).
MIN_NORMAL_SHARE = 0.005


def _fmt(v: float) -> str:
    return f"{v:.3g}" if abs(v) < 10 else f"{v:,.0f}" if abs(v) >= 1000 else f"{v:.1f}"


def extent_mm(points: np.ndarray) -> np.ndarray:
    """(3,) side lengths of the axis-aligned bounding box of ``points`` (N,3) mm."""
    return np.ptp(np.asarray(points, dtype=np.float64), axis=0)


def unit_hints(extent: np.ndarray, units: str, smallest_mm: float, largest_mm: float) -> list[str]:
    """The other input units under which a part of bounding box ``extent`` (mm, read as ``units``) would
    measure between ``smallest_mm`` and ``largest_mm`` on its largest side, each as a sentence part:
    ``"input.units=m (the part would measure 30 x 20 x 20 mm)"``."""
    here = UNIT_SCALE.get(units, 1.0)
    hints = []
    for unit, to_mm in sorted(UNIT_SCALE.items(), key=lambda kv: kv[1]):
        factor = to_mm / here
        if unit == units or factor <= 1.0:
            continue
        side = float(extent.max()) * factor
        if smallest_mm <= side <= largest_mm:
            dims = " x ".join(_fmt(float(e) * factor) for e in extent)
            hints.append(f"input.units={unit} (the part would measure {dims} mm)")
    return hints


def _describe(extent: np.ndarray) -> str:
    return " x ".join(_fmt(float(e)) for e in extent) + " mm"


def check_part_size(points: np.ndarray, *, units: str, tool_diameter_mm: float, min_tool_diameters: float,
                    max_extent_mm: float, accept_small_part: bool) -> None:
    """Refuse a part whose largest bounding-box side (mm) is under ``min_tool_diameters`` x
    ``tool_diameter_mm`` unless ``accept_small_part``; the message names the extent, the tool and the
    likely unit (module docstring). Raises :class:`InputError` ``part_too_small``."""
    if accept_small_part:
        return
    extent = extent_mm(points)
    smallest = float(min_tool_diameters) * float(tool_diameter_mm)
    if float(extent.max()) >= smallest:
        return
    hints = unit_hints(extent, units, smallest, max_extent_mm)
    unit_text = (" If the file is not in " + units + ", set " + " or ".join(hints) + "."
                 if hints else " Check the unit the scan was exported in (input.units).")
    raise InputError(
        f"The part measures {_describe(extent)} (read as {units}): its largest side is under "
        f"{_fmt(min_tool_diameters)} diameters of the {_fmt(tool_diameter_mm)} mm tool ({_fmt(smallest)} mm), so "
        f"it is most likely in another unit.{unit_text} To plan a part this small, set "
        f"input.accept_small_part=true.",
        code="part_too_small", extent_mm=[float(e) for e in extent], units=units,
        smallest_mm=smallest, hints=hints)


def check_normal_share(points: np.ndarray, n_sampled: int, *, units: str, sphere_diameter_mm: float,
                       tool_diameter_mm: float, max_extent_mm: float, accept_small_part: bool) -> None:
    """Refuse a cloud on which sphere throwing gave normals to fewer than :data:`MIN_NORMAL_SHARE` of
    its points unless ``accept_small_part`` (module docstring). Raises :class:`InputError`
    ``too_few_normals`` with the share, the sphere, the extent and the likely unit."""
    n = int(np.asarray(points).shape[0])
    if accept_small_part or n == 0 or n_sampled >= MIN_NORMAL_SHARE * n:
        return
    extent = extent_mm(points)
    hints = unit_hints(extent, units, 2.0 * float(tool_diameter_mm), max_extent_mm)
    unit_text = (" If the file is not in " + units + ", set " + " or ".join(hints) + "." if hints else "")
    raise InputError(
        f"Sphere throwing (sphere {_fmt(sphere_diameter_mm)} mm) found normals for only {n_sampled:,} of "
        f"{n:,} points ({n_sampled / n:.2%}; at least {MIN_NORMAL_SHARE:.1%} are needed). The part measures "
        f"{_describe(extent)}: the sphere is too large for it, or the cloud too sparse.{unit_text} Otherwise "
        f"lower normals.sphere_diameter_mm or set normals.grid_spacing_mm; input.accept_small_part=true plans "
        f"anyway.",
        code="too_few_normals", n_sampled=int(n_sampled), n_points=n, extent_mm=[float(e) for e in extent],
        hints=hints)
