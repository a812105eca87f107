"""Tests of planning.report.preview: segmentation colours and the PNG preview."""

from __future__ import annotations

import os

import matplotlib.image as mpimg
import numpy as np
import pytest

from planning.errors import ParameterError
from planning.report import preview
from planning.report.preview import (
    UNCOVERED_COLOR,
    area_colors,
    point_colors,
    render_preview,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def labelled_dome(n: int = 1500, seed: int = 0):
    """A half ellipsoid (mm) split among three tool axes, some points uncovered or integrated."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    pts = v * np.array([40.0, 30.0, 20.0]) + np.array([5.0, -3.0, 0.0])
    axes = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, -0.6, 0.8]])
    score = v @ axes.T
    labels = np.argmax(score, axis=1)
    labels[score.max(axis=1) < 0.4] = -1
    integrated = rng.random(n) < 0.05
    integrated[labels < 0] = False
    return pts, labels, axes, integrated


def test_area_colors_distinct_and_deterministic():
    for k in (0, 1, 5, 12, 13, 40):
        colors = area_colors(k)
        assert colors.shape == (k, 3) and colors.dtype == np.uint8
        assert len({tuple(c) for c in colors}) == k
        assert not any(np.array_equal(c, UNCOVERED_COLOR) for c in colors)
        np.testing.assert_array_equal(colors, area_colors(k))
    np.testing.assert_array_equal(area_colors(40)[:5], area_colors(5))     # stable prefix
    assert UNCOVERED_COLOR.shape == (3,) and UNCOVERED_COLOR.dtype == np.uint8
    with pytest.raises(ParameterError):
        area_colors(-1)


def test_point_colors_use_uncovered_for_minus_one():
    colors = point_colors(np.array([0, -1, 2, 1]), 3)
    np.testing.assert_array_equal(colors[1], UNCOVERED_COLOR)
    np.testing.assert_array_equal(colors[[0, 2, 3]], area_colors(3)[[0, 2, 1]])


def test_render_preview_writes_a_real_png(tmp_path):
    pts, labels, axes, integrated = labelled_dome()
    path = tmp_path / "preview.png"
    render_preview(path, pts, labels, axes, integrated=integrated, title="dome", dpi=60)
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC and len(data) > 1000
    image = mpimg.imread(str(path))
    assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100
    assert float(image[..., :3].std()) > 0.01                              # not uniform
    rgb = np.round(image[..., :3] * 255).astype(int).reshape(-1, 3)
    for color in area_colors(3):                                           # every area drawn
        assert np.any(np.all(np.abs(rgb - color) <= 2, axis=1)), color
    assert os.listdir(tmp_path) == ["preview.png"]                         # no temp left


def test_render_preview_is_deterministic_when_subsampling(tmp_path):
    pts, labels, axes, integrated = labelled_dome(3000)
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    for path in (a, b):
        render_preview(path, pts, labels, axes, integrated=integrated, max_points=500, dpi=40)
    assert a.read_bytes() == b.read_bytes()


def test_render_preview_without_setups_and_closes_figures(tmp_path):
    import matplotlib.pyplot as plt

    before = plt.get_fignums()
    pts, _, _, _ = labelled_dome(300)
    render_preview(tmp_path / "none.png", pts, np.full(300, -1), np.zeros((0, 3)), dpi=40)
    assert (tmp_path / "none.png").read_bytes()[:8] == PNG_MAGIC
    assert plt.get_fignums() == before


def test_render_preview_rejects_bad_inputs(tmp_path):
    pts, labels, axes, _ = labelled_dome(200)
    with pytest.raises(ParameterError):
        render_preview(tmp_path / "x.png", pts, labels[:-1], axes)
    with pytest.raises(ParameterError):
        render_preview(tmp_path / "x.png", pts, np.full(200, 3), axes)      # label >= k
    with pytest.raises(ParameterError):
        render_preview(tmp_path / "x.png", pts, labels, axes, integrated=np.ones(5, bool))
    assert os.listdir(tmp_path) == []


# --------------------------------------------------------------------------------------------
# every point drawn (rasterised), legend angles, set-up numbers clear of the arrows
# --------------------------------------------------------------------------------------------

def png_rgb(path) -> np.ndarray:
    """``(H, W, 3)`` uint8 pixels of a PNG."""
    return np.round(mpimg.imread(str(path))[..., :3] * 255).astype(int)


def sphere_points(n: int, centre, radius: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    return np.asarray(centre, dtype=float) + radius * v / np.linalg.norm(v, axis=1, keepdims=True)


def color_near(rgb: np.ndarray, fig, ax, view, point, color, reach: int = 2) -> bool:
    """Whether ``color`` (within 2 per channel) is at ``point``'s pixel in ``ax`` (+- reach px)."""
    x, y = ax.transData.transform(view.basis[:2] @ np.asarray(point, dtype=float))
    col, row = int(x), int(fig.bbox.height - y)
    window = rgb[row - reach:row + reach + 1, col - reach:col + reach + 1].reshape(-1, 3)
    return bool(np.any(np.all(np.abs(window - np.asarray(color, dtype=int)) <= 2, axis=1)))


def test_every_point_is_drawn_in_its_colour_in_every_view(tmp_path):
    """Two dense clusters and single points of their own labels (one uncovered, one integrated):
    each shows its colour where it projects, in all four panels."""
    a = sphere_points(20_000, (-60.0, 25.0, 20.0), 8.0, seed=1)
    b = sphere_points(20_000, (60.0, -25.0, -20.0), 8.0, seed=2)
    singles = np.array([[30.0, 40.0, 30.0], [20.0, 35.0, -30.0], [-30.0, -35.0, -30.0],
                        [0.0, 45.0, -35.0], [-35.0, 45.0, 35.0]])
    pts = np.vstack([a, b, singles])
    labels = np.concatenate([np.zeros(len(a), int), np.ones(len(b), int), [2, 2, 2, -1, 1]])
    integrated = np.zeros(len(pts), bool)
    integrated[-1] = True
    axes = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, -0.6, 0.8]])
    colors = area_colors(3)
    dark_1 = np.round(preview._INTEGRATED_SHADE * colors[1].astype(float))
    expected = [((-60.0, 25.0, 20.0), colors[0]), ((60.0, -25.0, -20.0), colors[1])]
    expected += [(p, colors[2]) for p in singles[:3]]
    expected += [(singles[3], UNCOVERED_COLOR), (singles[4], dark_1)]

    path = tmp_path / "p.png"
    render_preview(path, pts, labels, axes, integrated=integrated, dpi=60)
    rgb = png_rgb(path)
    fig = preview._build_figure(pts, labels, axes, integrated=integrated, dpi=60)
    assert rgb.shape[:2] == (fig.bbox.height, fig.bbox.width)
    for ax, view in zip(fig.axes, preview._VIEWS):
        for point, color in expected:
            assert color_near(rgb, fig, ax, view, point, color), (view.name, point, color)
    # a cluster's colour is not drawn where a single point of another label lies
    ax, view = fig.axes[1], preview._VIEWS[1]
    assert not color_near(rgb, fig, ax, view, singles[0], colors[0], reach=1)


