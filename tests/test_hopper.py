"""The hopper example: its builder model against Gymnasium's ``hopper.xml`` in MuJoCo
(and in `cs.load_mjcf`), the stored rest state, and the problem (a short solve in CI,
the full solve marked slow)."""

from __future__ import annotations

import importlib
import os
import warnings

import numpy as np
import pytest
import jax
import jax.numpy as jnp

import cstorm as cs
H = importlib.import_module("cstorm.examples.hopper")  # (cs.examples.hopper is the factory)

mujoco = pytest.importorskip("mujoco", reason="MuJoCo is the reference implementation")
gymnasium = pytest.importorskip("gymnasium", reason="Gymnasium ships hopper.xml")

XML = os.path.join(os.path.dirname(gymnasium.__file__), "envs", "mujoco", "assets", "hopper.xml")
D = mujoco.mjtDisableBit


def _states(rng, k=5):
    q = rng.uniform(-1.0, 1.0, size=(k, 6))
    q[:, 1] += 1.2
    q[:, 3:5] = rng.uniform(-2.6, 0.0, size=(k, 2))  # inside the hinge ranges (not needed, but typical)
    return q, rng.normal(size=(k, 6)), rng.normal(size=(k, 6)) * 20


def _mujoco_reference(m, qs, vs, taus):
    """MuJoCo's M, qfrc_bias, qfrc_passive and forward acceleration (constraints and
    actuators off; applied generalized forces ``taus``)."""
    m.opt.disableflags |= D.mjDSBL_CONSTRAINT | D.mjDSBL_ACTUATION
    d = mujoco.MjData(m)
    out = {k: [] for k in ("M", "bias", "passive", "qacc")}
    for q, v, tau in zip(qs, vs, taus):
        d.qpos[:], d.qvel[:], d.qfrc_applied[:] = q, v, tau
        mujoco.mj_forward(m, d)
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M)
        out["M"].append(M), out["bias"].append(d.qfrc_bias.copy()), out["passive"].append(d.qfrc_passive.copy())
        out["qacc"].append(d.qacc.copy())
    return {k: np.stack(v) for k, v in out.items()}


@jax.jit
def _dynamics(model, qs, vs, taus):
    def f(q, v, tau):
        pf = cs.passive_forces(model, q, v)
        return dict(M=cs.mass_matrix(model, q), bias=cs.bias_forces(model, q, v), passive=pf,
                    qacc=cs.aba(model, q, v, tau + pf))
    return jax.vmap(f)(qs, vs, taus)


def _ours(model, qs, vs, taus):
    """Our M, bias, passive forces and forward acceleration, one compiled function per
    model structure (the armature variants share it)."""
    return {k: np.asarray(v) for k, v in _dynamics(model, *(jnp.asarray(a) for a in (qs, vs, taus))).items()}


@pytest.mark.parametrize("armature", [None, 0.1])
def test_model_matches_mujoco(armature):
    """hopper_model (Gymnasium's numbers, or another armature set in both) vs MuJoCo at
    random states: mass matrix, bias forces, passive (damping) forces and the forward
    dynamics with applied forces, to 1e-12 relative."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = mujoco.MjModel.from_xml_path(XML)
    model = H.hopper_model(armature=armature)
    if armature is not None:
        m.dof_armature[3:] = armature
    assert model.joint_names == ("root_x", "root_z", "root_pitch", "thigh_joint", "leg_joint", "foot_joint")
    np.testing.assert_allclose(np.asarray(model.mass).sum(), m.body_mass.sum(), rtol=1e-14)
    qs, vs, taus = _states(np.random.default_rng(6))
    ref = _mujoco_reference(m, qs, vs, taus)
    ours = _ours(model, qs, vs, taus)
    for k in ref:
        err = np.abs(ours[k] - ref[k]).max() / max(1.0, np.abs(ref[k]).max())
        assert err < 1e-12, (k, err)
    # limits and efforts as Gymnasium's
    np.testing.assert_allclose(np.asarray(model.q_lower)[3:], m.jnt_range[3:, 0], atol=1e-15)
    np.testing.assert_allclose(np.asarray(model.q_upper)[3:], m.jnt_range[3:, 1], atol=1e-15)
    np.testing.assert_allclose(np.asarray(model.effort_limit)[3:], m.actuator_gear[:, 0] * m.actuator_ctrlrange[:, 1])


def test_model_matches_load_mjcf():
    """The builder model and `cs.load_mjcf(hopper.xml)` give the same dynamics (q =
    MuJoCo's qpos in both)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        loaded = cs.load_mjcf(XML)
    model = H.hopper_model()
    qs, vs, taus = _states(np.random.default_rng(7), k=3)
    a, b = _ours(model, qs, vs, taus), _ours(loaded, qs, vs, taus)
    for k in a:
        np.testing.assert_allclose(a[k], b[k], rtol=1e-12, atol=1e-12, err_msg=k)


def test_capsule_inertia_is_mujocos():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = mujoco.MjModel.from_xml_path(XML)
    for body, key in (("torso", "torso"), ("thigh", "thigh"), ("leg", "leg")):
        i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, body)
        mass, I = cs.robots.capsule_inertia(H.HOPPER[key]["radius"], H.HOPPER[key]["length"])
        np.testing.assert_allclose(mass, m.body_mass[i], rtol=1e-14)
        np.testing.assert_allclose(I, m.body_inertia[i], rtol=1e-13)


def test_multiple_shooting_default_and_bounds():
    """The default problem uses multiple shooting; its node states (a passive state per
    inner node, after the control points) are unbounded, the control points keep single
    shooting's trust-region bounds, and the plan is the same."""
    p5, p1 = H.hopper(), H.hopper(shooting=1)
    assert p5.shooting > 1 and p1.shooting == 1
    assert p5.n_vars == p1.n_vars + 2 * p5.n_vp * (p5.shooting - 1)
    ns = p1.n_vars
    np.testing.assert_array_equal(p5.x_bounds[0][:ns], p1.x_bounds[0])
    np.testing.assert_array_equal(p5.x_bounds[1][:ns], p1.x_bounds[1])
    assert np.all(np.isneginf(p5.x_bounds[0][ns:])) and np.all(np.isposinf(p5.x_bounds[1][ns:]))
    assert p5.solve_options == p1.solve_options
