"""The verification's artifacts (issue 15): the scan coloured by its deviation from the simulated
result (PLY with a ``deviation_mm`` property, and a PNG of three views with a colour bar in mm), and
the final simulated stock as a triangle mesh (PLY). Written atomically (:func:`atomic_path`)."""

from __future__ import annotations

import numpy as np
from plyfile import PlyData, PlyElement

from planning.report.files import atomic_path

#: Points drawn in the deviation PNG at most (a random, seeded subset of the scan).
PNG_MAX_POINTS = 120_000


#: The one colour convention for deviation (issue 34), used by the PLY, the PNG and the viewer
#: (viewer.json ``deviation.colors``): green within the finishing limit, blue for material left
#: (saturated at +10 x the limit), red for a cut below the scan (saturated at -10 x the limit),
#: grey where not measured. RGB 0-255.
DEVIATION_COLORS = {"within": (60, 170, 75), "left": (30, 80, 220), "cut": (220, 30, 30),
                    "unmeasured": (128, 128, 128)}
#: Where the ramps saturate, in limits.
DEVIATION_SATURATION = 10.0


def deviation_colors(dev: np.ndarray, limit_mm: float) -> np.ndarray:
    """(N,3) uint8 by :data:`DEVIATION_COLORS`: green within ``limit_mm`` on both sides; beyond it a
    ramp from a light tint of the colour to blue where material is left (dev > 0) or red where cut
    below the scan (dev < 0), saturated at :data:`DEVIATION_SATURATION` x ``limit_mm``; grey where
    not measured (NaN)."""
    dev = np.asarray(dev, dtype=np.float64)
    limit = max(float(limit_mm), 1e-9)
    d = np.nan_to_num(dev, nan=0.0)
    # 0 at the limit, 1 at saturation
    a = np.clip((np.abs(d) - limit) / (limit * (DEVIATION_SATURATION - 1.0)), 0.0, 1.0)[:, None]
    light = np.array([235.0, 235.0, 235.0])
    left, cut = (np.array(DEVIATION_COLORS[k], dtype=np.float64) for k in ("left", "cut"))
    t = 0.25 + 0.75 * a                       # a point just beyond the limit is already tinted
    col = np.where((d > 0)[:, None], (1 - t) * light + t * left, (1 - t) * light + t * cut)
    col[np.abs(d) <= limit] = DEVIATION_COLORS["within"]
    col[~np.isfinite(dev)] = DEVIATION_COLORS["unmeasured"]
    return np.rint(col).astype(np.uint8)


def write_deviation_ply(path, points: np.ndarray, dev: np.ndarray, limit_mm: float,
                        finish_left: np.ndarray | None = None) -> None:
    """Every scan point (mm, float: 24 bits, under 0.00005 mm within +-400 mm) with its colour
    (:func:`deviation_colors`) and ``deviation_mm``; with ``finish_left`` (N,) also ``finish_left_mm``:
    the material the finishing ball leaves over the point, measured exactly
    (:func:`planning.simulate.finish.finish_left_mm`; NaN where not measured, +inf where no finishing
    move reaches it)."""
    col = deviation_colors(dev, limit_mm)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
              ("deviation_mm", "f4")]
    if finish_left is not None:
        fields.append(("finish_left_mm", "f4"))
    v = np.empty(points.shape[0], dtype=fields)
    v["x"], v["y"], v["z"] = points[:, 0], points[:, 1], points[:, 2]
    v["red"], v["green"], v["blue"] = col[:, 0], col[:, 1], col[:, 2]
    v["deviation_mm"] = dev.astype(np.float32)
    if finish_left is not None:
        v["finish_left_mm"] = np.asarray(finish_left, dtype=np.float32)
    with atomic_path(path) as tmp:
        PlyData([PlyElement.describe(v, "vertex")], byte_order="<").write(str(tmp))