def test_a_lone_point_among_more_than_the_old_cap_is_drawn(tmp_path):
    """200,000 points (the old preview drew a 60,000 subsample): the single point of a rare
    label placed apart shows its colour in every panel; with max_points it may vanish."""
    sphere = sphere_points(200_000, (0.0, 0.0, 0.0), 20.0, seed=3)
    lone = np.array([[30.0, 30.0, 30.0]])
    pts = np.vstack([sphere, lone])
    labels = np.concatenate([(sphere[:, 0] > 0).astype(int), [2]])
    axes = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    rare = area_colors(3)[2]
    path = tmp_path / "p.png"
    render_preview(path, pts, labels, axes, dpi=60)
    rgb = png_rgb(path)
    fig = preview._build_figure(pts, labels, axes, dpi=60)
    for ax, view in zip(fig.axes, preview._VIEWS):
        assert color_near(rgb, fig, ax, view, lone[0], rare), view.name
    assert "showing" not in fig.texts[0].get_text()                   # the title: all drawn
    capped = preview._build_figure(pts, labels, axes, max_points=1000, dpi=40)
    assert "(showing 1,000)" in capped.texts[0].get_text()


def test_legend_gives_each_setups_machine_angles(tmp_path):
    pts, labels, axes, integrated = labelled_dome(600)
    angles = [{"B": 0.0, "C": 0.0}, {"B": 90.0, "C": -90.0}, {"C": -120.0, "B": 36.86989765}]
    fig = preview._build_figure(pts, labels, axes, integrated=integrated, angles=angles, dpi=40)
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    n2 = int(np.sum(labels == 2))
    assert texts[2] == f"area 2: C -120.000° B 36.870°, axis (0.000, -0.600, 0.800), {n2:,} input pts"
    assert texts[1].startswith("area 1: B 90.000° C -90.000°, axis (1.000, 0.000, 0.000), ")
    assert texts[0].startswith("area 0: B 0.000° C 0.000°, axis")
    plain = preview._build_figure(pts, labels, axes, integrated=integrated, dpi=40)
    plain_texts = [t.get_text() for t in plain.legends[0].get_texts()]
    assert plain_texts[2] == f"area 2: axis (0.000, -0.600, 0.800), {n2:,} input pts"
    assert not any("°" in t for t in plain_texts)
    render_preview(tmp_path / "a.png", pts, labels, axes, integrated=integrated, angles=angles,
                   dpi=40)
    assert (tmp_path / "a.png").read_bytes()[:8] == PNG_MAGIC


