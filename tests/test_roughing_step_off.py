"""A roughing retract beside a wall steps off it (planning.toolpath.roughing.links._step_off / _retract).

Issue 30 ("no feed below the stock"): a level cut along the stock block's edge with a tilted axis
leaves the tool at the region's rim, with the wall it just cut on one side and air on the other. The
region (where the level may cut: near material, off the part's allowance) holds no cell beyond the
rim, so a step off the wall that kept to the region found no direction and the retract fed up the
whole wall. A step out of the region is taken only where the tool grown by the rapid clearance is
clear of the material all the way up from the step's end (the stock holds the part, so that is the
independent proof the move meets nothing) and the machine reaches the cell.

The material here is a wall: everything at x < WALL_X up to TOP_Z; the column test is exact for a
flat cutter of radius RT grown by the clearance (brute force on the wall's plane)."""

from __future__ import annotations

import numpy as np

from planning.toolpath.moves import USE_RAPID, USE_RETRACT
from planning.toolpath.roughing.links import (
    _Level,
    _retract,
    _Scratch,
    _step_off,
    _Writer,
)

RT = 3.0           # tool radius, mm
CLEAR = 0.5        # rapid clearance, mm
WALL_X = 0.0       # the wall's face (material at x < WALL_X)
TOP_Z = 20.0       # the wall's top
H = 0.5            # raster cell, mm
X0, Y0, NX, NY = -10.0, -10.0, 40, 40


def _column_clear_many(points, top):
    """Lowest height from which the tool (radius RT + CLEAR, straight up to ``top``) misses the wall."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    touches = p[:, 0] - (RT + CLEAR) < WALL_X
    return np.where(touches, np.minimum(np.maximum(p[:, 2], TOP_Z), top), p[:, 2])


def _level(region, reach=None, z=0.0):
    return _Level(region, X0, Y0, H, NX, NY, z, np.full((4, 4), -np.inf), 10.0, RT, _Scratch(NX * NY),
                  reach=reach)


def _writer():
    w = _Writer()
    w.gap = 0.65
    w.column_clear_many = _column_clear_many
    w.column_clear = lambda x, y, z, top: float(_column_clear_many([[x, y, z]], top)[0])
    return w


def _rim_region():
    """The level's region: a band of cells whose right rim holds the tool centre at x = RT (the tool
    touching the wall's face), nothing beyond it."""
    cx = X0 + (np.arange(NX) + 0.5) * H
    region = np.zeros((NX, NY), dtype=bool)
    region[(cx >= RT - 2 * H) & (cx < RT), :] = True
    return region


TIP = np.array([RT, 0.0, 0.0])      # tool centre on the region's rim, touching the wall


def test_the_step_off_leaves_the_region_into_clear_air():
    w = _writer()
    off = _step_off(w, _level(_rim_region()), TIP, 30.0)
    assert off is not None
    p, zc = off
    assert p[0] > TIP[0] + 0.5 * w.gap                        # away from the wall
    assert abs(np.hypot(*(p - TIP[:2])) - w.gap) < 1e-9
    assert zc == TIP[2] + w.gap                                  # the rapid rises from the step's end
    # the independent check: the grown tool at the step's end misses the wall by the clearance
    assert p[0] - (RT + CLEAR) >= WALL_X


def _gains(off) -> bool:
    """Whether a step off was found from which the rapid rises lower than the wall's top."""
    return off is not None and off[1] < TOP_Z


def test_no_step_out_of_the_region_where_the_machine_does_not_reach():
    reach = np.zeros((NX, NY), dtype=bool)            # travel allows only the region itself
    reach[_rim_region()] = True
    assert not _gains(_step_off(_writer(), _level(_rim_region(), reach=reach), TIP, 30.0))
    assert _gains(_step_off(_writer(), _level(_rim_region(), reach=np.ones((NX, NY), bool)), TIP, 30.0))


