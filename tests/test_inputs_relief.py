"""Images read as reliefs (Sood 2015 ch. 3): one point per pixel, intensity -> height, pixel grid -> faces.

Expected heights are computed by hand from the thesis' formulas (eq. 3.1 luminance, eq. 3.3 mapping);
the blur is compared with scipy's convolution by the 3x3 / 5x5 Gaussian (binomial) kernels."""

from __future__ import annotations

import numpy as np
import pytest
from mesh_files import image_bytes
from scipy import ndimage

from planning.errors import InputError, ParameterError
from planning.inputs.cloud import read_cloud, read_input
from planning.inputs.relief import gaussian_blur, luminance, relief_from_intensity
from schemas.params import InputParams, ReliefParams, parse_config


def relief(**kw) -> ReliefParams:
    return ReliefParams(**kw)


def heights(cloud, shape) -> np.ndarray:
    """Z per pixel as an image (row 0 at the top)."""
    return cloud.points[:, 2].reshape(shape)


def test_known_gray_pixels_give_known_heights():
    img = np.array([[0, 51, 102], [153, 204, 255]], dtype=np.uint8)
    cloud = read_cloud(image_bytes(img), min_points=4, relief=relief(z_min_mm=2.0, z_max_mm=7.0))
    assert cloud.source_format == "image-png" and cloud.normals is None
    np.testing.assert_allclose(heights(cloud, img.shape), 2.0 + img / 255.0 * 5.0, atol=1e-12)


def test_the_intensity_range_is_stretched_onto_z_range():
    img = np.array([[100, 110], [120, 140]], dtype=np.uint8)        # I_min 100, I_max 140 (eq. 3.3)
    cloud = read_cloud(image_bytes(img), min_points=4, relief=relief(z_min_mm=0.0, z_max_mm=4.0))
    np.testing.assert_allclose(heights(cloud, img.shape), [[0.0, 1.0], [2.0, 4.0]], atol=1e-12)
    flat = read_cloud(image_bytes(np.full((3, 4), 77, np.uint8)), min_points=4)
    assert np.all(flat.points[:, 2] == 0.0)                          # a uniform image lies at z_min


def test_colour_pixels_by_the_luminance_formula():
    rgb = np.array([[[0, 0, 0], [255, 0, 0], [0, 255, 0]],
                    [[0, 0, 255], [255, 255, 255], [10, 200, 60]]], dtype=np.uint8)
    cloud = read_cloud(image_bytes(rgb), min_points=4, relief=relief(z_min_mm=0.0, z_max_mm=10.0))
    y = 0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]
    np.testing.assert_allclose(heights(cloud, y.shape), y / 255.0 * 10.0, atol=1e-9)
    np.testing.assert_allclose(heights(cloud, y.shape)[0, 1:], [2.99, 5.87], atol=1e-9)
    np.testing.assert_allclose(luminance(rgb), y)


def test_palette_rgba_and_16_bit_images():
    rgb = np.random.default_rng(0).integers(0, 256, (6, 5, 3), dtype=np.uint8)
    y = luminance(rgb)
    expect = (y - y.min()) / (y.max() - y.min()) * 10.0
    rgba = np.dstack((rgb, np.full((6, 5), 128, np.uint8)))           # alpha ignored
    np.testing.assert_allclose(heights(read_cloud(image_bytes(rgba)), y.shape), expect, atol=1e-9)
    from PIL import Image

    pal = Image.fromarray(rgb).quantize(8)
    import io

    buf = io.BytesIO()
    pal.save(buf, format="PNG")
    expect_pal = luminance(np.asarray(pal.convert("RGB")))
    got = heights(read_cloud(buf.getvalue()), y.shape)
    np.testing.assert_allclose(got, (expect_pal - expect_pal.min()) / np.ptp(expect_pal) * 10.0, atol=1e-9)
    deep = np.array([[0, 1000], [30000, 65535]], dtype=np.uint16)     # 16-bit grayscale, used as is
    cloud = read_cloud(image_bytes(deep), min_points=4)
    np.testing.assert_allclose(heights(cloud, deep.shape), deep / 65535.0 * 10.0, atol=1e-9)


