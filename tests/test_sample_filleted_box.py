"""The filleted_box reference sample (planning/inputs/samples/filleted.py): a 60 x 40 x 20 mm box with its
top and vertical edges rounded by 10 mm, checked against the exact surface: every point at 10 mm from
the inner box (the part shrunk by 10 mm on the sides and the top: 40 x 20 x 10 mm), normals the gradient of
that distance."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from planning.errors import ParameterError
from planning.inputs.cloud import read_cloud
from planning.inputs.samples import SAMPLES, filleted_box, filleted_box_inner_box, make_sample
from scanmill.cli import EXIT_OK, main


@pytest.fixture(scope="module")
def box():
    return filleted_box()


def _nearest_on_inner_box(s):
    lo, hi = (np.asarray(c) for c in s.meta["inner_box_mm"])
    return np.clip(s.points, lo, hi)


def test_dimensions_frame_and_meta(box):
    m = box.meta
    assert box.name == "filleted_box" and m["size_mm"] == (60.0, 40.0, 20.0) and m["fillet_radius_mm"] == 10.0
    assert m["inner_box_mm"] == ((-20.0, -10.0, 0.0), (20.0, 10.0, 10.0))
    assert filleted_box_inner_box() == m["inner_box_mm"]
    lo, hi = box.points.min(axis=0), box.points.max(axis=0)
    assert np.allclose(hi - lo, [60.0, 40.0, 20.0], atol=0.05)         # sampled extent
    assert np.all(hi <= [30.0, 20.0, 20.0]) and np.all(lo >= [-30.0, -20.0, 0.0])
    assert np.allclose(lo[:2], -hi[:2], atol=0.05)                        # centred in x and y
    assert box.points[:, 2].min() >= 0.0                                  # nothing below the table
    assert box.points.dtype == np.float64 and box.normals.shape == box.points.shape
    # the bottom rests on the fixture: not scanned, as with the other samples
    assert "bottom" not in {m["label_names"][k] for k in np.unique(m["labels"])}
    assert np.all(box.normals[:, 2] > -1e-12)
    # the analytic area: top 40x20, flat sides, quarter cylinders, four sphere octants
    area = 800 + 2 * (20 + 40) * 10 + 4 * 5 * np.pi * 10 + 5 * np.pi * 120 + 2 * np.pi * 100
    assert m["area_mm2"] == pytest.approx(area)
    assert len(box.points) / area == pytest.approx(1.0, rel=0.02)          # 1 point/mm^2 by default


def test_every_point_on_the_exact_surface_with_its_exact_normal(box):
    v = box.points - _nearest_on_inner_box(box)
    dist = np.linalg.norm(v, axis=1)
    assert np.max(np.abs(dist - 10.0)) < 1e-9
    assert np.allclose(np.linalg.norm(box.normals, axis=1), 1.0, atol=1e-12)
    assert np.allclose(box.normals, v / dist[:, None], atol=1e-12)         # gradient of the distance
    assert np.all(np.einsum("ij,ij->i", box.normals, box.points - [0.0, 0.0, 5.0]) > 0)   # outward


def _label(s, name):
    return s.meta["labels"] == s.meta["label_names"].index(name)


def test_patches_flat_faces_exact_and_rounded_zones(box):
    p, n = box.points, box.normals
    top = _label(box, "top")
    assert np.all(p[top, 2] == 20.0) and np.all(n[top] == [0.0, 0.0, 1.0])
    assert np.all(np.abs(p[top, 0]) <= 20.0) and np.all(np.abs(p[top, 1]) <= 10.0)
    side = _label(box, "side")
    on_x = np.abs(p[side, 0]) == 30.0
    on_y = np.abs(p[side, 1]) == 20.0
    assert np.all(on_x ^ on_y) and np.all(p[side, 2] <= 10.0)
    assert np.all(n[side][on_x] == np.column_stack((np.sign(p[side][on_x, 0]), np.zeros((on_x.sum(), 2)))))
    assert np.all(n[side][on_y, 1] == np.sign(p[side][on_y, 1])) and np.all(n[side][on_y][:, [0, 2]] == 0.0)
    inner = _nearest_on_inner_box(box)
    # each rounded patch touches the inner box on its edge / corner, as the rounded box should
    vert = _label(box, "vertical_fillet")
    assert np.all(np.abs(inner[vert, :2]) == [20.0, 10.0]) and np.all(n[vert, 2] == 0.0)
    tf = _label(box, "top_fillet")
    assert np.all(inner[tf, 2] == 10.0) and np.all((np.abs(inner[tf, 0]) == 20.0) | (np.abs(inner[tf, 1]) == 10.0))
    corner = _label(box, "corner")
    assert np.all(np.abs(inner[corner]) == [20.0, 10.0, 10.0]) and np.all(n[corner, 2] > 0.0)
    counts = {nm: int(_label(box, nm).sum()) for nm in box.meta["label_names"]}
    assert counts["corner"] == pytest.approx(4 * 50 * np.pi, rel=0.03)   # 4 octants of 50 pi mm^2
    assert counts["top"] == 800 and counts["side"] == 1200


def test_spacing_is_roughly_uniform_and_leaves_no_holes(box):
    d = cKDTree(box.points).query(box.points, k=2)[0][:, 1]
    assert 0.5 < np.median(d) < 0.8                 # jittered grid of 1 mm cells
    assert np.percentile(d, 5) > 0.2 and d.max() < 1.5
    # every patch, planar or curved, at the same density: medians within 10 % of each other
    med = [np.median(d[_label(box, nm)]) for nm in ("top", "side", "vertical_fillet", "top_fillet", "corner")]
    assert max(med) / min(med) < 1.1
    # no hole anywhere, seams included: a dense sample of the same surface lies within 1.25 mm
    probes = filleted_box(density_per_mm2=16.0, seed=7).points
    assert cKDTree(box.points).query(probes)[0].max() < 1.25


def test_deterministic_and_parametrised(box):
    again = filleted_box()
    assert np.array_equal(again.points, box.points) and np.array_equal(again.normals, box.normals)
    assert not np.array_equal(filleted_box(seed=1).points, box.points)
    assert len(make_sample("filleted_box", n_points=2000).points) == pytest.approx(2000, rel=0.03)
    noisy = filleted_box(noise_mm=0.05)
    off = np.einsum("ij,ij->i", noisy.points - box.points, box.normals)
    assert np.array_equal(noisy.normals, box.normals) and 0.04 < off.std() < 0.06


def test_other_sizes_and_the_bottom():
    s = filleted_box(size_mm=(50.0, 30.0, 25.0), fillet_radius_mm=5.0, density_per_mm2=2.0, seed=3)
    v = s.points - _nearest_on_inner_box(s)
    assert np.max(np.abs(np.linalg.norm(v, axis=1) - 5.0)) < 1e-9
    assert np.allclose(s.normals, v / 5.0, atol=1e-12)
    b = filleted_box(include_bottom=True)
    bottom = _label(b, "bottom")
    assert bottom.any() and np.all(b.points[bottom, 2] == 0.0) and np.all(b.normals[bottom] == [0.0, 0.0, -1.0])
    xy = b.points[bottom, :2]
    out = np.maximum(np.abs(xy) - [20.0, 10.0], 0.0)
    assert np.all(np.linalg.norm(out, axis=1) < 10.0)            # inside the rounded footprint
    assert bottom.sum() == pytest.approx(2400 - (4 - np.pi) * 100, rel=0.03)


@pytest.mark.parametrize("kwargs", [{"fillet_radius_mm": 0.0}, {"fillet_radius_mm": 21.0},
                                    {"size_mm": (60, 40)}, {"density_per_mm2": 0.0}, {"noise_mm": -1.0}])
def test_rejects_bad_arguments(kwargs):
    with pytest.raises(ParameterError) as e:
        filleted_box(**kwargs)
    assert next(iter(kwargs)) in str(e.value)


def test_registered_and_written_by_the_cli(tmp_path, capsys):
    assert SAMPLES["filleted_box"] is filleted_box
    out = tmp_path / "x.ply"
    assert main(["sample", "filleted_box", "--out", str(out)]) == EXIT_OK
    assert "filleted_box" in capsys.readouterr().out
    cloud = read_cloud(out)
    ref = filleted_box()
    assert cloud.points.shape == ref.points.shape
    assert np.allclose(cloud.points, ref.points, atol=1e-5)
    assert cloud.normals is not None and np.allclose(cloud.normals, ref.normals, atol=1e-5)
