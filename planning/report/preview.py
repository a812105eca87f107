"""PNG preview of a segmentation: which set-up (tool axis) machines which points.

``render_preview`` draws the cloud in four views (isometric, top from +Z, front from -Y, side
from +X) with equal aspect, each area in its colour (:func:`area_colors`, shared with the
segmentation PLY), points not machined in :data:`UNCOVERED_COLOR`, leftover points attached to
an area (``integrated``) in the area colour darkened and with larger markers, and every set-up's tool axis as an
arrow from the cloud centroid. Rendering uses matplotlib's Agg canvas directly (no pyplot, no
display, no global figure registry) and the PNG is written atomically.
"""

from __future__ import annotations

import colorsys

import numpy as np
from matplotlib import patheffects
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

import mpl_toolkits.mplot3d  # noqa: F401  (registers the "3d" projection)

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
_INTEGRATED_SHADE = 0.55       # integrated leftovers: area colour darkened by this factor ...
_INTEGRATED_SIZE = 1.6         # ... and markers this much larger

# (title, horizontal axis, vertical axis, axis towards the viewer) of the orthographic views
_VIEWS = (
    ("top (from +Z)", 0, 1, np.array([0.0, 0.0, 1.0])),
    ("front (from -Y)", 0, 2, np.array([0.0, -1.0, 0.0])),
    ("side (from +X)", 1, 2, np.array([1.0, 0.0, 0.0])),
)
_AXIS_NAMES = "XYZ"
# a dark outline keeps an arrow visible over points of its own colour
_OUTLINE = [patheffects.Stroke(linewidth=4.6, foreground="black"), patheffects.Normal()]
_TEXT_OUTLINE = [patheffects.Stroke(linewidth=2.5, foreground="white"), patheffects.Normal()]


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


def render_preview(path, points, labels, axes, *, integrated=None, max_points: int = 60_000,
                   title: str | None = None, dpi: int = 110) -> None:
    """Render a PNG preview of the segmentation to ``path`` (written atomically).

    ``points`` ``(N, 3)`` mm; ``labels`` ``(N,)`` ints in ``[-1, k)`` (-1 = not machined);
    ``axes`` ``(k, 3)`` tool axes (part frame, pointing to the spindle); ``integrated`` ``(N,)``
    bool marks leftover points attached to an area. At most ``max_points`` points are drawn
    (fixed-seed random subsample). Arrows are 0.6 x the largest bounding-box side long.
    """
    pts, lab, ax_dirs, integ = _check_inputs(points, labels, axes, integrated)
    if not (isinstance(max_points, (int, np.integer)) and max_points >= 1):
        raise ParameterError(f"max_points must be a positive integer, got {max_points!r}.",
                             parameter="max_points")
    keep = _subsample(pts.shape[0], max_points)
    scene = _Scene(pts, lab, ax_dirs, integ, keep)
    fig = Figure(figsize=(12.0, 9.6), dpi=dpi)
    FigureCanvasAgg(fig)
    try:
        _draw_iso(fig.add_subplot(2, 2, 1, projection="3d"), scene)
        for slot, view in zip((2, 3, 4), _VIEWS):
            _draw_ortho(fig.add_subplot(2, 2, slot), scene, view)
        _add_legend(fig, scene)
        fig.suptitle(title or scene.default_title(), fontsize=13)
        fig.subplots_adjust(left=0.05, right=0.97, top=0.93, bottom=0.12, wspace=0.18,
                            hspace=0.2)
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", dpi=dpi)
    finally:
        fig.clear()


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
    return pts, lab.astype(np.int64), ax_dirs, integ


def _subsample(n: int, max_points: int) -> np.ndarray:
    """Sorted indices of at most ``max_points`` of ``n`` points, the same on every call."""
    if n <= max_points:
        return np.arange(n)
    return np.sort(np.random.default_rng(_SEED).choice(n, size=max_points, replace=False))


class _Scene:
    """Drawn points, their colours, sizes and edges, and the set-up arrows."""

    def __init__(self, pts, lab, ax_dirs, integ, keep):
        self.n_total, self.k = pts.shape[0], ax_dirs.shape[0]
        self.counts = np.bincount(lab + 1, minlength=self.k + 1)     # [uncovered, area 0, ...]
        self.n_integrated = int(integ.sum())
        self.axes = ax_dirs
        self.colors = area_colors(self.k)
        self.pts = pts[keep]
        integ_kept = integ[keep]
        face = point_colors(lab[keep], self.k) / 255.0
        self.face = np.where(integ_kept[:, None], _INTEGRATED_SHADE * face, face)
        base = float(np.clip(640.0 / np.sqrt(max(self.pts.shape[0], 1)), 1.0, 20.0))
        self.size = np.where(integ_kept, _INTEGRATED_SIZE * base, base)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        self.centroid = pts.mean(axis=0)
        self.arrow_mm = _ARROW_FRACTION * max(float((hi - lo).max()), 1e-9)
        tips = self.centroid + self.arrow_mm * ax_dirs
        self.lo = np.minimum(lo, tips.min(axis=0)) if self.k else lo
        self.hi = np.maximum(hi, tips.max(axis=0)) if self.k else hi

    def default_title(self) -> str:
        shown = "" if self.pts.shape[0] == self.n_total else f" (showing {self.pts.shape[0]:,})"
        return (f"{self.n_total:,} points{shown}, {self.k} set-up(s), "
                f"{int(self.counts[0]):,} not machined, {self.n_integrated:,} integrated")

    def order_towards(self, view_dir: np.ndarray) -> np.ndarray:
        """Drawing order: far points first so that near ones stay visible (painter's rule)."""
        return np.argsort(self.pts @ view_dir, kind="stable")


