"""The analytic derivative rule of the plane contact points (`cstorm.contact.plane`)
against plain JAX differentiation of the same code (``contact_forces(...,
jacobians="autodiff")``) and central finite differences: every ContactData field,
forward and reverse mode, tangents of q (on the tangent space: free and ball joints),
v, contact parameters, a geom placement and an obstacle pose; at random
slip, zero slip, and mixed with a bounded obstacle and a near-point pair (whose points
keep plain autodiff). One compile per function, shared by the cases."""

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np
import jax.numpy as jnp
import pytest

import cstorm as cs
from cstorm.contact import ContactParams, contact_forces
from cstorm.contact import Environment, Obstacle, ground, incline, platform, sphere


def _model():
    """Free base (box) with a ball-jointed limb (capsule) and a hinged foot (cylinder,
    sphere): plane features of every kind, ball and free joints for the tangent map."""
    b = cs.ModelBuilder("limbs")
    b.add_link("base", mass=2.0, inertia=np.diag([0.01, 0.02, 0.025]))
    b.add_geom("base", cs.Box([0.15, 0.1, 0.05]), name="base_box")
    b.add_body("limb", "base", "ball", xyz=(0.15, 0, 0), mass=0.5, com=(0.1, 0, 0),
               inertia=np.diag([1e-4, 3e-3, 3e-3]))
    b.add_geom("limb", cs.Capsule(0.03, 0.2), xyz=(0.1, 0, 0), rpy=(0, np.pi / 2, 0), name="limb_capsule")
    b.add_body("foot", "limb", "revolute", axis=(0, 1, 0), xyz=(0.2, 0, 0), mass=0.3, com=(0.05, 0, 0),
               inertia=np.diag([1e-4, 1e-3, 1e-3]))
    b.add_geom("foot", cs.Cylinder(0.04, 0.05), xyz=(0.05, 0, 0), rpy=(np.pi / 2, 0, 0), name="foot_cyl")
    b.add_geom("foot", cs.Sphere(0.03), xyz=(0.1, 0, 0), name="toe")
    return b.build(floating_base="free")


MODEL = _model()
PLANES = Environment([ground(), incline(np.deg2rad(5.0), height=-0.02, name="ramp")])
MIXED = Environment([ground(), platform(0.02, center=(0.5, 0.0), size=(0.4, 0.2), name="top"), sphere(0.05, (0.3, 0.0, 0.0), name="rock")])
PARAMS = ContactParams(stiffness=5e3, damping=50.0, d_on=0.01, d_off=0.0, friction=0.8, v_max=0.1, eps=0.01)


def _quat(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])


def _states():
    """(q, v): base low over the ground, limb bent down, foot on the ramp / ground; at
    random slip and at rest (zero slip)."""
    rng = np.random.default_rng(7)
    q = np.concatenate([[0.02, 0.01, 0.048], _quat([0.1, 1.0, 0.0], 0.03), _quat([0.2, 1.0, 0.1], 0.4), [0.5]])
    v = rng.normal(scale=0.3, size=MODEL.nv)
    return [(q, v), (q, np.zeros(MODEL.nv))]


def _flat(out):
    return jnp.concatenate([out.d, out.p_robot.ravel(), out.p_obstacle.ravel(), out.velocity.ravel(),
                            out.normal_magnitude, out.normal_force.ravel(), out.friction_force.ravel(),
                            out.f_ext.ravel()])


def _fn(model, env, params, q, v, dq, dv, jacobians):
    return _flat(contact_forces(model, env, params, cs.integrate(model, q, dq), v + dv, jacobians=jacobians))


_fwd = jax.jit(jax.jacfwd(_fn, argnums=(5, 6)), static_argnums=7)
_rev = jax.jit(jax.jacrev(_fn, argnums=(5, 6)), static_argnums=7)
_val = jax.jit(_fn, static_argnums=7)


