"""Entries of the Z-level roughing into the material (planning.toolpath.roughing.entries).

The helices and ramps are read back from the move list (runs of plunge-feed moves); their cells
are checked against the forbidden map rebuilt from the module's own raster (the allowed cells are
its definition of gouge-free), the clearance against the module's verification; whether a straight
downward feed move goes into material is decided by an independent height-map simulation of the
stock (flat end mill: every feed move lowers the map under its disc to its lower end).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError
from roughing_clouds import _dexel_points, _dome, _grid, _pockets, _post

from planning.errors import ParameterError
from planning.toolpath.moves import RAPID, USE_CUT, USE_PLUNGE, USE_RAPID
from planning.toolpath.roughing import GAP_MM, roughing_paths
from planning.toolpath.roughing.common import _bounds
from planning.toolpath.roughing.maps import _ForbiddenMap, _raster
from schemas.params import RoughingParams

RT = 3.0          # tool radius, mm
ALLOW = 0.5       # stock allowance, mm
SP = 1.0          # stock sampling spacing (rest roughing), mm


# ------------------------------------------------------------------------------------------------
# clouds and stocks (area frame: tool axis +Z)
# ------------------------------------------------------------------------------------------------


def _plate(hx=12.0, hy=9.0):
    x, y = _grid(-hx, hx, -hy, hy, 0.5)
    return np.stack([x, y, np.zeros_like(x)], 1)


def _in_box(lo, hi, x, y):
    return (x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1])


# ------------------------------------------------------------------------------------------------
# reading the entries back, and the references
# ------------------------------------------------------------------------------------------------

def _plunge_runs(tp):
    """Maximal runs [i0, i1) of consecutive plunge-feed moves."""
    pl = np.concatenate([[False], tp.use == USE_PLUNGE, [False]]).astype(np.int8)
    d = np.diff(pl)
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def _entries(tp):
    """(helices, ramps, straight plunges): the plunge-feed runs as arrays of their points (the
    point before the run first). A run with horizontal motion on a line is a ramp, one on a circle a
    helix (without the straight feed down to its start that may lead it), any other a ramp along the
    piece's own path."""
    hel, ramps, straight = [], [], []
    for i0, i1 in _plunge_runs(tp):
        p = tp.xyz_mm[i0 - 1:i1]
        xy = p[:, :2] - p[0, :2]
        if np.abs(xy).max() < 1e-9:
            straight.append(p)
            continue
        k = int(np.flatnonzero(np.abs(xy).max(axis=1) >= 1e-9)[0]) - 1
        p = p[k:]
        xy = p[:, :2] - p[0, :2]
        d = xy[np.argmax(np.hypot(*xy.T))]
        cross = np.abs(xy[:, 0] * d[1] - xy[:, 1] * d[0]) / np.hypot(*d)
        if cross.max() < 1e-6:
            ramps.append(p)
            continue
        _, radii = _circle(p[:, :2])
        (hel if np.ptp(radii) < 1e-6 * max(1.0, radii.mean()) else ramps).append(p)
    return hel, ramps, straight


def _circle(xy):
    """Least-squares circle through the points (k, 2): (centre, radii of the points)."""
    A = np.column_stack([2 * xy, np.ones(len(xy))])
    b = (xy ** 2).sum(1)
    c = np.linalg.lstsq(A, b, rcond=None)[0]
    return c[:2], np.hypot(xy[:, 0] - c[0], xy[:, 1] - c[1])


def _allowed(pts, rp, rc=0.0, margin=2.0):
    """A function (samples (k,2), level z) -> bool (k,): the sample lies within 0.96 h of the
    centre of a cell (side h) the module's forbidden map allows at level z and within reach of the
    stock box (the clearing region's limits, the window aside): the module's guarantee for every
    point of its moves at a level (samples h / 4 apart in allowed cells), which its forbidden map
    covers (a cell is allowed when every point within h of its centre is safe)."""
    lo, hi, big = _bounds(pts)
    grid = _raster(pts, lo[:2] - margin, hi[:2] + margin, RT, rp.cell_mm)
    assert grid.h == rp.cell_mm
    forb = _ForbiddenMap(grid.cmax, grid.h, RT, rc, ALLOW, big)

    def ok(xy, z):
        thr = forb.threshold(z)
        h = grid.h
        good = np.zeros(len(xy), bool)
        i0 = np.floor((xy[:, 0] - grid.x0) / h).astype(int)
        j0 = np.floor((xy[:, 1] - grid.y0) / h).astype(int)
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                ix = np.clip(i0 + di, 0, grid.nx - 1)
                iy = np.clip(j0 + dj, 0, grid.ny - 1)
                d = np.hypot(xy[:, 0] - grid.x0 - (ix + 0.5) * h, xy[:, 1] - grid.y0 - (iy + 0.5) * h)
                good |= (d <= 0.96 * h + 1e-9) & grid.inbox[ix, iy] & (forb.G[ix, iy] <= thr)
        return good
    return ok


