"""The shipped tumbler sequence: structure, nominal postures, and (fast) solves."""

from __future__ import annotations

import numpy as np
import pytest

import cstorm as cs
import importlib

T = importlib.import_module("cstorm.examples.tumbler")  # the module (cs.examples.tumbler is the factory)


@pytest.fixture(scope="module")
def model():
    return cs.robots.tumbler(feet=True)


def test_sequence_structure():
    seq = cs.examples.tumbler()
    assert isinstance(seq, cs.MotionSequence)
    assert [s.name for s in seq.segments] == list(T.SEGMENTS)
    for s in seq.segments:
        assert s.active == ("hip", "shoulder")
        assert s.success_criteria
    labels = cs.contact_labels(seq.segments[0].model, seq.segments[0].env)
    assert {g for g, _, _ in labels} == {"torso", "legs", "arms", "foot", "palm"}


@pytest.mark.parametrize("posture", ["start_q", "handstand_q"])
def test_nominal_postures_are_at_rest(model, posture):
    """Held still, the start posture (on the foot) and the handstand (on the palm) stay
    put: they are statically stable rest states of the contact model at the height the
    example computes (no drop, no drift)."""
    env, contact = T._env_contact()
    q0 = getattr(T, posture)(model)
    tr = cs.simulate.simulate(model, q0, t_final=0.5, dt=4e-3, active=("hip", "shoulder"), env=env, contact=contact)
    q, v = np.asarray(tr.q), np.asarray(tr.v)
    # rests near the computed sink; on the compliant, lightly damped contact the tall body
    # rocks by a few mrad (period ~1.2 s) where its CoM is off the support's centre (arms
    # down), without drifting away
    assert np.max(np.abs(q[:, 1] - q0[1])) < 1e-3  # m
    assert np.max(np.abs(q[:, 0] - q0[0])) < 1e-2  # m
    assert np.max(np.abs(q[:, 2] - q0[2])) < 2e-2  # rad
    assert np.max(np.abs(v)) < 0.1  # no fall
