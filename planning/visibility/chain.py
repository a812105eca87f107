"""The visibility filters after the tool cone: travel, fixtures and the cloud (Makki 2010 §2.2.2-2.2.4).

:func:`global_visibility` takes the cone visibility of the sampled points on the machine-feasible
axes and removes, in this order (cheapest first; each filter only sees the pairs the previous ones
kept):

1. ``travel`` - the machine X/Y/Z position needed lies outside the profile's linear limits
   (:func:`planning.visibility.travel.travel_feasible`, Makki Fig. 4c);
2. ``fixture_collision`` - the ball, cutter, shank or holder touches a fixture or the table
   (:func:`planning.geometry.fixtures.fixture_collision_free`, python-fcl as the exact narrow phase);
3. ``cloud_collision`` - another point of the cloud (or a forbidden point) lies inside the cutter,
   shank or holder (:func:`planning.geometry.collision.cloud_collision_free`, exact).

It reports, per axis, how many sampled points each filter removed.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from planning.geometry.collision import cloud_collision_free
from planning.errors import ParameterError
from planning.geometry.fixtures import BoxFixture, CylinderFixture, TableFixture, load_mesh
from planning.geometry.fixtures import fixture_collision_free
from planning.geometry.tool import ToolAssembly
from planning.orientations.positions import default_placement
from planning.visibility.travel import travel_feasible

_UNITS_MM = {"mm": 1.0, "m": 1000.0, "in": 25.4}


@dataclass
class GlobalVisibility:
    """``visible`` (n, m) bool after every filter; ``removed[name]`` (m,) int: sampled points that
    filter removed per axis; ``placement_mm`` (3,): the part placement used; ``fixtures``: the
    fixture solids and table, ``forbidden_mm`` (K,3) the forbidden points (built once here, also the
    tool paths' obstacles); ``seconds[name]``. ``along`` (n, m) bool or None: with ``along_swing_deg``
    (simultaneous 5-axis), the machine can present axis ``j`` itself at sample ``i`` within the X/Y/Z
    travel, for the samples whose normal is within that swing of ``j`` (the others False): where a
    set-up of pass direction ``j`` can rough and drop its ball."""

    visible: np.ndarray
    removed: dict[str, np.ndarray]
    placement_mm: np.ndarray
    table_z_mm: Optional[float]
    n_obstacles: int
    fixtures: list = field(default_factory=list)
    forbidden_mm: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    seconds: dict[str, float] = field(default_factory=dict)
    along: np.ndarray | None = None


def build_fixtures(fixtures_params, placement_mm: np.ndarray, *, base_dir: Optional[Path] = None):
    """Fixture solids (part frame) and forbidden points from the ``fixtures`` parameters.

    Returns ``(solids, forbidden_points (K,3), table_z_mm or None)``. The table top is at table
    z = 0, i.e. part z = ``-placement_mm[2]``."""
    solids = []
    extra = []
    for i, it in enumerate(fixtures_params.items):
        if it.type == "box":
            solids.append(BoxFixture(tuple(it.min_mm), tuple(it.max_mm), name=it.name))
        elif it.type == "cylinder":
            solids.append(CylinderFixture(tuple(it.base_mm), tuple(it.axis), it.radius_mm, it.height_mm,
                                          name=it.name))
        elif it.type == "mesh":
            path = Path(it.path)
            if base_dir is not None and not path.is_absolute():
                path = base_dir / path
            solids.append(load_mesh(path, units=_UNITS_MM[it.units], name=it.name))
        elif it.type == "points":
            extra.append(np.asarray(it.points_mm, dtype=np.float64).reshape(-1, 3))
        else:  # pragma: no cover - the schema admits no other kind
            raise ParameterError(f"fixtures.items[{i}]: unknown type {it.type!r}")
    table_z = None
    if fixtures_params.table:
        table_z = float(-placement_mm[2])
        solids.append(TableFixture(table_z, name="table"))
    forbidden = np.concatenate(extra) if extra else np.zeros((0, 3))
    return solids, forbidden, table_z


def global_visibility(points: np.ndarray, sample_index: np.ndarray, normals: np.ndarray, axes: np.ndarray,
                      angles_deg: np.ndarray, cone_visible: np.ndarray, *, tool: ToolAssembly, profile,
                      fixtures_params, check_global: bool = True, check_travel: bool = True,
                      obstacles: str = "all", base_dir: Optional[Path] = None,
                      progress: Optional[Callable[[float, str], None]] = None,
                      check_cloud: bool = True, along_swing_deg: float | None = None) -> GlobalVisibility:
    """Apply travel, fixture and cloud-collision filters to ``cone_visible`` (n, m) bool.

    ``points`` (N,3) mm: the whole cloud; ``sample_index`` (n,), ``normals`` (n,3): the sampled
    points; ``axes`` (m,3) unit tool axes (part frame) with their rotary positions ``angles_deg``
    (m,2) ``(tilt, rotary)``; ``tool``: the cutter and holder; ``profile``: the machine profile;
    ``fixtures_params``: :class:`schemas.params.FixturesParams`. ``obstacles``: ``'all'`` (every
    input point is an obstacle: exact) or ``'sampled'`` (only the sampled points: faster, may miss a
    tool passing between samples). Follows Makki
    2010 §2.2.2 (Fig. 4c, travel) and §2.2.4 (global visibility). ``check_cloud=False`` stops after
    the fixtures and the table (a superset of the visible pairs at a fraction of the cost, which
    :mod:`planning.placement.search` bounds the coverage with). ``along_swing_deg`` (simultaneous
    5-axis, ``paths.finishing.max_swing_deg``): also the travel of every pair whose normal is within
    that angle of the axis, without the cone (``GlobalVisibility.along``; None: not computed, nor when
    the travel is not checked).
    """
    m = axes.shape[0]
    vis = np.array(cone_visible, dtype=bool, copy=True)
    removed = {k: np.zeros(m, dtype=np.int64) for k in ("travel", "fixture_collision", "cloud_collision")}
    seconds: dict[str, float] = {}
    if fixtures_params.placement_mm is not None:
        placement = np.asarray(fixtures_params.placement_mm, dtype=np.float64)
    else:
        placement = default_placement(points, fixture_height_mm=fixtures_params.fixture_height_mm)
    R = tool.radius_mm
    centres = points[sample_index] + R * normals

    def report(frac, msg):
        if progress is not None:
            progress(frac, msg)

    if check_travel:
        t0 = time.perf_counter()
        ok = travel_feasible(centres, axes, angles_deg, profile, placement_mm=placement, tool_radius_mm=R,
                             gauge_length_mm=tool.gauge_length_mm, candidates=vis)
        removed["travel"] = (vis & ~ok).sum(axis=0)
        vis &= ok
        seconds["travel"] = time.perf_counter() - t0
        report(0.05, f"travel: {int(removed['travel'].sum())} pairs out of X/Y/Z travel")
    along = None
    if check_travel and along_swing_deg is not None:
        t0 = time.perf_counter()
        facing = (normals @ axes.T) >= math.cos(math.radians(float(along_swing_deg))) - 1e-12
        along = travel_feasible(centres, axes, angles_deg, profile, placement_mm=placement, tool_radius_mm=R,
                                gauge_length_mm=tool.gauge_length_mm, candidates=facing)
        seconds["travel_along"] = time.perf_counter() - t0

    solids, forbidden, table_z = build_fixtures(fixtures_params, placement, base_dir=base_dir)
    n_obst = 0
    if check_global:
        if solids:
            t0 = time.perf_counter()
            ok = fixture_collision_free(centres, axes, tool, solids, candidates=vis,
                                        progress=lambda d, t: report(0.05 + 0.15 * d / t, "fixtures"))
            removed["fixture_collision"] = (vis & ~ok).sum(axis=0)
            vis &= ok
            seconds["fixture_collision"] = time.perf_counter() - t0
    if check_global and check_cloud:
        t0 = time.perf_counter()
        if obstacles == "all":
            obst_points, idx = points, sample_index
        else:
            obst_points, idx = points[sample_index], np.arange(sample_index.size)
        n_obst = int(obst_points.shape[0] + forbidden.shape[0])
        ok = cloud_collision_free(obst_points, idx, normals, axes, tool, candidates=vis,
                                  obstacles=forbidden if forbidden.size else None,
                                  progress=lambda d, t: report(0.2 + 0.8 * d / t, f"cloud collisions, axis {d}/{t}"))
        removed["cloud_collision"] = (vis & ~ok).sum(axis=0)
        vis &= ok
        seconds["cloud_collision"] = time.perf_counter() - t0
    return GlobalVisibility(visible=vis, removed=removed, placement_mm=placement, along=along,
                            table_z_mm=table_z if check_global else None, n_obstacles=n_obst, fixtures=solids,
                            forbidden_mm=forbidden, seconds=seconds)
