"""The solids of a plan's simulation (part frame, mm), built with :mod:`planning.simulate.stock`:

* the **stock** (``stock.*``): the box ``lo``-``hi`` the verification passes (the part's bounding box
  grown by ``stock.margin_mm``, or ``stock.min_mm``/``max_mm``), the smallest cylinder about
  ``stock.axis`` through that box's centre around it, or the real blank's closed mesh;
* the **obstacles**, never to be cut or touched: the fixtures (boxes, cylinders, meshes), the riser
  (``simulate.riser_diameter_mm``, under the centre of the stock's underside, from the table top up
  to it) and the table. Their domain is the stock box grown by the tools' largest radius on the
  sides, up to the highest fixture and down to the table, so a holder passing the stock's side
  meets what stands there.

The deviation's measuring bound is :func:`planning.simulate.dexel.deviation_bound_mm` for surfaces
curved no tighter than the finishing ball.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planning.geometry.fixtures import TableFixture
from planning.simulate.dexel import TriDexel, deviation_bound_mm
from planning.simulate.stock import (
    obstacle_domain,
    obstacle_model,
    riser,
    stock_box,
    stock_cylinder,
)

#: How far the obstacle domain reaches under the table top, mm (the table is a slab this thick).
TABLE_SLAB_MM = 5.0


@dataclass
class Models:
    """``stock`` and ``obstacles`` (None when there are none), the deviation's ``measuring_bound_mm``
    and ``notes`` on what was modelled."""

    stock: TriDexel
    obstacles: TriDexel | None
    measuring_bound_mm: float
    notes: list[str] = field(default_factory=list)


def _fixture_top(fixtures) -> float:
    """The highest z of the finite fixtures (part frame, mm), -inf when none."""
    from planning.toolpath.area_paths import _fixture_points

    tops = [float(_fixture_points(f)[:, 2].max()) for f in fixtures if not isinstance(f, TableFixture)]
    return max(tops, default=-np.inf)


def load_blank(stock, base_dir=None):
    """The blank's mesh of ``stock.type`` 'mesh' (:class:`MeshFixture`, part frame, mm), read once
    at the start of a plan so that a bad file stops it before any work; None for other types.
    Raises :class:`~planning.errors.InputError` for a missing, unreadable or open mesh."""
    if stock.type != "mesh":
        return None
    from pathlib import Path

    from planning.geometry.fixtures import load_mesh

    path = Path(stock.path)
    if base_dir is not None and not path.is_absolute():
        path = Path(base_dir) / path
    return load_mesh(path, units={"mm": 1.0, "m": 1000.0, "in": 25.4}[stock.units], name="blank", solid=True)


def build_models(lo, hi, config, fixtures, tools: dict, *, resolution_mm: float, blank=None) -> Models:
    """The stock, the obstacles and the measuring bound of a plan (module docstring). ``tools``:
    the :class:`~planning.simulate.motion.ToolShape` of every T number (their largest radius sets
    how far the obstacle domain reaches beyond the stock); ``blank``: the mesh of a 'mesh' stock."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    st = config.stock
    if blank is not None:
        stock = TriDexel.from_mesh(blank.vertices, blank.triangles, resolution_mm)
    elif st.type == "box":
        stock = stock_box(lo, hi, resolution_mm)
    else:
        stock = stock_cylinder(lo, hi, st.axis, 0.0, resolution_mm)
    reach = max([r for t in tools.values() for (_, _, r) in t.pieces] + [t.radius_mm for t in tools.values()])
    table = [f for f in fixtures if isinstance(f, TableFixture)]
    table_z = min((f.z_mm for f in table), default=None)
    below = reach if table_z is None else max(0.0, float(lo[2] - table_z)) + TABLE_SLAB_MM
    dlo, dhi = obstacle_domain(lo, hi, reach + resolution_mm, below_mm=below)
    dhi[2] = max(dhi[2], _fixture_top(fixtures) + resolution_mm)
    solids = list(fixtures)
    notes = []
    if table_z is not None and config.simulate.riser_diameter_mm:
        r = riser(lo, hi, config.simulate.riser_diameter_mm, table_z)
        if r is not None:
            solids.append(r)
            notes.append(f"a riser of {config.simulate.riser_diameter_mm:g} mm diameter stands under the stock's "
                         f"centre from the table (z {table_z:.1f}) up to its underside (z {lo[2]:.1f}), part frame")
    obstacles = obstacle_model(solids, dlo, dhi, resolution_mm) if solids else None
    R = config.tool.diameter_mm / 2.0
    return Models(stock=stock, obstacles=obstacles, measuring_bound_mm=deviation_bound_mm(resolution_mm, R),
                  notes=notes)