@pytest.mark.parametrize("angles", [
    [{"B": 1.0, "C": 2.0}] * 2,                              # one short
    [{"B": 1.0}] * 4,                                        # one too many
    [{"B": 1.0}, {"B": 2.0}, (3.0, 4.0)],                    # not a mapping
    [{"B": 1.0}, {"B": 2.0}, {"B": float("nan")}],           # not finite
    [{"B": 1.0}, {"B": 2.0}, {"B": "35"}],                   # not a number
    [{"B": 1.0}, {"B": 2.0}, {3: 1.0}],                      # name not a str
    {"B": 1.0, "C": 2.0},                                    # not a sequence of mappings
])
def test_render_preview_rejects_bad_angles(tmp_path, angles):
    pts, labels, axes, _ = labelled_dome(200)
    with pytest.raises(ParameterError) as err:
        render_preview(tmp_path / "x.png", pts, labels, axes, angles=angles)
    assert err.value.details["parameter"] == "angles"
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("max_points", [0, -5, 2.5, True])
def test_render_preview_rejects_bad_max_points(tmp_path, max_points):
    pts, labels, axes, _ = labelled_dome(200)
    with pytest.raises(ParameterError):
        render_preview(tmp_path / "x.png", pts, labels, axes, max_points=max_points)
    assert os.listdir(tmp_path) == []


def test_render_preview_of_all_points_is_deterministic(tmp_path):
    pts, labels, axes, integrated = labelled_dome(20_000, seed=4)
    angles = [{"A": float(i), "C": -float(i)} for i in range(3)]
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    for path in (a, b):
        render_preview(path, pts, labels, axes, integrated=integrated, angles=angles, dpi=40)
    assert a.read_bytes() == b.read_bytes()


def segment_meets_box(p0, p1, bbox, samples: int = 2000) -> bool:
    """Whether the display segment p0-p1 has a point inside ``bbox`` (dense sampling)."""
    t = np.linspace(0.0, 1.0, samples)[:, None]
    q = (1.0 - t) * np.asarray(p0) + t * np.asarray(p1)
    return bool(np.any((q[:, 0] >= bbox.x0) & (q[:, 0] <= bbox.x1) & (q[:, 1] >= bbox.y0)
                       & (q[:, 1] <= bbox.y1)))


