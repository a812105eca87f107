"""Issue 31 item 5: the simulation measures the roughing end mill's engagement on every level move
(planning/simulate/engagement.py), held to closed forms and to the dexel simulation's own cuts."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planning.geometry.basis import complete_basis
from planning.simulate.dexel import TriDexel, cut
from planning.simulate.engagement import Engagement, _walk, engagement_angle_deg, measure
from planning.simulate.motion import FEED, RAPID, ProgramMotion, ToolShape
from planning.simulate.verify import engagement_figures

R = 5.0


def _tool(rc: float = 0.0, flute: float = 20.0) -> ToolShape:
    return ToolShape(number=2, kind="bull" if rc > 0 else "flat", radius_mm=R, corner_radius_mm=rc,
                     flute_length_mm=flute)


def _frame(tilt_deg: float, turn_deg: float):
    a = np.array([math.sin(math.radians(tilt_deg)), 0.0, math.cos(math.radians(tilt_deg))])
    e1, e2 = complete_basis(a)
    th = math.radians(turn_deg)
    u = math.cos(th) * e1 + math.sin(th) * e2
    v = -math.sin(th) * e1 + math.cos(th) * e2
    return a, u, v


def _two_passes(a, u, v, step_mm: float, chords: int = 1):
    """A pass 200 mm long through the middle of a 120 mm cube, 10 mm below its top along ``a``, a step of
    ``step_mm`` across (outside the cube) and the pass back. Returns start, end (P,3) and each move's pass."""
    c = np.array([0.13, 0.37, 0.0]) + 50.0 * a
    p0, p1 = c - 100.0 * u, c + 100.0 * u
    legs = [(p0, p1, chords), (p1, p1 + step_mm * v, 1), (p1 + step_mm * v, p0 + step_mm * v, chords)]
    S, E, own = [], [], []
    for k, (A, B, n) in enumerate(legs):
        t = np.linspace(0.0, 1.0, n + 1)
        S.append(A + np.outer(t[:-1], B - A))
        E.append(A + np.outer(t[1:], B - A))
        own += [k] * n
    return np.concatenate(S), np.concatenate(E), np.array(own)


def _measure(stock, S, E, a, shape, kind=None):
    P = S.shape[0]
    kind = np.full(P, FEED) if kind is None else kind
    return measure(stock, S, E, np.tile(a, (P, 1)), kind, np.full(P, shape.number), shape)


@pytest.mark.parametrize("rc", [0.0, 2.0])
@pytest.mark.parametrize("tilt,turn", [(0.0, 0.0), (0.0, 31.0), (25.0, 77.0)])
def test_a_straight_cut_reads_its_closed_form_and_a_slot_180(rc, tilt, turn):
    """The first pass cuts a slot (180 degrees); the pass back, ``s`` over, cuts a strip ``s`` wide:
    ``acos(1 - s / R)`` within 4 degrees (the columns are R / 14), in any direction across the grid, flat or bull-nose, on a
    set-up axis tilted against the stock's."""
    a, u, v = _frame(tilt, turn)
    for s in (1.3, 2.5, 6.0, 8.0):
        stock = TriDexel.box([-60, -60, -60], [60, 60, 60], 0.5)
        S, E, own = _two_passes(a, u, v, s)
        eg = _measure(stock, S, E, a, _tool(rc))
        want = float(engagement_angle_deg(s, R))
        assert eg.deg[own == 0].max() == pytest.approx(180.0, abs=0.5), (s, eg.deg)
        got = float(eg.deg[own == 2].max())
        assert abs(got - want) <= 4.0, (s, got, want)
        assert eg.level.all() and eg.note == ""


def test_the_same_cut_as_one_move_or_a_thousand_chords_reads_the_same():
    """A move that continues a level move skips the columns its start already cleared: the figure does
    not depend on how the path is cut into moves."""
    a, u, v = _frame(0.0, 31.0)
    for rc in (0.0, 2.0):
        got = []
        for chords in (1, 1000):
            stock = TriDexel.box([-60, -60, -60], [60, 60, 60], 0.5)
            S, E, own = _two_passes(a, u, v, 6.0, chords)
            eg = _measure(stock, S, E, a, _tool(rc))
            got.append([float(eg.deg[own == k].max()) for k in (0, 2)])
        assert np.allclose(got[0], got[1], atol=2.0), (rc, got)      # the noise of the largest over 200 mm


