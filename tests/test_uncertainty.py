"""The uncertainty box (docs/conventions.md#uncertainty-box): its samples stay inside it and cover it,
bad boxes are refused before anything compiles, and a model identity builds the robot it names."""
import numpy as np
import pytest

from jaxflex.model_sets import build_model, model_set, models_of
from jaxflex.uncertainty import ModelId
from jaxflex.robot import cycle_preset, robot_preset
from jaxflex.uncertainty import Box


def test_random_models_fill_the_box_reproducibly():
    box = Box()
    ids = box.random([6.0], n=400, seed=3)
    assert ids == box.random([6.0], n=400, seed=3) and ids != box.random([6.0], n=400, seed=4)
    a = np.asarray([[i.stiffness_scale, i.payload_scale, i.damping_ratio, i.l1_delta, i.l2_delta, i.rotor_scale]
                    for i in ids])
    lo = np.array([0.95, 0.9, 0.0, -5e-4, -5e-4, 0.9])
    hi = np.array([1.05, 1.1, 0.01, 5e-4, 5e-4, 1.1])
    assert np.all(a >= lo) and np.all(a <= hi)
    # uniform: with 400 samples every factor comes within 2 % of the box width of both faces
    # (probability of missing one face ~ 0.98^400 ~ 3e-4 per face, fixed by the seed anyway)
    np.testing.assert_allclose(a.min(axis=0), lo, atol=0.02 * (hi - lo).max())
    assert np.all(a.min(axis=0) - lo <= 0.02 * (hi - lo)) and np.all(hi - a.max(axis=0) <= 0.02 * (hi - lo))


def test_grid_and_corners():
    box = Box()
    grid = box.grid([6.0, 0.1], points=3)
    # the 3 x 3 grid is the study's perturbed set (E outer, payload inner), per payload
    expected = model_set(robot_preset("default"), [6.0, 0.1], stiffness=(0.95, 1.0, 1.05),
                         payload_scale=(0.9, 1.0, 1.1)).ids
    assert [(i.payload, i.stiffness_scale, i.payload_scale) for i in grid] == \
        [(i.payload, pytest.approx(i.stiffness_scale), pytest.approx(i.payload_scale)) for i in expected]
    assert ModelId(6.0) in grid and ModelId(0.1) in grid
    corners = box.corners([6.0])
    assert len(corners) == 32 and len(set(corners)) == 32
    assert len(Box(damping=(0.0, 0.0)).corners([6.0])) == 16       # a degenerate axis is not doubled


@pytest.mark.parametrize("kw, name", [(dict(young=-0.1), "young"), (dict(payload=1.0), "payload"),
                                      (dict(damping=(0.02, 0.01)), "damping"), (dict(damping=0.01), "damping"),
                                      (dict(length=float("nan")), "length"), (dict(rotor=float("inf")), "rotor")])
def test_bad_boxes_are_refused(kw, name):
    with pytest.raises(ValueError, match=name):
        Box(**kw).checked()


def test_model_identity_builds_its_robot():
    robot = robot_preset("default", rotor_inertia=1e-3)
    cycle = cycle_preset()
    mid = ModelId(6.0, 1.1, 0.95, 0.0, 3e-4, -2e-4, 1.1)
    r = models_of(robot, [mid], cycle).robots
    np.testing.assert_allclose(np.asarray(r.payload), [6.6], rtol=1e-15)
    np.testing.assert_allclose(np.asarray(r.young), [0.95 * 70e9], rtol=1e-15)
    np.testing.assert_allclose(np.asarray(r.l1), [0.24 + 3e-4], rtol=1e-15)
    np.testing.assert_allclose(np.asarray(r.l2), [0.38079 - 2e-4], rtol=1e-15)
    np.testing.assert_allclose(np.asarray(r.rotor_inertia), [1.1e-3], rtol=1e-15)
    assert ModelId(6.0).nominal and not mid.nominal
    assert ModelId(6.0).label == "6 kg x1, E x1"                  # unchanged for the old sets
    assert "l1 +0.3 mm" in mid.label and "rotor x1.1" in mid.label
    with pytest.raises(ValueError, match="cycle"):
        build_model(ModelId(6.0, damping_ratio=0.01), robot)