def test_setup_numbers_clear_every_arrow_and_each_other():
    """Seven axes, near-parallel pairs among them and some along a panel's line of sight: in
    every panel no number's box meets an arrow's shaft (centroid to tip) or another number, and
    each number stays next to its own arrow's tip (or end-on symbol)."""
    pts, labels, _, _ = labelled_dome(3000, seed=5)
    axes = np.array([
        [0.0, 0.0, 1.0],            # end-on in the top view
        [1.0, 0.0, 0.05],           # end-on in the side view ...
        [0.9, 0.1, 0.42],           # ... and nearly parallel to 1 and 3 in the top view
        [0.97, -0.05, 0.24],
        [0.0, -1.0, 0.05],          # end-on in the front view
        [-0.6, 0.2, 0.77],
        preview._VIEWS[0].towards,  # end-on in the isometric view
    ])
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    labels = labels % len(axes)
    fig = preview._build_figure(pts, labels, axes, dpi=80)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    centroid = pts.mean(axis=0)
    arrow_mm = 0.6 * float(np.ptp(pts, axis=0).max())
    end_on_seen = 0
    for ax, view in zip(fig.axes, preview._VIEWS):
        texts = {t.get_gid(): t for t in ax.texts
                 if (t.get_gid() or "").startswith("setup-label-")}
        assert sorted(texts) == sorted(f"setup-label-{i}" for i in range(len(axes)))
        boxes = [texts[f"setup-label-{i}"].get_window_extent(renderer) for i in range(len(axes))]
        start = view.basis[:2] @ centroid
        tips = start + arrow_mm * axes @ view.basis[:2].T
        end_on = np.hypot(*(axes @ view.basis[:2].T).T) < 0.08      # drawn as a symbol
        end_on_seen += int(end_on.sum())
        ends = [ax.transData.transform(np.vstack([start, start if e else tip]))
                for tip, e in zip(tips, end_on)]
        for i, box in enumerate(boxes):
            for j, (p0, p1) in enumerate(ends):
                assert not segment_meets_box(p0, p1, box), (view.name, i, j)
            for k in range(i):
                assert not box.overlaps(boxes[k]), (view.name, i, k)
            anchor = ends[i][1]
            assert np.hypot(box.x0 + box.width / 2 - anchor[0],
                            box.y0 + box.height / 2 - anchor[1]) < 80, (view.name, i)
    assert end_on_seen == 4


@pytest.mark.parametrize("upper_first", [True, False])
def test_the_point_nearest_the_viewer_wins_its_pixel(tmp_path, upper_first):
    """Two stacked sheets of different labels: seen from +Z (top and isometric panels) only the
    upper one shows, whichever comes first in the input."""
    g = np.linspace(-20.0, 20.0, 120)
    x, y = (c.ravel() for c in np.meshgrid(g, g))
    upper = np.column_stack([x, y, np.full_like(x, 10.0)])
    lower = np.column_stack([x, y, np.full_like(x, -10.0)])
    pts = np.vstack([upper, lower] if upper_first else [lower, upper])
    labels = np.repeat([0, 1] if upper_first else [1, 0], len(x))
    axes = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    colors = area_colors(2)
    path = tmp_path / "p.png"
    render_preview(path, pts, labels, axes, dpi=60)
    rgb = png_rgb(path)
    fig = preview._build_figure(pts, labels, axes, dpi=60)
    for slot in (0, 1):                                               # isometric, top
        ax, view = fig.axes[slot], preview._VIEWS[slot]
        for corner in ((-15.0, -15.0), (15.0, -15.0), (-15.0, 15.0), (15.0, 15.0)):
            point = (*corner, 10.0)
            assert color_near(rgb, fig, ax, view, point, colors[0], reach=0), (view.name, corner)
            assert not color_near(rgb, fig, ax, view, point, colors[1], reach=3), view.name


def test_a_long_title_wraps_inside_the_picture():
    """Issue 34: the plan's message as the title ran off both sides of preview.png."""
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(500, 3)) * 20
    labels = (pts[:, 0] > 0).astype(int)
    axes = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    message = ("no 5 set-ups reach 95 % coverage; the best 5 set-ups cover 93.9 %: fixtures.placement=auto reaches "
               "it with the part principal axis 1 down, scan direction (+1.00, -0.04, +0.02) down: 5 set-ups cover "
               "95.0 %; run: scanmill plan part.ply --out plan/ --set fixtures.placement=auto ") * 2
    fig = preview._build_figure(pts, labels, axes, title=message, dpi=60)
    fig.canvas.draw()
    box = fig.texts[0].get_window_extent(fig.canvas.get_renderer())
    assert box.x0 >= 0 and box.x1 <= fig.bbox.width and box.y1 <= fig.bbox.height
    words = fig.texts[0].get_text().split()
    assert words[:6] == message.split()[:6] and len(fig.texts[0].get_text().splitlines()) <= 4
