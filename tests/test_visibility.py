"""Tool visibility (cone) against an independent per-pair angle computation."""

import numpy as np
import pytest

from planning.errors import ParameterError
from planning.visibility.cone import cone_visibility


def _unit(a):
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def test_cone_matches_angle_brute_force():
    rng = np.random.default_rng(3)
    normals = _unit(rng.normal(size=(500, 3)))
    axes = _unit(rng.normal(size=(37, 3)))
    vis = cone_visibility(normals, axes, (10, 60), chunk_rows=64)
    ref = np.zeros_like(vis)
    for i in range(len(normals)):
        for j in range(len(axes)):
            ang = np.degrees(np.arccos(np.clip(np.dot(normals[i], axes[j]), -1, 1)))
            ref[i, j] = 10 <= ang <= 60
    # Pairs within 1e-6 deg of a boundary may go either way numerically; none occur with this seed.
    assert np.array_equal(vis, ref)
    assert vis.any() and not vis.all()


def test_boundaries_are_inclusive():
    ax = np.array([[0.0, 0.0, 1.0]])
    angles = np.radians([10.0, 80.0, 9.9, 80.1, 0.0, 45.0])
    normals = np.stack([np.sin(angles), np.zeros_like(angles), np.cos(angles)], axis=1)
    assert cone_visibility(normals, ax, (10, 80))[:, 0].tolist() == [True, True, False, False, False, True]


def test_bad_cone():
    with pytest.raises(ParameterError, match="cone_deg"):
        cone_visibility(np.eye(3), np.eye(3), (50, 20))