# --------------------------------------------------------------------------------------------
# drawing
# --------------------------------------------------------------------------------------------

def _scatter_kwargs(scene: _Scene, order: np.ndarray) -> dict:
    # square markers without edges: ~3x faster to rasterise than stroked circles in Agg
    return dict(c=scene.face[order], s=scene.size[order], marker="s", linewidths=0)


def _draw_ortho(ax, scene: _Scene, view) -> None:
    name, h, v, towards = view
    order = scene.order_towards(towards)
    ax.scatter(scene.pts[order, h], scene.pts[order, v], **_scatter_kwargs(scene, order))
    for i in range(scene.k):
        _draw_arrow_2d(ax, scene, i, h, v, towards)
    margin = 0.05 * float((scene.hi - scene.lo).max())
    ax.set_xlim(scene.lo[h] - margin, scene.hi[h] + margin)
    ax.set_ylim(scene.lo[v] - margin, scene.hi[v] + margin)
    ax.set_aspect("equal", adjustable="box")
    ax.set_title(name, fontsize=10)
    ax.set_xlabel(f"{_AXIS_NAMES[h]} (mm)")
    ax.set_ylabel(f"{_AXIS_NAMES[v]} (mm)")
    ax.grid(True, linewidth=0.3, alpha=0.5)


def _draw_arrow_2d(ax, scene: _Scene, i: int, h: int, v: int, towards: np.ndarray) -> None:
    color = scene.colors[i] / 255.0
    c = scene.centroid
    d = scene.axes[i] * scene.arrow_mm
    tip = (c[h] + d[h], c[v] + d[v])
    if np.hypot(d[h], d[v]) < 0.08 * scene.arrow_mm:      # axis along the line of sight
        symbol = "." if scene.axes[i] @ towards > 0 else "x"   # dot: towards you, cross: away
        ax.plot(c[h], c[v], marker="o", ms=14, mfc="none", mec=color, mew=2.2,
                path_effects=_OUTLINE, zorder=4)
        ax.plot(c[h], c[v], marker=symbol, ms=9 if symbol == "x" else 10, color=color, mew=2.2,
                path_effects=_OUTLINE, zorder=4)
        tip = (c[h], c[v])
    else:
        arrow = ax.annotate("", xy=tip, xytext=(c[h], c[v]), zorder=4,
                            arrowprops=dict(arrowstyle="-|>", color=color, lw=2.4,
                                            mutation_scale=18))
        arrow.arrow_patch.set_path_effects(_OUTLINE)
    ax.annotate(str(i), xy=tip, xytext=(5, 5), textcoords="offset points", color=color,
                fontsize=10, fontweight="bold", path_effects=_TEXT_OUTLINE, zorder=5)


def _draw_iso(ax, scene: _Scene) -> None:
    elev, azim = 30.0, -60.0
    view_dir = _view_direction(elev, azim)
    order = scene.order_towards(view_dir)
    p = scene.pts[order]
    ax.computed_zorder = False            # arrows stay above the points, whatever the depth
    ax.scatter(p[:, 0], p[:, 1], p[:, 2], depthshade=False, zorder=1,
               **_scatter_kwargs(scene, order))
    c = scene.centroid
    for i in range(scene.k):
        color = scene.colors[i] / 255.0
        d = scene.axes[i] * scene.arrow_mm
        arrow = ax.quiver(c[0], c[1], c[2], d[0], d[1], d[2], color=color, linewidth=2.4,
                          arrow_length_ratio=0.15, zorder=4)
        arrow.set_path_effects(_OUTLINE)
        ax.text(c[0] + d[0], c[1] + d[1], c[2] + d[2], f" {i}", color=color, fontsize=10,
                fontweight="bold", path_effects=_TEXT_OUTLINE, zorder=5)
    centre = (scene.lo + scene.hi) / 2.0
    half = 0.5 * float((scene.hi - scene.lo).max()) * 1.05
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1.0, 1.0, 1.0))
    ax.view_init(elev=elev, azim=azim)
    ax.set_title("isometric", fontsize=10)
    for setter, name in ((ax.set_xlabel, "X"), (ax.set_ylabel, "Y"), (ax.set_zlabel, "Z")):
        setter(f"{name} (mm)", fontsize=8)
    ax.tick_params(labelsize=7)


def _view_direction(elev_deg: float, azim_deg: float) -> np.ndarray:
    """Unit vector from the scene towards a matplotlib 3D camera at (elev, azim) degrees."""
    elev, azim = np.radians(elev_deg), np.radians(azim_deg)
    return np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])


def _add_legend(fig, scene: _Scene) -> None:
    handles = []
    for i in range(scene.k):
        x, y, z = scene.axes[i]
        label = f"area {i}: axis ({x:.3f}, {y:.3f}, {z:.3f}), {int(scene.counts[i + 1]):,} pts"
        handles.append(_legend_marker(scene.colors[i] / 255.0, label))
    if scene.counts[0]:
        handles.append(_legend_marker(UNCOVERED_COLOR / 255.0,
                                      f"not machined: {int(scene.counts[0]):,} pts"))
    if scene.n_integrated:
        shade = _INTEGRATED_SHADE * (scene.colors[0] / 255.0 if scene.k else np.ones(3))
        handles.append(_legend_marker(shade, f"integrated leftovers (darker, larger): "
                                      f"{scene.n_integrated:,} pts"))
    if handles:
        fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 3), fontsize=9,
                   frameon=False)


def _legend_marker(color, label: str) -> Line2D:
    return Line2D([], [], linestyle="none", marker="s", markersize=9, markerfacecolor=color,
                  markeredgecolor=color, label=label)
