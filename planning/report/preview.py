"""PNG preview of a segmentation: which set-up (tool axis) machines which points.

``render_preview`` draws every input point (``max_points`` optionally caps them with a fixed-seed
subsample) in four orthographic views with equal aspect: isometric (camera at elevation 30 deg,
azimuth -60 deg, i.e. from +X -Y +Z, with a small XYZ triad in its corner), top (from +Z), front
(from -Y) and side (from +X). Units are mm of the part frame: the axis-aligned views show X, Y, Z
in mm on their axes, the isometric view mm in its view plane. Each area is in its colour
(:func:`area_colors`, shared with the segmentation PLY), points not machined in
:data:`UNCOVERED_COLOR`, leftover points attached to an area (``integrated``) in the area colour
darkened and one pixel larger. Every set-up's tool axis is an arrow from the cloud centroid (seen
end-on: a dot in a circle when it points at the viewer, a cross when away), numbered beyond its
tip along its on-screen direction, clear of every arrow and of the other numbers. The legend gives
per set-up the machine's rotary positions (``angles``, when given), the axis and the point count.

Points are rasterised in numpy, not drawn as matplotlib markers. Per view, every point is projected
onto the pixel grid of its panel (the panel's size in pixels at the figure's dpi once its aspect is
equal), the point nearest the viewer wins each pixel (a z-buffer: ``np.maximum.at`` of a key made of
the quantised depth, then the point index, so ties resolve the same on every run), and the winners
are splatted to squares of 1 to 4 px, the size chosen from the projected density so that a sampled
surface looks closed, depth-tested again. The RGBA image is shown with ``imshow`` (nearest
neighbour, extent = the panel's mm limits; its size rounded down so that no pixel is dropped, a
single point keeps its exact colour) below the arrows and above the grid, which shows only where
no point lies. Points are processed in chunks: memory is O(chunk + pixels), time O(N). Rendering
uses matplotlib's Agg canvas directly (no pyplot, no display, no global figure registry) and the
PNG is written atomically.
"""

from __future__ import annotations

import colorsys
import math
import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from numbers import Real

import numpy as np
from matplotlib import patheffects
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from planning.errors import ParameterError
from planning.report.files import atomic_path

__all__ = ["UNCOVERED_COLOR", "area_colors", "point_colors", "render_preview"]

#: Colour (RGB uint8) of points that no set-up machines (label -1).
UNCOVERED_COLOR = np.array([64, 64, 64], dtype=np.uint8)

# Saturated, mutually distinct colours (matplotlib tab10 without its grey, then extras).
_BASE_COLORS = np.array([
    [31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
    [140, 86, 75], [227, 119, 194], [188, 189, 34], [23, 190, 207], [0, 0, 128],
    [255, 215, 0], [0, 128, 128],
], dtype=np.uint8)
_GOLDEN = 0.618033988749895
_ARROW_FRACTION = 0.6          # arrow length / largest side of the cloud's bounding box
_SEED = 0                      # subsampling seed (deterministic previews)
# the title: font size (pt), the widest character in em (DejaVu Sans, digits and capitals), most lines
_TITLE_PT, _TITLE_EM, _TITLE_LINES = 12, 0.66, 4
_INTEGRATED_SHADE = 0.55       # integrated leftovers: area colour darkened by this factor ...
_INTEGRATED_GROW = 1           # ... and splatted this many pixels larger
_MARGIN = 0.05                 # panel margin / largest projected side
_END_ON = 0.08                 # an axis projected shorter than this x its length is seen end-on

# rasterising
_CHUNK = 1 << 20               # points projected at a time
_DENSITY_BLOCK = 8             # px: side of the blocks of the density estimate
_CLOSED_DENSITY = 5.0          # front points per splat that make a sampled surface look closed
_DENSITY_QUANTILE = 0.1        # ... in this share of the silhouette's blocks, the sparsest
_MAX_SPLAT = 4                 # px

# set-up numbers at the arrows (sizes in points, converted with the figure's dpi)
_SEGMENT_CLEARANCE_PT = 6.0    # number box to an arrow's centre line: head half-width + outlines
_SYMBOL_RADIUS_PT = 10.0       # end-on symbol: circle radius with its outline
_LABEL_GAP_PT = 2.0            # number box to another number box or symbol
_LABEL_ANGLES = (0,) + tuple(s * a for a in range(20, 180, 20) for s in (1, -1)) + (180,)
_LABEL_STEPS = 10              # distances tried per direction, each 0.6 x the box's larger side

_ISO_ELEV, _ISO_AZIM = 30.0, -60.0
_AXIS_NAMES = "XYZ"
# a dark outline keeps an arrow visible over points of its own colour
_OUTLINE = [patheffects.Stroke(linewidth=4.6, foreground="black"), patheffects.Normal()]
_TEXT_OUTLINE = [patheffects.Stroke(linewidth=2.5, foreground="white"), patheffects.Normal()]
_LABEL_FONT = {"fontsize": 10, "fontweight": "bold"}


@dataclass(frozen=True)
class _View:
    """An orthographic view: part-frame directions drawn rightwards, upwards and towards the
    viewer (``right x up``), and the panel's title and axis labels."""

    name: str
    right: np.ndarray
    up: np.ndarray
    towards: np.ndarray
    xlabel: str
    ylabel: str

    @property
    def basis(self) -> np.ndarray:
        """``(3, 3)``: rows right, up, towards; ``p @ basis.T`` = (screen x, screen y, depth)."""
        return np.vstack([self.right, self.up, self.towards])


def _view_direction(elev_deg: float, azim_deg: float) -> np.ndarray:
    """Unit vector from the scene towards a camera at (elevation, azimuth) degrees."""
    elev, azim = np.radians(elev_deg), np.radians(azim_deg)
    return np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])


