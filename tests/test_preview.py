"""Tests of planning.report.preview: segmentation colours and the PNG preview."""

from __future__ import annotations

import os

import matplotlib.image as mpimg
import numpy as np
import pytest

from planning.errors import ParameterError
from planning.report.preview import UNCOVERED_COLOR, area_colors, point_colors, render_preview

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
