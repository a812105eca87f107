"""Area labelling: single-visibility points, overlap split at the cone middle, leftovers by distance."""

import numpy as np

from planning.areas.assign import assign_areas
from schemas.params import AreasParams

PER_POINT = AreasParams(method="per_point")


def test_rules_on_a_hand_made_case():
    # five sampled points along x; a sixth input point duplicates none and sits near point 4
    points = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [10, 0, 0], [10.2, 0, 0]], float)
    sample_index = np.array([0, 1, 2, 3, 4])
    up = np.array([0, 0, 1.0])
    tilt30 = np.array([np.sin(np.radians(30)), 0, np.cos(np.radians(30))])
    tilt60 = np.array([np.sin(np.radians(60)), 0, np.cos(np.radians(60))])
    normals = np.array([up, up, up, up, up])
    axes = np.array([tilt30, tilt60])
    vis = np.array([[1, 0], [0, 1], [1, 1], [0, 0], [0, 0]], bool)
    a = assign_areas(points, sample_index, normals, vis, np.array([0, 1]), axes, cone_deg=(10, 80), params=PER_POINT)
    # point 2 is seen by both: angles 30 and 60 are both 15 from the middle 45 -> tie -> lowest id
    assert a.labels.tolist()[:3] == [0, 1, 0]
    assert a.overlap.tolist() == [False, False, True, False, False]
    # leftovers 3 and 4: nearest labelled point is 2 (label 0) for both
    assert a.integrated.tolist() == [False, False, False, True, True]
    assert a.labels[3] == 0 and a.labels[4] == 0
    # input point 5 takes its nearest sampled point's label (point 4)
    assert a.input_labels.tolist() == [0, 1, 0, 0, 0, 0]


def test_overlap_goes_to_the_axis_nearest_the_cone_middle():
    points = np.zeros((1, 3))
    normals = np.array([[0, 0, 1.0]])
    a20 = np.array([np.sin(np.radians(20)), 0, np.cos(np.radians(20))])
    a40 = np.array([np.sin(np.radians(40)), 0, np.cos(np.radians(40))])
    a = assign_areas(points, np.array([0]), normals, np.array([[True, True]]), np.array([0, 1]),
                     np.array([a20, a40]), cone_deg=(10, 80), params=PER_POINT)
    assert a.labels.tolist() == [1]


def test_leftovers_match_brute_force_nearest():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 100, size=(400, 3))
    sample_index = np.arange(0, 400, 2)
    normals = np.tile([0, 0, 1.0], (200, 1))
    vis = rng.random((200, 3)) < 0.3
    axes = np.array([[0, 0.3, 0.95], [0.3, 0, 0.95], [-0.3, 0, 0.95]])
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    a = assign_areas(pts, sample_index, normals, vis, np.array([0, 1, 2]), axes, params=PER_POINT)
    seen = vis.any(axis=1)
    sp = pts[sample_index]
    for i in np.flatnonzero(~seen):
        d = np.linalg.norm(sp[seen] - sp[i], axis=1)
        assert a.labels[i] == a.labels[np.flatnonzero(seen)[np.argmin(d)]]
    for i in range(400):
        d = np.linalg.norm(sp - pts[i], axis=1)
        assert a.input_labels[i] == a.labels[np.argmin(d)]


def test_no_setup_chosen_labels_everything_uncovered():
    # select_setups returns no axis when none is kept (e.g. nothing visible): nothing is machined
    pts = np.random.default_rng(1).uniform(0, 10, size=(8, 3))
    normals = np.tile([0, 0, 1.0], (4, 1))
    a = assign_areas(pts, np.arange(4), normals, np.zeros((4, 3), bool), np.zeros(0, np.int64),
                     np.zeros((0, 3)))
    assert a.labels.tolist() == [-1] * 4 and a.input_labels.tolist() == [-1] * 8
    assert a.integrated.all() and not a.overlap.any()