def _dense(p, step):
    out = [p[:1]]
    for a, b in zip(p[:-1], p[1:]):
        n = max(1, int(math.ceil(np.linalg.norm(b[:2] - a[:2]) / step)))
        out.append(a + (b - a) * (np.arange(1, n + 1)[:, None] / n))
    return np.concatenate(out)


def _downward_into_material(rp, top, lo, hi, g=0.2, cone_deg=10.0, rapids=None):
    """Indices of the feed moves that go straight down (within ``cone_deg`` of -Z) into material:
    the stock (height field ``top`` in the box lo..hi) is lowered under every feed move's disc to the
    move's lower end (flat end mill), and a downward move is into material when the stock under its
    end's disc (radius RT, touching excluded) stands above its end. ``rapids`` (a list): gets the
    rapids whose tool (radius RT from the tip up) meets the stock."""
    tp = rp.toolpath
    gx, gy = _grid(lo[0], hi[0], lo[1], hi[1], g)
    H = top(gx, gy).astype(np.float64)
    xyz = tp.xyz_mm
    bad = []
    tan = math.tan(math.radians(cone_deg))
    for i in range(1, tp.n_moves):
        a, b = xyz[i - 1], xyz[i]
        if tp.kind[i] == RAPID:
            if rapids is not None:
                d = b[:2] - a[:2]
                L2 = float(d @ d)
                u = np.clip(((gx - a[0]) * d[0] + (gy - a[1]) * d[1]) / L2, 0, 1) if L2 > 0 else np.zeros(gx.size)
                disc = np.hypot(gx - a[0] - u * d[0], gy - a[1] - u * d[1]) < RT - 1e-6
                if disc.any() and H[disc].max() >= min(a[2], b[2]):
                    rapids.append(i)
            continue
        dz = b[2] - a[2]
        dxy = float(np.hypot(*(b[:2] - a[:2])))
        if dz < 0 and dxy <= tan * -dz:
            disc = np.hypot(gx - b[0], gy - b[1]) < RT - 1e-6
            if disc.any() and H[disc].max() > b[2] + 1e-6:
                bad.append(i)
        d = b[:2] - a[:2]
        L2 = float(d @ d)
        u = np.clip(((gx - a[0]) * d[0] + (gy - a[1]) * d[1]) / L2, 0, 1) if L2 > 0 else np.zeros(gx.size)
        disc = np.hypot(gx - a[0] - u * d[0], gy - a[1] - u * d[1]) <= RT
        H[disc] = np.minimum(H[disc], min(a[2], b[2]))
    return bad


def _box_top(rp):
    lo, hi = rp.stock_box_mm
    return (lambda x, y: np.where(_in_box(lo, hi, x, y), hi[2], -np.inf)), lo, hi


# ------------------------------------------------------------------------------------------------
# helix geometry
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("diameter, angle", [(None, 3.0), (3.0, 5.0), (2.0, 12.0)])
def test_helix_angle_and_diameter_as_configured(diameter, angle):
    pts = _pockets([(0.0, 0.0)], 12.0)
    rp = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=2.0, stock_margin_mm=0.0, entry_diameter_mm=diameter,
                        entry_angle_deg=angle)
    hel, ramps, _ = _entries(rp.toolpath)
    assert rp.n_helix == len(hel) >= rp.n_levels and rp.n_ramps == len(ramps) == 0
    want = 0.5 * (0.7 * 2 * RT if diameter is None else diameter)
    for p in hel:
        d = np.diff(p, axis=0)
        slope = np.degrees(np.arctan2(-d[:, 2], np.hypot(d[:, 0], d[:, 1])))
        np.testing.assert_allclose(slope, angle, atol=1e-9)          # every chord at the entry angle
        _, r = _circle(p[:, :2])
        r_want = want if np.allclose(r, want, atol=1e-6) else 0.5 * want       # the fallback: half the diameter
        np.testing.assert_allclose(r, r_want, atol=1e-6)
        turn = np.degrees(np.arccos(np.clip(1 - (np.hypot(d[:, 0], d[:, 1]) / r_want) ** 2 / 2, -1, 1)))
        assert np.all(turn <= 360 / 24 + 1e-6)                       # at most 15 degrees per chord
        assert p[-1, 2] in rp.levels_mm                              # down to the level
        assert p[0, 2] >= p[-1, 2] + GAP_MM - 1e-9                   # from above the material
        # counter-clockwise seen from +Z
        c, _ = _circle(p[:, :2])
        ang = np.unwrap(np.arctan2(p[:, 1] - c[1], p[:, 0] - c[0]))
        assert np.all(np.diff(ang) > 0)
    assert rp.min_clearance_mm >= ALLOW - 1e-6


