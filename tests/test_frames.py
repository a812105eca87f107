"""Per-area frames (planning.toolpath.frames)."""

from __future__ import annotations

import numpy as np
import pytest

from planning.errors import ParameterError
from planning.toolpath.frames import area_frame


@pytest.mark.parametrize("seed", range(5))
def test_frame_is_right_handed_with_the_axis_as_z(seed):
    rng = np.random.default_rng(seed)
    t = rng.normal(size=3)
    cloud = rng.normal(size=(500, 3)) * [30, 10, 5]
    f = area_frame(t, cloud, cloud[:200])
    R = f.rotation
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    assert np.allclose(R[2], t / np.linalg.norm(t))
    q = f.to_frame(cloud)
    assert np.allclose(f.to_part(q), cloud, atol=1e-9)
    assert q[:, 2].max() == pytest.approx(0.0, abs=1e-9)          # origin at the cloud's top along z
    # the tool axis maps to +Z
    assert np.allclose(f.to_frame(f.origin_mm + 5 * R[2]), [0, 0, 5])


def test_x_runs_along_the_longer_side_and_origin_centres_the_footprint():
    # a 60 x 10 mm rectangle in a plane tilted about X, seen along its normal
    rng = np.random.default_rng(1)
    uv = rng.uniform([-30, -5], [30, 5], size=(2000, 2)) + [7, 3]
    a = np.radians(30)
    n = np.array([0, -np.sin(a), np.cos(a)])
    e1 = np.array([1.0, 0, 0])
    e2 = np.cross(n, e1)
    pts = uv[:, :1] * e1 + uv[:, 1:] * e2
    f = area_frame(n, pts)
    assert abs(f.rotation[0] @ e1) > 0.999 and f.rotation[0][0] > 0
    q = f.to_frame(pts)
    assert 0.5 * (q[:, 0].min() + q[:, 0].max()) == pytest.approx(0, abs=1e-9)
    assert 0.5 * (q[:, 1].min() + q[:, 1].max()) == pytest.approx(0, abs=1e-9)
    assert np.ptp(q[:, 0]) > 5 * np.ptp(q[:, 1])


def test_bad_input():
    with pytest.raises(ParameterError):
        area_frame([0, 0, 0], np.zeros((3, 3)))
    with pytest.raises(ParameterError):
        area_frame([0, 0, 1], np.zeros((0, 3)))
    f = area_frame([1, 0, 0], np.array([[1.0, 2.0, 3.0]]))     # one point: X is part +Y projected
    assert np.allclose(f.rotation[0], [0, 1, 0])