def write_mesh_ply(path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """A triangle mesh (vertices (V,3) mm, faces (F,3) indices) as binary PLY: plyfile's header
    (float ``x y z``; ``list uchar int vertex_indices``) and the bytes its writer would give, packed
    by numpy in one go (plyfile writes a list property row by row)."""
    v = np.empty(vertices.shape[0], dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    v["x"], v["y"], v["z"] = vertices[:, 0], vertices[:, 1], vertices[:, 2]
    f = np.empty(faces.shape[0], dtype=[("vertex_indices", "<i4", (3,))])
    f["vertex_indices"] = faces.astype(np.int32)
    header = PlyData([PlyElement.describe(v, "vertex"), PlyElement.describe(f, "face")], byte_order="<").header
    rows = np.empty(faces.shape[0], dtype=[("n", "u1"), ("vertex_indices", "<i4", (3,))])   # packed: 13 bytes
    rows["n"] = 3
    rows["vertex_indices"] = f["vertex_indices"]
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header.encode("ascii") + b"\n")
        fh.write(v.tobytes())
        fh.write(rows.tobytes())


def render_deviation_png(path, points: np.ndarray, dev: np.ndarray, limit_mm: float, title: str = "") -> None:
    """Three orthographic views (top, front, side) of the scan coloured by deviation, with a colour
    bar in mm (positive: material left, negative: cut below the scan)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap, Normalize

    n = points.shape[0]
    idx = np.arange(n) if n <= PNG_MAX_POINTS else np.sort(
        np.random.default_rng(0).choice(n, PNG_MAX_POINTS, replace=False))
    p, d = points[idx], dev[idx]
    span = max(DEVIATION_SATURATION * limit_mm, 1e-6)
    # the colour bar is the points' own colouring (deviation_colors) sampled over [-span, span]
    cmap = ListedColormap(deviation_colors(np.linspace(-span, span, 401), limit_mm) / 255.0, name="deviation")
    norm = Normalize(vmin=-span, vmax=span)
    rgb = deviation_colors(d, limit_mm) / 255.0
    dot = float(np.clip(20_000.0 / max(idx.size, 1), 0.5, 6.0))     # a small scan's points stay visible
    fig, axes = plt.subplots(1, 3, figsize=(15, 5.4), constrained_layout=True)
    for ax, (h, v, name) in zip(axes, ((0, 1, "top (from +Z)"), (0, 2, "front (from -Y)"), (1, 2, "side (from +X)"))):
        order = np.argsort(p[:, 3 - h - v]) if name.startswith("top") else np.argsort(
            -p[:, 1] if name.startswith("front") else p[:, 0])
        ax.scatter(p[order, h], p[order, v], c=rgb[order], s=dot, linewidths=0)
        ax.set_aspect("equal")
        ax.set_title(name)
        ax.set_xlabel("XYZ"[h] + " (mm)")
        ax.set_ylabel("XYZ"[v] + " (mm)")
    bar = fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), ax=axes, shrink=0.8)
    bar.set_label("deviation, mm (+ material left, - cut below)")
    fig.suptitle((title or "deviation of the simulated result from the scan")
                 + f"\ngreen: within +-{limit_mm:.3g} mm; blue: material left; red: cut below the scan; "
                   "grey: not measured")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def render_unmachined_png(path, points: np.ndarray, unmachined: np.ndarray, title: str = "") -> None:
    """Three orthographic views (top, front, side) of the scan: the points no kept finishing move
    reaches (``unmachined``: input point indices) in red over the others in grey (issue 16: what the
    guard cut out, shown)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = points.shape[0]
    mask = np.zeros(n, dtype=bool)
    mask[np.asarray(unmachined, dtype=np.int64)] = True
    idx = np.arange(n) if n <= PNG_MAX_POINTS else np.sort(
        np.random.default_rng(0).choice(n, PNG_MAX_POINTS, replace=False))
    idx = np.union1d(idx, np.flatnonzero(mask)[:PNG_MAX_POINTS])
    p, m = points[idx], mask[idx]
    fig, axes = plt.subplots(1, 3, figsize=(15, 5.4), constrained_layout=True)
    for ax, (h, v, name) in zip(axes, ((0, 1, "top (from +Z)"), (0, 2, "front (from -Y)"), (1, 2, "side (from +X)"))):
        ax.scatter(p[~m, h], p[~m, v], c=[(0.75, 0.75, 0.75)], s=0.4, linewidths=0)
        ax.scatter(p[m, h], p[m, v], c=[(0.86, 0.12, 0.12)], s=1.5, linewidths=0)
        ax.set_aspect("equal")
        ax.set_title(name)
        ax.set_xlabel("XYZ"[h] + " (mm)")
        ax.set_ylabel("XYZ"[v] + " (mm)")
    fig.suptitle(title or f"unmachined scan points (red): {int(mask.sum())} of {n}")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