# ------------------------------------------------------------------------------------------------
# entries stay in the allowed cells
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("entry", ["helix", "ramp"])
@pytest.mark.parametrize("cloud", ["pocket", "dome", "post"])
def test_every_helix_and_ramp_sample_lies_in_allowed_cells(entry, cloud):
    pts = {"pocket": _pockets([(-10.0, 0.0), (10.0, 0.0)], 20.0), "dome": _dome(), "post": _post()}[cloud]
    margin = 0.0 if cloud == "pocket" else 2.0
    rp = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=2.0, stock_margin_mm=margin, entry=entry)
    ok = _allowed(pts, rp, margin=margin)
    hel, ramps, _ = _entries(rp.toolpath)
    assert len(hel) == rp.n_helix and len(ramps) == rp.n_ramps
    assert hel or ramps
    for p in hel + ramps:
        s = _dense(p[1:] if p[0, 2] > p[1, 2] and np.allclose(p[0, :2], p[1, :2]) else p, rp.cell_mm / 8)
        assert ok(s[:, :2], p[-1, 2]).all()
    if entry == "ramp":
        for p in ramps:
            legs = np.hypot(*np.diff(p[:, :2], axis=0).T)
            assert legs.max() <= 4 * RT + 1e-9 and np.all(legs >= 0)
            slope = np.degrees(np.arctan2(-np.diff(p[:, 2]), legs))
            np.testing.assert_allclose(slope, 3.0, atol=1e-9)
    assert rp.min_clearance_mm >= ALLOW - 1e-6


# ------------------------------------------------------------------------------------------------
# which entry where
# ------------------------------------------------------------------------------------------------

def test_a_closed_pocket_is_entered_by_a_helix():
    pts = _pockets([(0.0, 0.0)], 12.0)
    rp = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=2.0, stock_margin_mm=0.0)
    np.testing.assert_allclose(rp.levels_mm, [-2.0, -4.0, -5.5])
    assert rp.n_helix == rp.n_levels                                 # one per level: the pocket is one piece
    assert rp.n_plunges_into_material == rp.n_side_entries == rp.n_ramps == 0
    hel, _, _ = _entries(rp.toolpath)
    assert len(hel) == 3
    top, lo, hi = _box_top(rp)
    assert not _downward_into_material(rp, top, lo, hi)
    # with plunges the same pocket is entered straight down into the material, once per level
    pl = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=2.0, stock_margin_mm=0.0, entry="plunge")
    assert pl.n_plunges_into_material == 3 and pl.n_helix == 0
    assert len(_downward_into_material(pl, top, lo, hi)) == 3