def _iso_view() -> _View:
    towards = _view_direction(_ISO_ELEV, _ISO_AZIM)
    right = np.cross([0.0, 0.0, 1.0], towards)
    right /= np.linalg.norm(right)
    return _View("isometric (from +X -Y +Z)", right, np.cross(towards, right), towards,
                 "view plane (mm)", "view plane (mm)")


_E = np.eye(3)
_VIEWS = (
    _iso_view(),
    _View("top (from +Z)", _E[0], _E[1], _E[2], "X (mm)", "Y (mm)"),
    _View("front (from -Y)", _E[0], _E[2], -_E[1], "X (mm)", "Z (mm)"),
    _View("side (from +X)", _E[1], _E[2], _E[0], "Y (mm)", "Z (mm)"),
)


def area_colors(k: int) -> np.ndarray:
    """``(k, 3)`` uint8 RGB colours, distinct and deterministic, one per area (set-up).

    The first 12 come from a fixed palette; further ones step the hue by the golden ratio with
    alternating saturation and value. None is grey, so all differ from :data:`UNCOVERED_COLOR`.
    """
    if not isinstance(k, (int, np.integer)) or k < 0:
        raise ParameterError(f"k must be a non-negative integer, got {k!r}.", parameter="k")
    if k <= len(_BASE_COLORS):
        return _BASE_COLORS[:k].copy()
    extra = [_golden_color(i) for i in range(k - len(_BASE_COLORS))]
    return np.vstack([_BASE_COLORS, np.array(extra, dtype=np.uint8)])