def test_dark_high_reverses_the_heights():
    img = np.array([[0, 64], [128, 255]], dtype=np.uint8)
    low = read_cloud(image_bytes(img), min_points=4, relief=relief(dark="low"))
    high = read_cloud(image_bytes(img), min_points=4, relief=relief(dark="high"))
    np.testing.assert_allclose(heights(low, img.shape), img / 255.0 * 10.0)
    np.testing.assert_allclose(heights(high, img.shape), 10.0 - img / 255.0 * 10.0)
    assert heights(high, img.shape)[0, 0] == 10.0 and heights(high, img.shape)[1, 1] == 0.0


@pytest.mark.parametrize("size", [3, 5])
def test_blur_changes_a_step_edge_as_the_gaussian_kernel_does(size):
    img = np.zeros((9, 12), dtype=np.uint8)
    img[:, 6:] = 255                                                  # a vertical step edge
    img[4, 2] = 255                                                   # and a lone bright pixel
    k1 = {3: np.array([1, 2, 1]) / 4, 5: np.array([1, 4, 6, 4, 1]) / 16}[size]
    expected_i = ndimage.convolve(img.astype(float), np.outer(k1, k1), mode="mirror")
    np.testing.assert_allclose(gaussian_blur(img, size), expected_i, atol=1e-9)
    cloud = read_cloud(image_bytes(img), relief=relief(blur=size, z_min_mm=0.0, z_max_mm=10.0))
    z = heights(cloud, img.shape)
    lo, hi = expected_i.min(), expected_i.max()
    np.testing.assert_allclose(z, (expected_i - lo) / (hi - lo) * 10.0, atol=1e-9)
    if size == 3:                                                     # by hand: the columns beside the step
        np.testing.assert_allclose(z[0, 5:7], [2.5, 7.5])
        np.testing.assert_allclose(z[0, [4, 7]], [0.0, 10.0])
    sharp = heights(read_cloud(image_bytes(img)), img.shape)
    assert set(np.unique(sharp)) == {0.0, 10.0}


def test_blur_of_a_flat_image_is_flat_and_zero_blur_is_identity():
    flat = np.full((5, 7), 42.0)
    np.testing.assert_allclose(gaussian_blur(flat, 5), flat)
    img = np.random.default_rng(1).uniform(0, 255, (5, 7))
    np.testing.assert_array_equal(gaussian_blur(img, 0), img)
    with pytest.raises(ParameterError):
        gaussian_blur(img, 4)


@pytest.mark.parametrize("rows, cols", [(20, 30), (30, 20)])
def test_size_fitting_keeps_aspect_along_the_longer_side(rows, cols):
    img = np.random.default_rng(2).integers(0, 256, (rows, cols), dtype=np.uint8)
    cloud = read_cloud(image_bytes(img), relief=relief(size_mm=58.0))
    spacing = 58.0 / (max(rows, cols) - 1)
    assert cloud.n_points == rows * cols                              # one point per pixel
    p = cloud.points
    np.testing.assert_allclose(p[:, 0].max() - p[:, 0].min(), (cols - 1) * spacing)
    np.testing.assert_allclose(p[:, 1].max() - p[:, 1].min(), (rows - 1) * spacing)
    assert max(np.ptp(p[:, 0]), np.ptp(p[:, 1])) == pytest.approx(58.0)
    # row-major from the top-left pixel, which sits at the top (largest y) of the relief
    np.testing.assert_allclose(p[0], [0.0, (rows - 1) * spacing, p[0, 2]])
    np.testing.assert_allclose(p[cols + 2, :2], [2 * spacing, (rows - 2) * spacing])


def test_pixel_grid_faces_point_up():
    img = np.random.default_rng(3).integers(0, 256, (7, 9), dtype=np.uint8)
    cloud = read_cloud(image_bytes(img))
    assert cloud.n_faces == 2 * 6 * 8 and cloud.faces.dtype == np.int64
    p, f = cloud.points, cloud.faces
    normal = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    assert np.all(normal[:, 2] > 0)                                   # counter-clockwise seen from +Z
    points, faces = relief_from_intensity(img, size_mm=8.0)
    np.testing.assert_array_equal(faces, f)
    np.testing.assert_allclose(points[:, :2], p[:, :2] * 8.0 / 100.0)


@pytest.mark.parametrize("fmt, ext, label", [("PNG", "png", "image-png"), ("JPEG", "jpg", "image-jpeg"),
                                             ("BMP", "bmp", "image-bmp"), ("TIFF", "tif", "image-tiff")])
