"""The shipped robot models (`cstorm.examples.robots`, ``cs.robots``): the registry, the
capsule inertia, and each model's joints and geoms as its docstring lists them. The
models against MuJoCo are in tests/test_hopper.py and tests/test_walker.py."""

from __future__ import annotations

import numpy as np
import pytest

import cstorm as cs
from cstorm.examples import robots


def test_registry():
    assert cs.robots is robots
    assert robots.names() == ["double_pendulum", "tumbler"]
    assert robots.get("tumbler").name == "tumbler"
    with pytest.raises(cs.ModelError, match="no shipped robot named 'nope'"):
        robots.get("nope")


def test_capsule_inertia_mass_form():
    """Given the mass instead of the density, the same capsule."""
    m, I = robots.capsule_inertia(0.02, 0.1, density=800.0)
    m2, I2 = robots.capsule_inertia(0.02, 0.1, mass=m)
    assert m2 == pytest.approx(m, rel=1e-14)
    np.testing.assert_allclose(I2, I, rtol=1e-13)


@pytest.mark.parametrize("build, joints, mass", [
    (robots.double_pendulum, ("shoulder", "elbow"), 2.0),
    (robots.tumbler, ("root_x", "root_z", "root_pitch", "hip", "shoulder"), 3.0),
    (robots.acrobot_model, ("shoulder", "elbow"), 2.0),
    (robots.hopper_model, ("root_x", "root_z", "root_pitch", "thigh_joint", "leg_joint", "foot_joint"), 15.820),
    (robots.walker_model, ("root_x", "root_z", "root_pitch", "hip_r", "knee_r", "ankle_r", "hip_l", "knee_l",
                           "ankle_l"), 23.677),
    (robots.luxo_model, ("root_x", "root_z", "root_pitch", "base", "elbow", "neck"), 1.35),
    (robots.jumper_model, ("root_x", "root_z", "root_pitch", "knee", "ankle"), 2.7),
])
def test_models_as_documented(build, joints, mass):
    m = build()
    assert tuple(m.joint_names) == joints
    assert float(np.sum(np.asarray(m.mass))) == pytest.approx(mass, abs=1e-3)