def test_a_level_starting_in_air_plunges_straight():
    """Rest roughing of an island of stock on a plate already cut to the floor: every level starts
    beside the island, in air, and comes straight down (at the piece's first point, or, where the
    map's one-cell slack puts material within the radius there, a few cells back along the piece:
    a side entry, also a straight plunge into air)."""
    pts = _plate()
    lo = np.array([-22.0, -19.0, 0.0])
    hi = np.array([22.0, 19.0, 5.0])

    def top(x, y):
        return np.where(_in_box(lo, hi, x, y), np.where((np.abs(x) < 5) & (np.abs(y) < 4), 5.0, 0.4), -np.inf)

    rp = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=2.0, stock_points_mm=_dexel_points(top, lo, hi),
                        stock_spacing_mm=SP)
    np.testing.assert_allclose(rp.levels_mm, [3.0, 1.0, 0.5])
    assert rp.n_helix == rp.n_ramps == rp.n_plunges_into_material == 0
    assert rp.n_side_entries < rp.n_levels
    hel, ramps, straight = _entries(rp.toolpath)
    assert not hel and not ramps and len(straight) >= rp.n_levels
    for p in straight:                    # rapid down to GAP_MM above the level, then the plunge
        assert p[-1, 2] in rp.levels_mm and p[0, 2] == pytest.approx(p[-1, 2] + GAP_MM)
    assert not _downward_into_material(rp, top, lo, hi)
    # the side entries: the plunge, then a short feed at the level to the piece's first point
    tp = rp.toolpath
    ends = [i1 for i0, i1 in _plunge_runs(tp)]
    side = [i for i in ends if i < tp.n_moves and tp.use[i] == USE_CUT
            and np.linalg.norm(tp.xyz_mm[i, :2] - tp.xyz_mm[i - 1, :2]) <= RT + 4 * rp.cell_mm + 1e-9]
    assert len(side) >= rp.n_side_entries


def test_plunge_entry_is_the_former_path():
    """entry='plunge' reproduces the roughing as it was before the entries (figures recorded from it)."""
    cases = [
        (_dome(), dict(step_down_mm=2.0), (735, 1998.254385, 225.840386, 13)),
        (_pockets([(-10.0, 0.0), (10.0, 0.0)], 20.0), dict(step_down_mm=2.0, stock_margin_mm=0.0),
         (361, 200.89164, 73.147249, 6)),
        (_post(), dict(corner_radius_mm=1.0, step_down_mm=1.5, pattern="oneway"), (772, 2624.771043, 2349.495092, 80)),
    ]
    for pts, kw, (n, length, air, n_into) in cases:
        rp = roughing_paths(pts, tool_radius_mm=RT, entry="plunge", **kw)
        tp = rp.toolpath
        assert tp.n_moves == n
        assert rp.length_mm == pytest.approx(length, abs=1e-5) and rp.air_mm == pytest.approx(air, abs=1e-5)
        pl = np.flatnonzero(tp.use == USE_PLUNGE)
        np.testing.assert_array_equal(tp.xyz_mm[pl, :2], tp.xyz_mm[pl - 1, :2])      # all straight down
        assert rp.n_helix == rp.n_ramps == rp.n_side_entries == 0
        assert rp.n_plunges_into_material == n_into


# ------------------------------------------------------------------------------------------------
# brute force: no straight downward feed into material
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("entry", ["helix", "ramp", "plunge"])
def test_no_straight_downward_feed_into_material(entry):
    cases = [(_dome(), dict(step_down_mm=2.0), None),
             (_pockets([(-10.0, 0.0), (10.0, 0.0)], 20.0), dict(step_down_mm=2.0, stock_margin_mm=0.0), None),
             (_post(), dict(step_down_mm=2.0, pattern="oneway"), None)]
    lo_r = np.array([-16.0, -14.0, 0.0])
    hi_r = np.array([16.0, 14.0, 6.0])

    def rest_top(x, y):
        slope = np.clip(1.0 + 0.3 * (x + 16.0), 1.0, 6.0)
        return np.where(_in_box(lo_r, hi_r, x, y), np.where(np.hypot(x - 6.0, y + 5.0) < 4.0, 0.8, slope), -np.inf)

    cases.append((_plate(10.0, 8.0), dict(step_down_mm=1.5, stock_margin_mm=6.0,
                                          stock_points_mm=_dexel_points(rest_top, lo_r, hi_r), stock_spacing_mm=SP),
                  (rest_top, lo_r, hi_r)))
    total_into = 0
    for pts, kw, stock in cases:
        rp = roughing_paths(pts, tool_radius_mm=RT, entry=entry, **kw)
        top, lo, hi = _box_top(rp) if stock is None else stock
        rap = []
        bad = _downward_into_material(rp, top, lo, hi, rapids=rap)
        assert not rap                                               # rapids in air, the approaches included
        assert len(bad) <= rp.n_plunges_into_material                # the module's map is an upper bound
        if entry != "plunge":
            assert not bad and rp.n_plunges_into_material == 0
        total_into += len(bad)
        assert rp.min_clearance_mm >= ALLOW - 1e-6
        # helix and ramp moves are plunge feed; the rapids are rapids
        assert np.all(rp.toolpath.use[rp.toolpath.kind == RAPID] == USE_RAPID)
        _, _, straight = _entries(rp.toolpath)
        cut = rp.toolpath.use == USE_CUT
        assert cut.any() and len(straight) >= (0 if entry != "plunge" else rp.n_plunges_into_material)
    if entry == "plunge":
        assert total_into > 0