def test_no_step_out_of_the_region_where_the_air_is_not_clear():
    # the same rim, but the wall is on both sides of a 1 mm gap: no direction out of the region clears
    w = _writer()
    w.column_clear_many = lambda pts, top: np.full(np.asarray(pts).reshape(-1, 3).shape[0], TOP_Z)
    assert not _gains(_step_off(w, _level(_rim_region()), TIP, 30.0))


def test_the_retract_steps_off_instead_of_feeding_up_the_wall():
    w = _writer()
    end = _retract(w, TIP, 30.0, _level(_rim_region()))
    xyz = np.concatenate(w.pts)
    use = np.asarray(w.use())
    feed = use == USE_RETRACT
    fed = np.concatenate([[TIP], xyz])
    seg = np.linalg.norm(np.diff(fed, axis=0), axis=1)
    assert seg[feed].sum() < 1.0                               # 0.65 mm up and out, not 20 mm up the wall
    assert np.all(use[xyz[:, 2] > TIP[2] + w.gap + 1e-9] == USE_RAPID)
    assert end[0] > TIP[0]
    # without the step off (no level given) the same retract feeds up to the wall's top
    w2 = _writer()
    _retract(w2, TIP, 30.0, None)
    xyz2 = np.concatenate(w2.pts)
    assert np.asarray(w2.use())[0] == USE_RETRACT and xyz2[0, 2] == TOP_Z


def test_a_helix_start_beside_the_wall_is_come_down_to_off_the_wall_and_fed_in():
    """The approach to a helix or ramp starting at p beside the wall: the rapid down p's own column
    would stop at the wall's top (the grown tool meets it), and the rest, 20 mm, would be fed straight
    down. Instead the rapid comes down 0.65 mm off the wall, clear of it, and feeds in at 45 degrees
    (``entries._approach`` through ``links._down_off_wall``, the lift's own descent off a wall)."""
    from planning.toolpath.moves import USE_PLUNGE
    from planning.toolpath.roughing.entries import _approach
    from planning.toolpath.roughing.links import _down_off_wall

    w = _writer()
    w.rapid_clear = lambda a, b, z, top: z
    zs = TIP[2]
    cur = np.array([RT + 5.0, 0.0, 25.0])                     # in the air beyond the wall, above p
    _approach(w, _level(_rim_region()), cur, TIP[:2], zs, zs, 30.0)
    xyz = np.concatenate(w.pts)
    use = np.asarray(w.use())
    assert np.allclose(xyz[-1], TIP) and use[-1] == USE_PLUNGE      # ends at the helix start, fed
    assert np.all(use[1:-1] == USE_RAPID)                            # after the retract, rapids only
    assert abs(xyz[-2, 2] - (zs + w.gap)) < 1e-9                   # down to the gap above it, off the wall
    assert float(_column_clear_many(xyz[-2:-1], 30.0)[0]) == xyz[-2, 2]   # where the grown tool is clear
    assert np.linalg.norm(xyz[-1] - xyz[-2]) < 1.0
    # where no direction clears (the wall all round) nothing is written and the caller feeds down
    w2 = _writer()
    w2.column_clear_many = lambda pts, top: np.full(np.asarray(pts).reshape(-1, 3).shape[0], TOP_Z)
    w2.column_clear = lambda x, y, z, top: TOP_Z
    w2.add([TIP[0], TIP[1], 30.0], USE_RAPID)
    assert not _down_off_wall(w2, _level(_rim_region()), TIP[:2], zs, TOP_Z, 30.0, 30.0)
    assert len(w2.pts) == 1
    # and the approach itself then feeds the 20 mm straight down p's column, as before
    w3 = _writer()
    w3.column_clear_many = w2.column_clear_many
    w3.column_clear = w2.column_clear
    w3.rapid_clear = lambda a, b, z, top: z
    _approach(w3, _level(_rim_region()), cur, TIP[:2], zs, zs, 30.0)
    xyz3 = np.concatenate(w3.pts)
    assert np.allclose(xyz3[-1], TIP) and np.allclose(xyz3[-2], [TIP[0], TIP[1], TOP_Z])
    assert np.asarray(w3.use())[-1] == USE_PLUNGE