def _golden_color(i: int) -> list[int]:
    hue = (0.11 + i * _GOLDEN) % 1.0
    sat = (0.95, 0.6, 0.8)[i % 3]
    val = (0.9, 0.7, 1.0, 0.55)[(i // 3) % 4]
    return [int(round(255 * c)) for c in colorsys.hsv_to_rgb(hue, sat, val)]


def point_colors(labels, k: int) -> np.ndarray:
    """``(N, 3)`` uint8 colour per point: its area's colour, :data:`UNCOVERED_COLOR` for -1."""
    labels = np.asarray(labels)
    palette = np.vstack([area_colors(k), UNCOVERED_COLOR[None, :]])
    return palette[np.where(labels < 0, k, labels)]


def render_preview(path, points, labels, axes, *, integrated=None,
                   angles: Sequence[Mapping[str, float]] | None = None,
                   max_points: int | None = None, title: str | None = None,
                   dpi: int = 110, integrated_label: str | None = None) -> None:
    """Render a PNG preview of the segmentation to ``path`` (written atomically).

    ``points`` ``(N, 3)`` mm; ``labels`` ``(N,)`` ints in ``[-1, k)`` (-1 = not machined);
    ``axes`` ``(k, 3)`` tool axes (part frame, pointing to the spindle); ``integrated`` ``(N,)``
    bool marks leftover points attached to an area; ``angles`` per set-up the machine's rotary
    positions in degrees by axis name, in the machine's order (e.g. ``{"B": 35.0, "C": -120.0}``),
    shown in the legend. Every point is drawn unless ``max_points`` caps them (fixed-seed random
    subsample). Arrows are 0.6 x the largest bounding-box side long. ``integrated_label``: the legend's
    words for the integrated points (default: their count).
    """
    fig = _build_figure(points, labels, axes, integrated=integrated, angles=angles,
                        max_points=max_points, title=title, dpi=dpi, integrated_label=integrated_label)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", dpi=dpi)
    finally:
        fig.clear()


def _build_figure(points, labels, axes, *, integrated=None, angles=None, max_points=None,
                  title=None, dpi: int = 110, integrated_label: str | None = None) -> Figure:
    """The preview's figure (Agg canvas attached), laid out and ready to save at ``dpi``."""
    pts, lab, ax_dirs, integ = _check_inputs(points, labels, axes, integrated)
    rows = _check_angles(angles, ax_dirs.shape[0])
    keep = _subsample(pts.shape[0], _check_max_points(max_points))
    scene = _Scene(pts, lab, ax_dirs, integ, rows, keep)
    scene.integrated_label = integrated_label
    fig = Figure(figsize=(12.0, 9.6), dpi=dpi)
    FigureCanvasAgg(fig)
    # a long title (the plan's message) wraps instead of running off the picture; 4 lines at most
    chars = int(fig.get_figwidth() * 72.0 / (_TITLE_EM * _TITLE_PT))        # characters that fit across
    lines = textwrap.wrap(title or scene.default_title(), width=chars) or [""]
    if len(lines) > _TITLE_LINES:
        lines = lines[:_TITLE_LINES]
        lines[-1] = lines[-1][:chars - 3].rstrip() + "..."
    try:
        fig.subplots_adjust(left=0.05, right=0.97, top=0.93 - 0.022 * (len(lines) - 1), bottom=_legend_bottom(scene),
                            wspace=0.18, hspace=0.26)
        renderer = fig.canvas.get_renderer()
        for slot, view in enumerate(_VIEWS, start=1):
            _draw_panel(fig.add_subplot(2, 2, slot), scene, view, renderer)
        _add_legend(fig, scene)
        fig.suptitle("\n".join(lines), fontsize=_TITLE_PT)
    except BaseException:
        fig.clear()
        raise
    return fig


# --------------------------------------------------------------------------------------------
# inputs
# --------------------------------------------------------------------------------------------

def _check_inputs(points, labels, axes, integrated):
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] == 0:
        raise ParameterError(f"points must be a non-empty (N, 3) array, got shape {pts.shape}.",
                             parameter="points")
    if not np.isfinite(pts).all():
        raise ParameterError("points must be finite (validate the cloud first).",
                             parameter="points")
    ax_dirs = np.asarray(axes, dtype=np.float64).reshape(-1, 3) if np.size(axes) else \
        np.zeros((0, 3))
    norms = np.linalg.norm(ax_dirs, axis=1)
    if np.any(~np.isfinite(norms) | (norms < 1e-12)):
        raise ParameterError("every tool axis must be a non-zero finite vector.", parameter="axes")
    ax_dirs = ax_dirs / norms[:, None]
    lab = np.asarray(labels)
    if lab.shape != (pts.shape[0],) or (lab.size and not np.issubdtype(lab.dtype, np.integer)):
        raise ParameterError(f"labels must be (N,) integers with N={pts.shape[0]}, got "
                             f"{lab.shape} {lab.dtype}.", parameter="labels")
    if lab.size and (lab.min() < -1 or lab.max() >= ax_dirs.shape[0]):
        raise ParameterError(f"labels must lie in [-1, {ax_dirs.shape[0]}) (one per tool axis).",
                             parameter="labels")
    if integrated is None:
        integ = np.zeros(pts.shape[0], dtype=bool)
    else:
        integ = np.asarray(integrated, dtype=bool)
        if integ.shape != (pts.shape[0],):
            raise ParameterError(f"integrated must have shape ({pts.shape[0]},), got "
                                 f"{integ.shape}.", parameter="integrated")
    return pts, lab.astype(np.int64, copy=False), ax_dirs, integ


def _check_angles(angles, k: int) -> list[dict[str, float]] | None:
    """``angles`` as one ``{axis name: degrees}`` dict per set-up (order kept), or None."""
    if angles is None:
        return None
    if isinstance(angles, (str, bytes, Mapping)) or not isinstance(angles, Sequence):
        raise ParameterError("angles must be a sequence with one {axis name: degrees} mapping "
                             "per tool axis.", parameter="angles")
    if len(angles) != k:
        raise ParameterError(f"angles must give the machine angles of every tool axis: {k} "
                             f"expected, got {len(angles)}.", parameter="angles")
    return [_check_angle_row(row, i) for i, row in enumerate(angles)]


def _check_angle_row(row, i: int) -> dict[str, float]:
    if not isinstance(row, Mapping):
        raise ParameterError(f"angles[{i}] must map axis names to degrees, got {row!r}.",
                             parameter="angles")
    out = {}
    for name, value in row.items():
        if not isinstance(name, str) or isinstance(value, bool) or not isinstance(value, Real) \
                or not math.isfinite(value):
            raise ParameterError(f"angles[{i}] must map axis names (str) to finite degrees, got "
                                 f"{name!r}: {value!r}.", parameter="angles")
        out[name] = float(value)
    return out


def _check_max_points(max_points) -> int | None:
    if max_points is None:
        return None
    if isinstance(max_points, bool) or not isinstance(max_points, (int, np.integer)) \
            or max_points < 1:
        raise ParameterError(f"max_points must be a positive integer or None, got "
                             f"{max_points!r}.", parameter="max_points")
    return int(max_points)


def _subsample(n: int, max_points: int | None) -> np.ndarray | None:
    """Sorted indices of at most ``max_points`` of ``n`` points, the same on every call; None
    for all of them."""
    if max_points is None or n <= max_points:
        return None
    return np.sort(np.random.default_rng(_SEED).choice(n, size=max_points, replace=False))


class _Scene:
    """Drawn points with their palette rows, the set-up arrows and the legend's figures."""

    def __init__(self, pts, lab, ax_dirs, integ, angles, keep):
        self.n_total, self.k = pts.shape[0], ax_dirs.shape[0]
        self.counts = np.bincount(lab + 1, minlength=self.k + 1)     # [uncovered, area 0, ...]
        self.n_integrated = int(integ.sum())
        self.axes, self.angles = ax_dirs, angles
        self.colors = area_colors(self.k)
        self.palette = _palette(self.colors)
        if keep is not None:
            pts_drawn, lab, integ = pts[keep], lab[keep], integ[keep]
        else:
            pts_drawn = pts
        self.pts = pts_drawn
        self.code = ((lab + 1) * 2 + integ).astype(np.int32)          # row of self.palette
        self.centroid = np.ones(pts.shape[0]) @ pts / pts.shape[0]     # BLAS, not a column sum
        lo, hi = _projected_bounds(pts, np.eye(3))
        self.arrow_mm = _ARROW_FRACTION * max(float((hi - lo).max()), 1e-9)

    @property
    def tips(self) -> np.ndarray:
        """``(k, 3)`` arrow tips (mm)."""
        return self.centroid + self.arrow_mm * self.axes

    def default_title(self) -> str:
        shown = "" if self.pts.shape[0] == self.n_total else f" (showing {self.pts.shape[0]:,})"
        return (f"{self.n_total:,} points{shown}, {self.k} set-up(s), "
                f"{int(self.counts[0]):,} not machined, {self.n_integrated:,} integrated")


def _palette(colors: np.ndarray) -> np.ndarray:
    """``(2 (k + 1), 4)`` uint8 RGBA: row ``2 (label + 1) + integrated``."""
    base = np.vstack([UNCOVERED_COLOR[None, :], colors]).astype(np.float64)
    rgb = np.empty((2 * base.shape[0], 3))
    rgb[0::2], rgb[1::2] = base, np.round(_INTEGRATED_SHADE * base)
    return np.hstack([rgb, np.full((rgb.shape[0], 1), 255.0)]).astype(np.uint8)


# --------------------------------------------------------------------------------------------
# rasterising
# --------------------------------------------------------------------------------------------

def _projected_bounds(pts: np.ndarray, basis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-row minimum and maximum of ``pts @ basis.T``, chunk by chunk."""
    lo = np.full(basis.shape[0], np.inf)
    hi = np.full(basis.shape[0], -np.inf)
    for start in range(0, pts.shape[0], _CHUNK):
        q = _project(pts[start:start + _CHUNK], basis)
        lo, hi = np.minimum(lo, q.min(axis=1)), np.maximum(hi, q.max(axis=1))
    return lo, hi


def _project(pts: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """``(rows of basis, n)``: ``basis @ pts.T``, one contiguous row per coordinate (BLAS; an
    order of magnitude faster than ``pts @ basis.T`` and its column reductions)."""
    return basis @ pts.T


def _rasterise(scene: _Scene, view: _View, limits, shape, depth_range) -> np.ndarray:
    """``(H, W, 4)`` uint8 RGBA image of the points seen in ``view``, its pixels spanning
    ``limits`` (x0, x1, y0, y1 mm, row 0 at y1); transparent where no point lies."""
    height, width = shape
    n = scene.pts.shape[0]
    bits = max(int(n - 1).bit_length(), 1)                 # low bits of a key: the point index
    levels = 1 << min(32, 62 - bits)                       # high bits: the quantised depth
    dlo, dhi = depth_range
    dscale = (levels - 1) / (dhi - dlo) if dhi > dlo else 0.0
    x0, x1, y0, y1 = limits
    sx, sy = width / (x1 - x0), height / (y1 - y0)
    block_w = -(-width // _DENSITY_BLOCK)
    zbuf = np.full(height * width, -1, dtype=np.int64)
    density = np.zeros(block_w * -(-height // _DENSITY_BLOCK), dtype=np.int64)
    for start in range(0, n, _CHUNK):
        q = _project(scene.pts[start:start + _CHUNK], view.basis)
        col = np.clip(((q[0] - x0) * sx).astype(np.int64), 0, width - 1)
        row = np.clip(((y1 - q[1]) * sy).astype(np.int64), 0, height - 1)
        depth = np.clip(((q[2] - dlo) * dscale).astype(np.int64), 0, levels - 1)
        np.maximum.at(zbuf, row * width + col,
                      (depth << bits) | np.arange(start, start + q.shape[1], dtype=np.int64))
        density += np.bincount((row // _DENSITY_BLOCK) * block_w + col // _DENSITY_BLOCK,
                               minlength=density.size)
    zbuf = _splat(zbuf, shape, _splat_size(density.reshape(-1, block_w)), scene.code, bits)
    rgba = np.zeros((height * width, 4), dtype=np.uint8)
    hit = np.flatnonzero(zbuf >= 0)
    rgba[hit] = scene.palette[scene.code[zbuf[hit] & ((1 << bits) - 1)]]
    return rgba.reshape(height, width, 4)


def _splat_size(density: np.ndarray) -> int:
    """Square side (px) that puts :data:`_CLOSED_DENSITY` front points in every square where the
    cloud is sparsest: the low :data:`_DENSITY_QUANTILE` of the blocks inside the silhouette
    (they and their 4 neighbours hold points), taking half a block's points as its front layer
    (a closed surface shows one of its two sides)."""
    occupied = density > 0
    inner = occupied.copy()
    inner[1:-1, 1:-1] &= (occupied[:-2, 1:-1] & occupied[2:, 1:-1] & occupied[1:-1, :-2]
                          & occupied[1:-1, 2:])
    inner[[0, -1], :] = False
    inner[:, [0, -1]] = False
    counts = density[inner] if inner.any() else density[occupied]
    if counts.size == 0:
        return 1
    front_per_px = float(np.quantile(counts, _DENSITY_QUANTILE)) / (2.0 * _DENSITY_BLOCK ** 2)
    return int(np.clip(np.ceil(np.sqrt(_CLOSED_DENSITY / front_per_px)), 1, _MAX_SPLAT))


def _splat(zbuf: np.ndarray, shape, size: int, code: np.ndarray, bits: int) -> np.ndarray:
    """Every pixel's winner drawn as a square of ``size`` px (integrated points
    :data:`_INTEGRATED_GROW` larger), nearest key winning again where squares overlap."""
    height, width = shape
    hit = np.flatnonzero(zbuf >= 0)
    keys = zbuf[hit]
    sizes = size + _INTEGRATED_GROW * (code[keys & ((1 << bits) - 1)] & 1)
    if hit.size == 0 or sizes.max() <= 1:
        return zbuf
    rows, cols = np.divmod(hit, width)
    first, last = -((sizes - 1) // 2), sizes // 2          # offsets covered by each square
    out = np.full(height * width, -1, dtype=np.int64)
    span = range(int(first.min()), int(last.max()) + 1)
    for dy in span:
        for dx in span:
            r, c = rows + dy, cols + dx
            sel = ((first <= dy) & (dy <= last) & (first <= dx) & (dx <= last)
                   & (r >= 0) & (r < height) & (c >= 0) & (c < width))
            np.maximum.at(out, r[sel] * width + c[sel], keys[sel])
    return out


# --------------------------------------------------------------------------------------------
# panels
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Arrow:
    """A set-up's arrow in a panel (mm of the panel's axes)."""

    index: int
    start: np.ndarray
    tip: np.ndarray
    end_on: bool


def _draw_panel(ax, scene: _Scene, view: _View, renderer) -> None:
    lo, hi = _projected_bounds(scene.pts, view.basis)
    limits = _panel_limits(scene, view, lo[:2], hi[:2])
    ax.set_xlim(limits[0], limits[1])
    ax.set_ylim(limits[2], limits[3])
    ax.set_aspect("equal", adjustable="box")
    ax.apply_aspect()                                # the panel's final box, in pixels
    # rounded down: imshow then scales by >= 1 and its nearest-neighbour resampling drops no pixel
    shape = (int(np.floor(ax.bbox.height)), int(np.floor(ax.bbox.width)))
    ax.imshow(_rasterise(scene, view, limits, shape, (lo[2], hi[2])), extent=limits,
              origin="upper", interpolation="nearest", zorder=1)
    ax.set_xlim(limits[0], limits[1])
    ax.set_ylim(limits[2], limits[3])
    ax.apply_aspect()
    arrows = [_draw_arrow(ax, scene, view, i) for i in range(scene.k)]
    obstacles = _draw_triad(ax) if view is _VIEWS[0] else []
    _draw_labels(ax, scene, arrows, obstacles, renderer)
    ax.set_title(view.name, fontsize=10)
    ax.set_xlabel(view.xlabel)
    ax.set_ylabel(view.ylabel)
    ax.set_axisbelow(True)                           # the grid shows between points, not on them
    ax.grid(True, linewidth=0.3, alpha=0.5)


def _panel_limits(scene: _Scene, view: _View, lo: np.ndarray, hi: np.ndarray):
    """(x0, x1, y0, y1) mm: the projected points, centroid and arrow tips plus a margin."""
    ends = np.vstack([scene.centroid[None, :], scene.tips]) @ view.basis[:2].T
    lo, hi = np.minimum(lo, ends.min(axis=0)), np.maximum(hi, ends.max(axis=0))
    margin = _MARGIN * max(float((hi - lo).max()), 1e-9)
    return (float(lo[0] - margin), float(hi[0] + margin), float(lo[1] - margin),
            float(hi[1] + margin))


def _draw_arrow(ax, scene: _Scene, view: _View, i: int) -> _Arrow:
    color = scene.colors[i] / 255.0
    start = scene.centroid @ view.basis[:2].T
    d = scene.axes[i] @ view.basis.T                  # (right, up, towards)
    if np.hypot(d[0], d[1]) < _END_ON:                # axis along the line of sight
        symbol = "." if d[2] > 0 else "x"             # dot: towards you, cross: away
        ax.plot(*start, marker="o", ms=14, mfc="none", mec=color, mew=2.2,
                path_effects=_OUTLINE, zorder=4, gid=f"setup-symbol-{i}")
        ax.plot(*start, marker=symbol, ms=9 if symbol == "x" else 10, color=color, mew=2.2,
                path_effects=_OUTLINE, zorder=4)
        return _Arrow(i, start, start, True)
    tip = start + scene.arrow_mm * d[:2]
    arrow = ax.annotate("", xy=tuple(tip), xytext=tuple(start), zorder=4,
                        arrowprops=dict(arrowstyle="-|>", color=color, lw=2.4,
                                        mutation_scale=18))
    arrow.arrow_patch.set_path_effects(_OUTLINE)
    arrow.set_gid(f"setup-arrow-{i}")
    return _Arrow(i, start, tip, False)


def _draw_triad(ax) -> list[tuple[float, float, float, float]]:
    """Part-frame X, Y, Z as seen in the isometric view, in the panel's lower-left corner;
    returns its box (display px), which the set-up numbers keep clear of."""
    view, px = _VIEWS[0], ax.figure.dpi / 72.0
    box = ax.bbox
    origin = np.array([box.x0, box.y0]) + 28.0 * px
    length, reach = 16.0 * px, 22.0 * px
    for j, name in enumerate(_AXIS_NAMES):
        d = view.basis[:2, j]
        end, label = origin + length * d, origin + reach * d
        (ox, oy), (ex, ey), (lx, ly) = (_to_axes(ax, q) for q in (origin, end, label))
        ax.plot([ox, ex], [oy, ey], transform=ax.transAxes, color="0.15", lw=1.3, zorder=5)
        ax.text(lx, ly, name, transform=ax.transAxes, fontsize=8, ha="center", va="center",
                color="0.15", zorder=5, path_effects=_TEXT_OUTLINE)
    half = reach + 5.0 * px
    return [(origin[0] - half, origin[1] - half, origin[0] + half, origin[1] + half)]


def _to_axes(ax, display_xy: np.ndarray) -> tuple[float, float]:
    box = ax.bbox
    return ((display_xy[0] - box.x0) / box.width, (display_xy[1] - box.y0) / box.height)


# --------------------------------------------------------------------------------------------
# set-up numbers: beyond the arrow tips, clear of every arrow, symbol and other number
# --------------------------------------------------------------------------------------------

def _draw_labels(ax, scene: _Scene, arrows: list[_Arrow], obstacles: list, renderer) -> None:
    px = ax.figure.dpi / 72.0
    to_px = ax.transData.transform
    ends = [(to_px(a.start), to_px(a.tip)) for a in arrows]
    segments = [e for a, e in zip(arrows, ends) if not a.end_on]
    boxes = list(obstacles) + [_box(to_px(a.start), 2 * _SYMBOL_RADIUS_PT * px,
                                    2 * _SYMBOL_RADIUS_PT * px) for a in arrows if a.end_on]
    frame = tuple(ax.bbox.extents)
    for a, (start, tip) in zip(arrows, ends):
        text = ax.text(*a.tip, str(a.index), color=scene.colors[a.index] / 255.0, ha="center",
                       va="center", path_effects=_TEXT_OUTLINE, zorder=5,
                       gid=f"setup-label-{a.index}", **_LABEL_FONT)
        extent = text.get_window_extent(renderer)
        size = (float(extent.width), float(extent.height))
        centre = _place_label(start, tip, a.end_on, size, segments, boxes, frame, px)
        text.set_position(tuple(ax.transData.inverted().transform(centre)))
        boxes.append(_box(centre, *size))


def _place_label(start, tip, end_on: bool, size, segments, boxes, frame, px: float) -> np.ndarray:
    """Centre (display px) of a number box of ``size``: the first candidate, nearest the tip
    along the arrow's on-screen direction first, whose box stays :data:`_SEGMENT_CLEARANCE_PT`
    from every arrow's centre line and :data:`_LABEL_GAP_PT` from every box in ``boxes``, inside
    the panel if possible."""
    clearance, gap = _SEGMENT_CLEARANCE_PT * px, _LABEL_GAP_PT * px
    if end_on:                                       # beside the symbol, to its right first
        base, u, offset = start, np.array([1.0, 0.0]), _SYMBOL_RADIUS_PT * px + gap
    else:
        length = float(np.linalg.norm(tip - start))
        u = (tip - start) / length if length > 0.0 else np.array([1.0, 0.0])
        base, offset = tip, clearance + px
    candidates = _label_candidates(base, u, offset, size)
    for inside in (True, False):
        for centre in candidates:
            box = _box(centre, *size)
            if (not inside or _box_within(box, frame)) and \
                    _box_is_clear(box, segments, clearance, boxes, gap):
                return centre
    return candidates[0]


def _label_candidates(base: np.ndarray, u: np.ndarray, offset: float, size) -> list[np.ndarray]:
    """Box centres whose box lies ``offset`` + k steps beyond ``base`` in direction ``u``
    turned by each of :data:`_LABEL_ANGLES`, cheapest (small turn, small k) first."""
    w, h = size
    step = 0.6 * max(w, h)
    scored = []
    for order, angle in enumerate(_LABEL_ANGLES):
        c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
        d = np.array([u[0] * c - u[1] * s, u[0] * s + u[1] * c])
        support = 0.5 * (w * abs(d[0]) + h * abs(d[1]))  # box half-extent along d
        for k in range(_LABEL_STEPS):
            centre = base + d * (offset + support + k * step)
            scored.append((abs(angle) / 20.0 + k, order, k, centre))
    scored.sort(key=lambda item: item[:3])
    return [item[3] for item in scored]


def _box(centre, w: float, h: float) -> tuple[float, float, float, float]:
    return (float(centre[0]) - w / 2, float(centre[1]) - h / 2, float(centre[0]) + w / 2,
            float(centre[1]) + h / 2)


def _box_within(box, frame) -> bool:
    return box[0] >= frame[0] and box[1] >= frame[1] and box[2] <= frame[2] and box[3] <= frame[3]


def _box_is_clear(box, segments, clearance: float, boxes, gap: float) -> bool:
    if any(_segment_box_distance(a, b, box) <= clearance for a, b in segments):
        return False
    return not any(box[0] < o[2] + gap and o[0] < box[2] + gap and box[1] < o[3] + gap
                   and o[1] < box[3] + gap for o in boxes)


def _segment_box_distance(a, b, box) -> float:
    """Euclidean distance between segment ``ab`` and an axis-aligned box (0 if they meet)."""
    if _segment_meets_box(a, b, box):
        return 0.0
    corners = ((box[0], box[1]), (box[2], box[1]), (box[0], box[3]), (box[2], box[3]))
    return min(_point_box_distance(a, box), _point_box_distance(b, box),
               *(_point_segment_distance(c, a, b) for c in corners))


def _segment_meets_box(a, b, box) -> bool:
    """Liang-Barsky: does segment ``ab`` meet the closed box?"""
    t0, t1 = 0.0, 1.0
    dx, dy = float(b[0] - a[0]), float(b[1] - a[1])
    for p, q in ((-dx, a[0] - box[0]), (dx, box[2] - a[0]), (-dy, a[1] - box[1]),
                 (dy, box[3] - a[1])):
        if p == 0.0:
            if q < 0.0:
                return False
            continue
        r = float(q) / p
        if p < 0.0:
            t0 = max(t0, r)
        else:
            t1 = min(t1, r)
        if t0 > t1:
            return False
    return True


def _point_box_distance(p, box) -> float:
    return math.hypot(max(box[0] - p[0], 0.0, p[0] - box[2]),
                      max(box[1] - p[1], 0.0, p[1] - box[3]))


def _point_segment_distance(p, a, b) -> float:
    ab = (float(b[0] - a[0]), float(b[1] - a[1]))
    ap = (float(p[0] - a[0]), float(p[1] - a[1]))
    length2 = ab[0] ** 2 + ab[1] ** 2
    t = 0.0 if length2 == 0.0 else min(max((ap[0] * ab[0] + ap[1] * ab[1]) / length2, 0.0), 1.0)
    return math.hypot(ap[0] - t * ab[0], ap[1] - t * ab[1])


# --------------------------------------------------------------------------------------------
# legend
# --------------------------------------------------------------------------------------------

def _legend_entries(scene: _Scene) -> list[tuple[np.ndarray, str]]:
    """(RGB in [0, 1], text) of every legend entry."""
    entries = [(scene.colors[i] / 255.0, _setup_text(scene, i)) for i in range(scene.k)]
    if scene.counts[0]:
        entries.append((UNCOVERED_COLOR / 255.0, f"not machined: {int(scene.counts[0]):,} input pts"))
    if scene.n_integrated:
        shade = scene.palette[3 if scene.k else 1, :3] / 255.0
        text = (getattr(scene, "integrated_label", None)
                or f"seen by no chosen set-up, attached by distance (darker, larger): {scene.n_integrated:,} input pts")
        entries.append((shade, text))
    return entries


def _setup_text(scene: _Scene, i: int) -> str:
    """``area i: B 35.000° C -120.000°, axis (x, y, z), n pts`` (angles only when given)."""
    rows = scene.angles[i] if scene.angles is not None else {}
    angles = " ".join(f"{name} {round(value, 3) + 0.0:.3f}°" for name, value in rows.items())
    x, y, z = scene.axes[i]
    return (f"area {i}: {angles + ', ' if angles else ''}axis ({x:.3f}, {y:.3f}, {z:.3f}), "
            f"{int(scene.counts[i + 1]):,} input pts")


def _legend_columns(scene: _Scene) -> int:
    return 2 if scene.angles else 3


def _legend_bottom(scene: _Scene) -> float:
    """Figure fraction below the panels: room for the legend's rows (15 pt each)."""
    n_rows = -(-len(_legend_entries(scene)) // _legend_columns(scene))
    return max(0.12, 0.05 + n_rows * 15.0 / (72.0 * 9.6))


def _add_legend(fig, scene: _Scene) -> None:
    handles = [_legend_marker(color, text) for color, text in _legend_entries(scene)]
    if handles:
        fig.legend(handles=handles, loc="lower center", fontsize=9, frameon=False,
                   ncol=min(len(handles), _legend_columns(scene)))


def _legend_marker(color, label: str) -> Line2D:
    return Line2D([], [], linestyle="none", marker="s", markersize=9, markerfacecolor=color,
                  markeredgecolor=color, label=label)