@pytest.mark.parametrize("cloud", ["dome", "post"])
def test_helices_beside_walls_start_just_above_the_level_before(cloud):
    """The map keeps the part's height beside its walls; a helix there is placed where the map is
    low (or farther away, linked at the level), so it starts GAP_MM above the level before."""
    pts = {"dome": _dome(), "post": _post()}[cloud]
    rp = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=2.0)
    hel, _, _ = _entries(rp.toolpath)
    assert len(hel) == rp.n_helix > 0
    lv = rp.levels_mm
    for p in hel:
        k = int(np.flatnonzero(lv == p[-1, 2])[0])
        above = lv[k - 1] if k else rp.stock_box_mm[1, 2]
        assert p[0, 2] <= above + GAP_MM + 1e-9


# ------------------------------------------------------------------------------------------------
# parameters
# ------------------------------------------------------------------------------------------------

def test_roughing_params_entries():
    p = RoughingParams()
    assert p.entry == "helix" and p.entry_angle_deg == 3.0 and p.entry_diameter_mm is None and p.ramp_length_mm is None
    RoughingParams(entry="ramp", entry_angle_deg=45.0, entry_diameter_mm=19.9, ramp_length_mm=5.0)
    for bad in (dict(entry="spiral"), dict(entry_angle_deg=0.0), dict(entry_angle_deg=46.0),
                dict(entry_diameter_mm=0.0), dict(entry_diameter_mm=20.0), dict(ramp_length_mm=4.0)):
        with pytest.raises(ValidationError):
            RoughingParams(**bad)


@pytest.mark.parametrize("kwargs, words", [
    (dict(entry="spiral"), "entry"),
    (dict(entry_angle_deg=0.0), "entry_angle_deg"),
    (dict(entry_angle_deg=60.0), "entry_angle_deg"),
    (dict(entry_angle_deg=float("nan")), "entry_angle_deg"),
    (dict(entry_diameter_mm=0.0), "entry_diameter_mm"),
    (dict(entry_diameter_mm=12.0), "entry_diameter_mm"),
    (dict(ramp_length_mm=2.0), "ramp_length_mm"),
])
def test_bad_entry_arguments_raise(kwargs, words):
    with pytest.raises(ParameterError, match=words):
        roughing_paths(_dome(), tool_radius_mm=RT, **kwargs)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_helix_sites_keeps_the_cheapest_in_order(seed):
    """The far helix sites look the material up cheapest first and stop early (issue 17): the
    FAR_TRIES cheapest in the stable order by cost are those of looking every site up (a huge
    ``ntop``), bit for bit, also with ties (material heights on a 0.5 mm grid, a wall) and a finite cap."""
    from planning.toolpath.roughing.entries import FAR_TRIES, _helix_sites

    rng = np.random.default_rng(seed)
    nx, ny, h, H = 80, 70, 0.5, 2.0
    ncx, ncy = int(nx * h / H), int(ny * h / H)
    top = np.round(rng.uniform(-2.0, 0.5, (ncx, ncy)) * 2) / 2       # cut down
    top[(np.arange(ncx) + 0.5) * H < 14.0] = 6.0                   # a wall beside q
    cx, cy = (np.arange(ncx) + 0.5) * H, (np.arange(ncy) + 0.5) * H
    hx, hy = np.full(ncx, 0.5 * H), np.full(ncy, 0.5 * H)
    fine = np.full((1, 1), np.inf)
    region = rng.random(nx * ny) < 0.6
    for cap in (math.inf, 25.0):
        args = (region, nx, ny, 20.3, 17.1, 24.0, 2, 4.5, 0.0, GAP_MM, 10.0, math.tan(math.radians(5.0)), cap)
        rest = (top, cx, cy, hx, hy, 0.0, 0.0, H, fine, False, 0.0, 0.0, h)
        fast, full = _helix_sites(*args, FAR_TRIES, *rest), _helix_sites(*args, 10**5, *rest)
        assert fast.shape[0] < full.shape[0]
        pick = [s[np.argsort(s[:, 3], kind="stable")[:FAR_TRIES]] for s in (fast, full)]
        assert np.array_equal(pick[0], pick[1])