def test_the_area_it_counts_is_the_volume_the_dexel_simulation_removes():
    """Summed over the steps and slices, the area the measure counts times the slice height is the volume
    the tri-dexel simulation (its own closed-form cuts) removes with the same moves: a zigzag of two
    2 mm levels with 60 % step-over through a box, slices of 1 mm (flute 16 mm) so that they tile the cut."""
    shape = _tool(0.0, flute=16.0)
    S, E = [], []
    for lv, z in enumerate((58.0, 56.0)):
        for k in range(10):
            y = -27.3 + 6.0 * k + 0.4 * lv
            x0, x1 = (-45.0, 45.0) if k % 2 == 0 else (45.0, -45.0)
            S += [[x0, y, z], [x1, y, z]]
            E += [[x1, y, z], [x1, y + 6.0, z]]
    S, E = np.array(S), np.array(E)
    a = np.array([0.0, 0.0, 1.0])
    e1, e2 = complete_basis(a)
    stock = TriDexel.box([-30, -30, 0], [30, 30, 60], 0.5)
    Rm = np.stack([e1, e2, a])
    fS, fE = S @ Rm.T, E @ Rm.T
    cell, nx, ny = 0.25, 480, 480
    h = np.full((ny, nx), np.inf)
    feed = np.ones(S.shape[0], bool)
    _, _, lev, area = _walk(h, fS, fE, feed, e1, e2, a, 2, stock.lo, stock.res, stock.n, stock.base, stock.off,
                            stock.cnt, stock.pool, -60.0, -60.0, cell, nx, ny, R, 0.0, 1.0, 16, cell, 1e-3)
    counted = float(area[lev].sum()) * 1.0
    removed = float(cut(stock.copy(), S, E, np.tile(a, (S.shape[0], 1)), shape).sum())
    assert removed == pytest.approx(60.0 * 60.0 * 4.0, rel=0.01)
    assert counted == pytest.approx(removed, rel=0.01)


def test_what_it_does_not_measure_it_says():
    """Rapids, other tools and moves that are not level (a ramp, a plunge) read NaN; a tool that turns its
    axis while it feeds is not measured at all, and the note says why."""
    stock = TriDexel.box([-30, -30, 0], [30, 30, 60], 0.5)
    shape = _tool()
    S = np.array([[-40, 0, 70], [-40, 0, 70], [-40, 0, 58], [40, 0, 58], [40, 0, 58], [30, 0, 50]], float)
    E = np.array([[-40, 0, 58], [-40, 0, 58], [40, 0, 58], [40, 0, 58], [30, 0, 50], [-30, 0, 50]], float)
    kind = np.array([RAPID, FEED, FEED, FEED, FEED, FEED])
    tool = np.array([2, 2, 2, 1, 2, 2])
    ax = np.tile([0.0, 0.0, 1.0], (6, 1))
    eg = measure(stock, S, E, ax, kind, tool, shape)
    assert list(eg.level) == [False, False, True, False, False, True]
    assert np.isnan(eg.deg[[0, 1, 3, 4]]).all()
    assert eg.deg[2] == pytest.approx(180.0, abs=0.5)          # a slot along the top level
    ax5 = ax.copy()
    ax5[5] = [0.0, math.sin(0.2), math.cos(0.2)]
    eg5 = measure(stock, S, E, ax5, kind, tool, shape)
    assert not eg5.level.any() and np.isnan(eg5.deg).all() and "5-axis" in eg5.note


def test_the_figures_weigh_the_percentile_by_length_and_count_the_moves_over_the_bound():
    P = 4
    S = np.zeros((P, 3))
    E = np.array([[0.5, 0, 0], [9.0, 0, 0], [10.0, 0, 0], [1.0, 0, 0]])
    motion = ProgramMotion(program="p", area=0, line=np.arange(P), kind=np.full(P, FEED), tool=np.full(P, 2),
                           start_mm=S, end_mm=E, axis=np.tile([0, 0, 1.0], (P, 1)), machine_mm=E,
                           rotary_deg=np.zeros((P, 2)))
    eg = Engagement(deg=np.array([170.0, 80.0, 120.0, np.nan]), level=np.array([True, True, True, False]))
    f = engagement_figures(motion, eg, 90.0)
    # by length: 80 deg over 9 mm, 120 over 10, 170 over 0.5 (of 19.5): the 95th percentile is 120
    assert f == {"engagement_max_deg": 170.0, "engagement_p95_deg": 120.0, "over_engagement_moves": 2,
                 "over_engagement_mm": 10.5}
    assert engagement_figures(motion, None, 90.0) == {}