def test_image_formats_by_name_and_by_content(tmp_path, fmt, ext, label):
    img = np.tile(np.linspace(0, 255, 16).astype(np.uint8), (12, 1))
    data = image_bytes(np.dstack([img] * 3), fmt=fmt)
    path = tmp_path / f"relief.{ext}"
    path.write_bytes(data)
    for source in (path, data):
        cloud = read_cloud(source)
        assert cloud.source_format == label and cloud.n_points == 12 * 16
    if fmt != "JPEG":                                                 # lossless: exact heights
        np.testing.assert_allclose(heights(read_cloud(path), img.shape), img / 255.0 * 10.0, atol=1e-9)


def test_large_image_is_scaled_down_to_max_points():
    img = np.random.default_rng(4).integers(0, 256, (80, 100), dtype=np.uint8)
    cloud = read_cloud(image_bytes(img), max_points=2000, relief=relief(size_mm=50.0))
    assert 1800 <= cloud.n_points <= 2000
    width, height = np.ptp(cloud.points[:, 0]), np.ptp(cloud.points[:, 1])
    assert width == pytest.approx(50.0)
    assert height / width == pytest.approx(80 / 100, rel=0.03)        # aspect kept
    cols = round(width / (cloud.points[1, 0] - cloud.points[0, 0])) + 1
    assert cloud.n_faces == 2 * (cols - 1) * (cloud.n_points // cols - 1)
    again = read_input(image_bytes(img), InputParams(max_points=100_000), max_points=2000)
    np.testing.assert_allclose(again.points[:, :2], cloud.points[:, :2] * 2.0)   # 100 mm instead of 50


def test_units_do_not_apply_to_images_and_read_input_takes_the_relief():
    img = np.array([[0, 255, 0], [255, 0, 255]], dtype=np.uint8)
    mm = read_cloud(image_bytes(img), min_points=4)
    metres = read_cloud(image_bytes(img), min_points=4, units="m")
    np.testing.assert_array_equal(mm.points, metres.points)
    params = parse_config({"input": {"min_points": 4, "units": "in",
                                     "relief": {"size_mm": 20, "z_min_mm": -3, "z_max_mm": -1, "dark": "high"}}})
    cloud = read_input(image_bytes(img), params.input)
    assert np.ptp(cloud.points[:, 0]) == pytest.approx(20.0)
    np.testing.assert_allclose(heights(cloud, img.shape), np.where(img > 0, -3.0, -1.0))


def test_relief_parameters_are_validated():
    with pytest.raises(ParameterError) as info:
        parse_config({"input": {"relief": {"z_min_mm": 5, "z_max_mm": 5}}})
    assert "input.relief" in info.value.message and "z_max_mm" in info.value.message
    for bad in ({"blur": 4}, {"dark": "dim"}, {"size_mm": 0}, {"size_mm": -10}, {"unknown": 1}):
        with pytest.raises(ParameterError) as info:
            parse_config({"input": {"relief": bad}})
        assert "input.relief" in info.value.message
    defaults = parse_config({}).input.relief
    assert (defaults.size_mm, defaults.z_min_mm, defaults.z_max_mm, defaults.dark, defaults.blur) == \
        (100.0, 0.0, 10.0, "low", 0)


def test_broken_images(tmp_path):
    good = image_bytes(np.random.default_rng(5).integers(0, 256, (40, 50, 3), dtype=np.uint8))
    path = tmp_path / "photo.png"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"not an image at all" * 20)
    err = pytest.raises(InputError, read_cloud, path).value
    assert err.code in ("unreadable_file", "truncated_file") and "photo.png" in err.message
    path.write_bytes(good[: len(good) // 2])
    err = pytest.raises(InputError, read_cloud, path).value
    assert err.code == "truncated_file" and "photo.png" in err.message
    path = tmp_path / "scan.jpg"
    path.write_bytes(b"plain text, no image")
    err = pytest.raises(InputError, read_cloud, path).value
    assert err.code == "unreadable_file" and "scan.jpg" in err.message
    err = pytest.raises(InputError, read_cloud, image_bytes(np.zeros((1, 40), np.uint8))).value
    assert err.code == "too_few_points"