def _rel(a, b):
    return float(np.abs(np.asarray(a) - np.asarray(b)).max() / max(np.abs(np.asarray(b)).max(), 1e-300))


@pytest.mark.parametrize("env_name", ["planes", "mixed"])
@pytest.mark.parametrize("case", range(2))
def test_state_jacobians_equal_autodiff_and_finite_differences(env_name, case):
    env = PLANES if env_name == "planes" else MIXED
    q, v = _states()[case]
    z = np.zeros(MODEL.nv)
    out = contact_forces(MODEL, env, PARAMS, q, v)
    assert int(np.sum(np.asarray(out.d) < PARAMS.d_on)) >= 3  # several points in contact
    ref = _fwd(MODEL, env, PARAMS, q, v, z, z, "autodiff")
    for J in (_fwd(MODEL, env, PARAMS, q, v, z, z, "analytic"), _rev(MODEL, env, PARAMS, q, v, z, z, "analytic")):
        for a, b in zip(J, ref):
            assert np.all(np.isfinite(np.asarray(a)))
            assert _rel(a, b) < 1e-12
    # central differences (q on the tangent space)
    h, E = 1e-6, np.eye(MODEL.nv)
    fdq = np.stack([(_val(MODEL, env, PARAMS, q, v, h * e, z, "analytic")
                     - _val(MODEL, env, PARAMS, q, v, -h * e, z, "analytic")) / (2 * h) for e in E], axis=1)
    fdv = np.stack([(_val(MODEL, env, PARAMS, q, v, z, h * e, "analytic")
                     - _val(MODEL, env, PARAMS, q, v, z, -h * e, "analytic")) / (2 * h) for e in E], axis=1)
    Jq, Jv = _fwd(MODEL, env, PARAMS, q, v, z, z, "analytic")
    assert np.abs(fdq).max() > 1e3 and np.abs(fdv).max() > 10.0  # stiff contacts are in the check
    assert _rel(Jq, fdq) < 1e-6 and _rel(Jv, fdv) < 1e-6


def _design_fn(theta, q, v, jacobians):
    """Contact data as a function of the stiffness (one entry per point), a geom
    placement (the toe's x) and the ramp's height."""
    k_pt, x_geom, z_ramp = theta
    n = len(cs.contact.contact_labels(MODEL, PLANES))
    params = PARAMS.replace(stiffness=k_pt * jnp.ones(n))
    poses = jnp.asarray(MODEL.geom_poses)
    g = MODEL.geom_names.index("toe")
    model = MODEL.replace(geom_poses=poses.at[g, 0, 3].add(x_geom))
    ramp = PLANES.obstacles[1]
    moved = Obstacle(ramp.shape, pose=jnp.asarray(ramp.pose).at[2, 3].add(z_ramp), name=ramp.name, contact=ramp.contact)
    env = Environment([PLANES.obstacles[0], moved])
    return _flat(contact_forces(model, env, params, q, v, jacobians=jacobians))


_design_fwd = jax.jit(jax.jacfwd(_design_fn), static_argnums=3)
_design_rev = jax.jit(jax.jacrev(_design_fn), static_argnums=3)


def test_parameter_tangents_equal_autodiff():
    q, v = _states()[0]
    theta = (jnp.asarray(5e3), jnp.asarray(0.0), jnp.asarray(0.0))
    ref = _design_fwd(theta, q, v, "autodiff")
    assert all(np.abs(np.asarray(r)).max() > 0 for r in ref)
    for J in (_design_fwd(theta, q, v, "analytic"), _design_rev(theta, q, v, "analytic")):
        for a, b in zip(J, ref):
            assert _rel(a, b) < 1e-12


def test_jacobians_argument_is_checked():
    q, v = _states()[0]
    with pytest.raises(cs.errors.InputError, match="jacobians"):
        contact_forces(MODEL, PLANES, PARAMS, q, v, jacobians="fd")
