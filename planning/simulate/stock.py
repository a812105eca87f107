"""The stock and the solids that may never be cut, as tri-dexel models (issue 15; part frame, mm).

* :func:`stock_box`, :func:`stock_cylinder`: the blank (``stock.type``: the part's bounding box grown
  by a margin, or the smallest cylinder about a coordinate axis through the box's centre around it,
  grown by the margin);
* :func:`fixture_model`: one fixture of :mod:`planning.geometry.fixtures` (box, possibly rotated;
  cylinder; triangle mesh; the table's half-space) on a given domain grid;
  :func:`obstacle_model`: the union of several (fixtures, riser, table) on one grid;
  :func:`riser`: the round riser from the table top up to the stock's underside;
  :func:`obstacle_domain`: a domain around the stock wide enough for a tool and holder to reach.

Everything is cut to the domain: material outside it is not modelled, so a collision outside the
domain is not seen (make the obstacle domain cover where the tool and holder go).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from planning.geometry.fixtures import (
    BoxFixture,
    CylinderFixture,
    MeshFixture,
    TableFixture,
)
from planning.simulate import dexel_kernels as K
from planning.simulate.dexel import RESOLUTION_MM, TriDexel, _grid

_AXES = {"x": 0, "y": 1, "z": 2}


def stock_box(lo, hi, resolution_mm: float = RESOLUTION_MM, domain_lo=None, domain_hi=None) -> TriDexel:
    """The box stock ``lo..hi`` (default domain: the box grown by one ray spacing)."""
    return TriDexel.box(lo, hi, resolution_mm, domain_lo, domain_hi)


def cylinder_around(part_lo, part_hi, axis: str = "z", margin_mm: float = 0.0):
    """The smallest cylinder about ``axis`` ('x', 'y' or 'z') through the centre of the box
    ``part_lo..part_hi`` containing it, grown by ``margin_mm`` radially and at both ends:
    (base (3,), unit axis (3,), radius, height)."""
    lo = np.asarray(part_lo, float)
    hi = np.asarray(part_hi, float)
    k = _AXES[axis]
    c = (lo + hi) / 2
    other = [i for i in range(3) if i != k]
    radius = 0.5 * float(np.hypot(*(hi - lo)[other])) + margin_mm
    base = c.copy()
    base[k] = lo[k] - margin_mm
    ax = np.zeros(3)
    ax[k] = 1.0
    return base, ax, radius, float(hi[k] - lo[k] + 2 * margin_mm)


def stock_cylinder(part_lo, part_hi, axis: str = "z", margin_mm: float = 0.0,
                   resolution_mm: float = RESOLUTION_MM, domain_lo=None, domain_hi=None) -> TriDexel:
    """The cylinder stock of :func:`cylinder_around` (exact on every ray)."""
    base, ax, radius, height = cylinder_around(part_lo, part_hi, axis, margin_mm)
    return TriDexel.cylinder(base, ax, radius, height, resolution_mm, domain_lo, domain_hi)


def obstacle_domain(stock_lo, stock_hi, reach_mm: float, below_mm: float | None = None):
    """A domain around the stock box grown by ``reach_mm`` on the four sides and the top and by
    ``below_mm`` (default ``reach_mm``) underneath: (lo, hi)."""
    lo = np.asarray(stock_lo, float) - reach_mm
    hi = np.asarray(stock_hi, float) + reach_mm
    lo[2] = float(stock_lo[2]) - (reach_mm if below_mm is None else below_mm)
    return lo, hi


def riser(stock_lo, stock_hi, diameter_mm: float, table_z_mm: float) -> CylinderFixture | None:
    """The round riser under the centre of the stock's underside, from the table top up to it
    (None when the stock does not stand above the table)."""
    lo = np.asarray(stock_lo, float)
    hi = np.asarray(stock_hi, float)
    h = float(lo[2] - table_z_mm)
    if not h > 0:
        return None
    c = (lo + hi) / 2
    return CylinderFixture(base_mm=(float(c[0]), float(c[1]), float(table_z_mm)), axis=(0.0, 0.0, 1.0),
                           radius_mm=diameter_mm / 2, height_mm=h, name="riser")


def box_mesh(lo, hi, rotation=None):
    """A closed, outward-wound triangle mesh of the box ``lo..hi`` turned by ``rotation`` (3x3)
    about its centre: (vertices (8,3), faces (12,3))."""
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    V = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    # vertex index = 4 ix + 2 iy + iz
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5],      # x = lo (-x), x = hi (+x)
                  [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],      # y = lo, y = hi
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])     # z = lo, z = hi
    if rotation is not None:
        c = (lo + hi) / 2
        V = (V - c) @ np.asarray(rotation, float).T + c
    return V, F


def _shell(V, F, lo, res, n, thickness):
    """The surface of an open mesh thickened to ``thickness`` along every ray (CSR per family)."""
    V = np.ascontiguousarray(V, float)
    F = np.ascontiguousarray(F, np.int64)
    csrs = []
    for f in range(3):
        ptr, coords = K.mesh_crossings(V, F, lo, res, n, f)
        csrs.append(K.shell_crossings(ptr, coords, lo[f], lo[f] + n[f] * res, thickness / 2))
    return csrs


def fixture_model(fixture, domain_lo, domain_hi, resolution_mm: float = RESOLUTION_MM,
                  shell_mm: float | None = None) -> TriDexel:
    """One fixture on the grid of the domain: a box (rotated: through its mesh), a cylinder, a
    mesh (``solid``: its interior; else its surface thickened to ``shell_mm``, default the ray
    spacing, so a tool must touch the surface to be seen), the table (everything below its top)."""
    res = float(resolution_mm)
    lo, n = _grid(domain_lo, domain_hi, res)
    hi = lo + n * res
    if isinstance(fixture, BoxFixture):
        if fixture.rotation is None:
            return TriDexel.box(fixture.min_mm, fixture.max_mm, res, lo, hi)
        V, F = box_mesh(fixture.min_mm, fixture.max_mm, fixture.rotation_matrix)
        return TriDexel.from_mesh(V, F, res, lo, hi)
    if isinstance(fixture, CylinderFixture):
        return TriDexel.cylinder(fixture.base_mm, fixture.axis, fixture.radius_mm, fixture.height_mm, res, lo, hi)
    if isinstance(fixture, TableFixture):
        top = np.array([hi[0] + res, hi[1] + res, fixture.z_mm])
        if fixture.z_mm <= lo[2]:
            return TriDexel.empty(lo, hi, res)
        return TriDexel.box(lo - res, top, res, lo, hi)
    if isinstance(fixture, MeshFixture):
        if fixture.solid:
            return TriDexel.from_mesh(fixture.vertices, fixture.triangles, res, lo, hi)
        return TriDexel(lo, res, n, _shell(fixture.vertices, fixture.triangles, lo, res, n,
                                           res if shell_mm is None else float(shell_mm)))
    raise TypeError(f"not a fixture: {fixture!r}")


def obstacle_model(fixtures: Iterable, domain_lo, domain_hi, resolution_mm: float = RESOLUTION_MM,
                   shell_mm: float | None = None) -> TriDexel:
    """The union of the fixtures (and riser, table: any of :func:`fixture_model`'s kinds; None
    entries skipped) on the domain's grid."""
    lo, n = _grid(domain_lo, domain_hi, float(resolution_mm))
    hi = lo + n * float(resolution_mm)
    model = TriDexel.empty(lo, hi, resolution_mm)
    for fx in fixtures:
        if fx is None:
            continue
        model = model.union(fixture_model(fx, lo, hi, resolution_mm, shell_mm))
    return model
