"""Contact points, environments and f_ext assembly (`cstorm.contact.contact_forces`,
`cstorm.contact.environment`): hand computations, J^T f consistency, finite-difference gradients
and physics sanity (bounce, sliding deceleration mu g, incline slide and creep) with a
small semi-implicit Euler integrator. Compiles once per model (functions take the model,
environment and parameters as arguments and are reused across cases)."""

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np
import jax.numpy as jnp
import pytest
from scipy.optimize import brentq

import cstorm as cs
from cstorm.contact import ContactParams, contact_forces, contact_labels, normal_force
from cstorm.contact import Environment, Obstacle, ground, incline, platform, sphere, step
from cstorm.errors import InputError

G = 9.81
R_BALL = 0.1
HALF = np.array([0.1, 0.1, 0.05])  # box half extents
# k m: ball equilibrium d = d_on - m g / k = -0.905 mm lies in the beta = 1 region
P = ContactParams(stiffness=2000.0, damping=20.0, d_on=0.004, d_off=0.0, friction=0.5, v_max=0.1, eps=0.01)

_cf = jax.jit(contact_forces)


def _ball():
    b = cs.ModelBuilder("ball")
    b.add_link("ball", mass=1.0, inertia=np.eye(3) * 0.4 * R_BALL ** 2)
    b.add_geom("ball", cs.Sphere(R_BALL), name="ball")
    return b.build(floating_base="planar")  # q = [x, z, pitch]


def _box():
    b = cs.ModelBuilder("box")
    dims = 2 * HALF
    b.add_link("box", mass=1.0, inertia=np.diag([dims[1] ** 2 + dims[2] ** 2, dims[0] ** 2 + dims[2] ** 2,
                                                   dims[0] ** 2 + dims[1] ** 2]) / 12.0)
    b.add_geom("box", cs.Box(HALF), name="box")
    return b.build(floating_base="planar")


def _robot():
    """Free-floating box base with a revolute arm (capsule) ending in a sphere hand."""
    b = cs.ModelBuilder("robot")
    b.add_link("base", mass=2.0, inertia=np.diag([0.01, 0.02, 0.025]))
    b.add_geom("base", cs.Box([0.15, 0.1, 0.05]), name="base_box")
    b.add_body("arm", "base", "revolute", axis=(0, 1, 0), xyz=(0.15, 0, 0), mass=0.5, com=(0.15, 0, 0),
               inertia=np.diag([1e-4, 4e-3, 4e-3]))
    b.add_geom("arm", cs.Capsule(0.03, 0.3), xyz=(0.15, 0, 0), rpy=(0, np.pi / 2, 0), name="arm_capsule")
    b.add_geom("arm", cs.Sphere(0.04), xyz=(0.3, 0, 0), name="hand")
    return b.build(floating_base="free")


BALL, BOX, ROBOT = _ball(), _box(), _robot()
GROUND = Environment([ground()])


def _quat_y(angle):
    return np.array([np.cos(angle / 2), 0.0, np.sin(angle / 2), 0.0])


# ---------------------------------------------------------------------------------------
# Hand computations
# ---------------------------------------------------------------------------------------


def test_sphere_on_ground_matches_hand_computation():
    # penetrating by 1 mm, sliding slower than v_max, rolling: contact point velocity
    # x-component vx - r wy
    z, vx, vz, wy = R_BALL - 0.001, 0.07, -0.05, 0.3
    out = _cf(BALL, GROUND, P, jnp.array([0.2, z, 0.4]), jnp.array([vx, vz, wy]))
    d = z - R_BALL
    assert out.labels == (("ball", "ground", 0),) and out.body == (BALL.body_names.index("ball"),)
    np.testing.assert_allclose(out.d, [d], atol=1e-15)
    np.testing.assert_allclose(out.p_robot, [[0.2, 0, d]], atol=1e-15)
    np.testing.assert_allclose(out.p_obstacle, [[0.2, 0, 0]], atol=1e-15)
    np.testing.assert_allclose(out.n, [[0, 0, 1]], atol=1e-15)
    x = 2000.0 * (0.004 - d) - 20.0 * vz
    N = 0.5 * (x + np.sqrt(x * x + 0.01 ** 2))  # beta = 1 (d < d_off)
    s = vx - R_BALL * wy
    gam = 1.5 * abs(s) / 0.1 - 0.5 * (abs(s) / 0.1) ** 3
    ft = -0.5 * N * gam * np.sign(s)
    np.testing.assert_allclose(out.velocity, [[s, 0, vz]], rtol=1e-13)
    np.testing.assert_allclose(out.normal_force, [[0, 0, N]], rtol=1e-13)
    np.testing.assert_allclose(out.friction_force, [[ft, 0, 0]], rtol=1e-13)
    f = np.array([ft, 0, N])
    expect = np.zeros((3, 6))
    expect[2] = np.concatenate([np.cross([0.2, 0, d], f), f])  # bodies: root_x, root_z, ball
    np.testing.assert_allclose(out.f_ext, expect, rtol=1e-13, atol=1e-15)
    # separated beyond d_on: exactly zero
    out = _cf(BALL, GROUND, P, jnp.array([0.0, R_BALL + 0.0041, 0.0]), jnp.array([1.0, -1.0, 2.0]))
    assert np.all(np.asarray(out.f_ext) == 0.0) and float(out.d[0]) == pytest.approx(0.0041)


def test_several_points_per_pair():
    """A capsule lying flat gets two equal normal forces; a box (and the same box as a
    ConvexMesh) resting on a face four equal ones; an upright cylinder 8 (its bottom rim)."""
    b = cs.ModelBuilder("shapes")
    b.add_link("body", mass=4.0, inertia=np.eye(3))
    b.add_geom("body", cs.Capsule(0.05, 0.4), xyz=(0, 0, 0), rpy=(0, np.pi / 2, 0), name="capsule")
    b.add_geom("body", cs.Box([0.2, 0.1, 0.05]), xyz=(0, 1, 0), name="box")
    b.add_geom("body", cs.ConvexMesh(_BOX_CORNERS * [0.2, 0.1, 0.05]), xyz=(0, 2, 0), name="mesh")
    b.add_geom("body", cs.Cylinder(0.1, 0.1), xyz=(0, 3, 0), name="cylinder")
    m = b.build(floating_base="planar")
    env = Environment([ground()])
    out = contact_forces(m, env, P, jnp.array([0.3, 0.05 - 0.002, 0.0]), jnp.zeros(3))
    labels = out.labels
    assert [lb[0] for lb in labels].count("cylinder") == 16 and [lb[0] for lb in labels].count("box") == 8
    N = np.asarray(out.normal_magnitude)
    N_one = float(normal_force(-0.002, 0.0, P))
    for geom, n_on in (("capsule", 2), ("box", 4), ("mesh", 4), ("cylinder", 8)):
        Ng = np.array([N[i] for i, lb in enumerate(labels) if lb[0] == geom])
        on = Ng[Ng > 0]
        assert len(on) == n_on, geom
        np.testing.assert_allclose(on, N_one, rtol=1e-12)
    # per-pair parameters: a stiffer capsule
    stiff = P.replace(stiffness=4000.0)
    out2 = contact_forces(m, env, {("capsule", "ground"): stiff, ("*", "*"): P}, jnp.array([0.3, 0.048, 0.0]),
                          jnp.zeros(3))
    N2 = np.asarray(out2.normal_magnitude)
    is_cap = np.array([lb[0] == "capsule" for lb in labels])
    np.testing.assert_allclose(N2[~is_cap], N[~is_cap], rtol=1e-14)
    np.testing.assert_allclose(N2[is_cap], float(normal_force(-0.002, 0.0, stiff)), rtol=1e-12)
    # per-point parameters (k,), in contact_labels order
    assert contact_labels(m, env) == labels
    fr = np.where(is_cap, 0.9, 0.3)
    out3 = contact_forces(m, env, P.replace(friction=fr), jnp.array([0.3, 0.048, 0.0]), jnp.array([1.0, 0, 0]))
    Ft = np.abs(np.asarray(out3.friction_force)[:, 0])
    np.testing.assert_allclose(Ft, fr * N, rtol=1e-12)


_BOX_CORNERS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)


# ---------------------------------------------------------------------------------------
# Box obstacles (platform tops, steps): one force per robot feature
# ---------------------------------------------------------------------------------------

TOP = 0.2  # platform top height
PLAT_ENV = Environment([platform(TOP, center=(0.0, 0.0), size=(1.0, 1.0))])


def test_box_resting_on_a_platform_top_is_held_at_its_four_corners():
    """A box resting flat on a platform top gets four equal forces at its lower corners
    (the same as on the ground at the same penetration), no torque about its centre, and
    keeps them while it slides across the top; half over the edge, only the two corners
    above the top push. With contact='near_point' the same box gets one force."""
    pen = 0.002
    z = TOP + HALF[2] - pen
    N_one = float(normal_force(-pen, 0.0, P))
    for x in (0.0, 0.13, -0.31):  # sliding across the top: the same four forces
        out = _cf(BOX, PLAT_ENV, P, jnp.array([x, z, 0.0]), jnp.zeros(3))
        assert out.labels == tuple(("box", "platform", j) for j in range(8))
        N = np.asarray(out.normal_magnitude)
        on = N > 0
        assert on.sum() == 4
        np.testing.assert_allclose(N[on], N_one, rtol=1e-12)
        np.testing.assert_allclose(np.asarray(out.n)[on], np.tile([0.0, 0.0, 1.0], (4, 1)), atol=1e-15)
        np.testing.assert_allclose(np.asarray(out.p_obstacle)[on][:, 2], TOP, atol=1e-15)
        f = np.asarray(out.f_ext)[-1]  # [torque about the world origin; force] of the box body
        c = np.array([x, 0.0, z])
        np.testing.assert_allclose(f[3:], [0.0, 0.0, 4 * N_one], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(f[:3] - np.cross(c, f[3:]), 0.0, atol=1e-12)  # no torque about the centre
        ref = _cf(BOX, Environment([ground(TOP)]), P, jnp.array([x, z, 0.0]), jnp.zeros(3))
        np.testing.assert_allclose(np.asarray(out.f_ext), np.asarray(ref.f_ext), rtol=1e-12, atol=1e-12)
    out = _cf(BOX, PLAT_ENV, P, jnp.array([0.55, z, 0.0]), jnp.zeros(3))  # over the edge x = 0.5
    N = np.asarray(out.normal_magnitude)
    assert (N > 0).sum() == 2  # the corners at x = 0.45; those at x = 0.65 are 0.15 m beside the side face
    np.testing.assert_allclose(N[N > 0], N_one, rtol=1e-12)
    # one near-point pair instead, and both together
    env1 = Environment([platform(TOP, size=(1.0, 1.0), contact="near_point")])
    out = contact_forces(BOX, env1, P, jnp.array([0.13, z, 0.0]), jnp.zeros(3))
    assert out.labels == (("box", "platform", -1),)
    np.testing.assert_allclose(out.d, [-pen], atol=1e-10)
    env2 = Environment([platform(TOP, size=(1.0, 1.0), contact="both")])
    assert contact_labels(BOX, env2) == tuple(("box", "platform", j) for j in range(8)) + (("box", "platform", -1),)


def test_features_on_box_obstacles_capsule_cylinder_and_per_pair_parameters():
    """A capsule lying on a step gets two equal forces (its end spheres), an upright
    cylinder on a box its bottom rim; per-pair parameters apply to box-obstacle features."""
    b = cs.ModelBuilder("shapes")
    b.add_link("body", mass=4.0, inertia=np.eye(3))
    b.add_geom("body", cs.Capsule(0.05, 0.4), rpy=(0, np.pi / 2, 0), name="capsule")
    b.add_geom("body", cs.Cylinder(0.1, 0.1), xyz=(0, 1, 0), name="cylinder")
    m = b.build(floating_base="planar")
    env = Environment([step(TOP, x=-1.0, length=3.0, width=4.0), sphere(0.05, (0.0, 0.0, -1.0), name="rock")])
    q = jnp.array([0.3, TOP + 0.05 - 0.002, 0.0])
    out = contact_forces(m, env, P, q, jnp.zeros(3))
    lab = out.labels
    assert [lb for lb in lab if lb[1] == "rock"] == [("capsule", "rock", -1), ("cylinder", "rock", -1)]
    N = np.asarray(out.normal_magnitude)
    N_one = float(normal_force(-0.002, 0.0, P))
    for geom, n_on in (("capsule", 2), ("cylinder", 8)):
        Ng = np.array([N[i] for i, lb in enumerate(lab) if lb[:2] == (geom, "step")])
        np.testing.assert_allclose(Ng[Ng > 0], N_one, rtol=1e-12)
        assert (Ng > 0).sum() == n_on
    stiff = P.replace(stiffness=4000.0)
    out2 = contact_forces(m, env, {("capsule", "step"): stiff, ("*", "*"): P}, q, jnp.zeros(3))
    N2 = np.asarray(out2.normal_magnitude)
    cap = np.array([lb[:2] == ("capsule", "step") for lb in lab])
    np.testing.assert_allclose(N2[cap & (N2 > 0)], float(normal_force(-0.002, 0.0, stiff)), rtol=1e-12)
    np.testing.assert_allclose(N2[~cap], N[~cap], rtol=1e-14)


_box_jac = jax.jit(jax.jacfwd(lambda q, v: _flat(contact_forces(BOX, PLAT_ENV, P, q, v)), argnums=(0, 1)))


def test_box_on_platform_gradients_match_finite_differences():
    """Derivatives of the box-obstacle feature contacts w.r.t. q and v: flat on the top
    at zero slip, tilted near the edge (corners beside the side face: the normal turns
    round the edge) while sliding, and a corner pressed into the side face."""
    f = lambda q, v: np.asarray(_flat(_cf(BOX, PLAT_ENV, P, q, v)))  # noqa: E731
    cases = [(np.array([0.1, TOP + HALF[2] - 0.002, 0.0]), np.zeros(3)),
             (np.array([0.407, TOP + 0.0612, 0.1]), np.array([0.4, -0.1, 0.5])),  # corners 2 mm off the edge
             (np.array([0.57, TOP - 0.02, 0.2]), np.array([-0.2, 0.05, -0.3]))]
    for q, v in cases:
        Jq, Jv = (np.asarray(J) for J in _box_jac(q, v))
        assert np.all(np.isfinite(Jq)) and np.all(np.isfinite(Jv))
        h = 1e-7
        fdq = np.stack([(f(q + h * e, v) - f(q - h * e, v)) / (2 * h) for e in np.eye(3)], axis=1)
        fdv = np.stack([(f(q, v + h * e) - f(q, v - h * e)) / (2 * h) for e in np.eye(3)], axis=1)
        assert np.abs(fdq).max() > 10.0  # contact is active
        print(f"box on platform: FD rel error dq {np.abs(Jq - fdq).max() / np.abs(fdq).max():.2e}, "
              f"dv {np.abs(Jv - fdv).max() / max(np.abs(fdv).max(), 1e-12):.2e}")
        np.testing.assert_allclose(Jq, fdq, rtol=0, atol=1e-6 * np.abs(fdq).max())
        np.testing.assert_allclose(Jv, fdv, rtol=0, atol=1e-6 * max(np.abs(fdv).max(), 1.0))


# ---------------------------------------------------------------------------------------
# A multi-body robot: near-point pairs, self-collision, J^T f, gradients
# ---------------------------------------------------------------------------------------

# closed-form pairs only (the GJK/EPA pairs base_box-step and arm_capsule-step are left out
# to keep compile times low; geometry's own tests cover their derivatives)
ROBOT_ENV = Environment([ground(), step(0.03, x=0.47), sphere(0.1, (-0.5, 0.0, 0.05), name="rock")],
                        pairs=[("*", "ground"), ("*", "rock"), ("hand", "step")],
                        self_collision=[("hand", "base_box")])
ROBOT_P = ContactParams(stiffness=5e3, damping=50.0, d_on=0.01, d_off=0.0, friction=0.8, v_max=0.1, eps=0.01)


def _robot_states():
    """(q, v) pairs: base tilted on the ground, arm down with the hand on the step edge;
    arm folded back with the hand pressing on the base top (self-collision)."""
    rng = np.random.default_rng(3)
    qa = np.concatenate([[0.0, 0.0, 0.047], _quat_y(0.02), [0.04]])
    qb = np.concatenate([[0.0, 0.0, 0.052], _quat_y(-0.01), [-(np.pi - 0.28)]])
    vr = rng.normal(scale=0.2, size=7)
    return [(qa, vr), (qa, np.zeros(7)), (qb, vr), (qb, np.zeros(7))]


def _flat(out):
    return jnp.concatenate([out.d, out.normal_force.ravel(), out.friction_force.ravel(), out.f_ext.ravel()])


def _robot_flat_fn(model, env, params, q, v, dq, dv):
    return _flat(contact_forces(model, env, params, cs.integrate(model, q, dq), v + dv))


_robot_jac = jax.jit(jax.jacfwd(_robot_flat_fn, argnums=(5, 6)))
_integrate = jax.jit(cs.integrate)


def _robot_flat(model, env, params, q, v, dq, dv):  # reuses _cf's compile
    return _flat(_cf(model, env, params, _integrate(model, q, dq), v + dv))


def test_robot_contacts_are_active_and_self_collision_is_equal_and_opposite():
    (qa, _), _, (qb, vb), _ = _robot_states()
    out = _cf(ROBOT, ROBOT_ENV, ROBOT_P, qa, np.zeros(7))
    lab = {lb: i for i, lb in enumerate(out.labels)}
    d = np.asarray(out.d)
    assert d[lab[("hand", "step", 0)]] < 0.01 and d[lab[("hand", "ground", 0)]] < 0.01
    assert sum(d[i] < 0.01 for lb, i in lab.items() if lb[:2] == ("base_box", "ground")) == 4
    out = _cf(ROBOT, ROBOT_ENV, ROBOT_P, qb, vb)
    i = out.labels.index(("base_box", "hand", -1))
    assert out.body[i] == 0 and out.other_body[i] == 1 and float(out.normal_magnitude[i]) > 0
    # the self pair alone: equal and opposite along one line, no net wrench
    env_self = Environment([], self_collision=[("hand", "base_box")])
    o = _cf(ROBOT, env_self, ROBOT_P, qb, vb)
    assert o.labels == (("base_box", "hand", -1),)
    np.testing.assert_allclose(np.asarray(o.f_ext).sum(0), 0.0, atol=1e-12)
    assert np.abs(np.asarray(o.f_ext)).max() > 1.0


_rnea = jax.jit(cs.rnea)
_pjac = jax.jit(cs.point_jacobian, static_argnums=2)


@pytest.mark.parametrize("case", range(4))
def test_f_ext_matches_point_jacobians(case):
    """rnea(f_ext = 0) - rnea(f_ext) = sum_k J_k^T f_k (J_k: point Jacobian at p_robot; for
    the self pair, +f on body a and -f on body b at the witness midpoint)."""
    q, v = _robot_states()[case]
    out = _cf(ROBOT, ROBOT_ENV, ROBOT_P, q, v)
    a = np.random.default_rng(case).normal(size=7)
    diff = _rnea(ROBOT, q, v, a, jnp.zeros((ROBOT.n_bodies, 6))) - _rnea(ROBOT, q, v, a, out.f_ext)
    T = np.asarray(cs.forward_kinematics(ROBOT, q))
    tau = np.zeros(7)
    f = np.asarray(out.force)
    pr, po = np.asarray(out.p_robot), np.asarray(out.p_obstacle)
    for i in range(len(out.labels)):
        p = pr[i] if out.other_body[i] < 0 else 0.5 * (pr[i] + po[i])
        for bdy, sgn in ((out.body[i], 1.0), (out.other_body[i], -1.0)):
            if bdy < 0:
                continue
            local = T[bdy, :3, :3].T @ (p - T[bdy, :3, 3])
            J = np.asarray(_pjac(ROBOT, q, bdy, local))
            tau += sgn * J[3:].T @ f[i]
    assert np.abs(tau).max() > 5.0  # contacts are loaded
    np.testing.assert_allclose(diff, tau, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("case", range(4))
def test_robot_gradients_match_finite_differences(case):
    """d(contact data)/d(q, v) (q on the tangent space) vs central differences, with
    contacts active (ground corners, hand on the step edge or the base, self-collision),
    at random slip and at zero slip (v = 0)."""
    q, v = _robot_states()[case]
    z = np.zeros(7)
    Jq, Jv = (np.asarray(J) for J in _robot_jac(ROBOT, ROBOT_ENV, ROBOT_P, q, v, z, z))
    h = 1e-6
    E = np.eye(7)
    fdq = np.stack([(_robot_flat(ROBOT, ROBOT_ENV, ROBOT_P, q, v, h * e, z) -
                     _robot_flat(ROBOT, ROBOT_ENV, ROBOT_P, q, v, -h * e, z)) / (2 * h) for e in E], axis=1)
    fdv = np.stack([(_robot_flat(ROBOT, ROBOT_ENV, ROBOT_P, q, v, z, h * e) -
                     _robot_flat(ROBOT, ROBOT_ENV, ROBOT_P, q, v, z, -h * e)) / (2 * h) for e in E], axis=1)
    assert np.all(np.isfinite(Jq)) and np.all(np.isfinite(Jv))
    scale_q, scale_v = np.abs(fdq).max(), np.abs(fdv).max()
    assert scale_q > 1e3 and scale_v > 10.0  # stiff contacts are in the check
    err_q = np.abs(Jq - fdq).max() / scale_q
    err_v = np.abs(Jv - fdv).max() / scale_v
    print(f"case {case}: FD rel error dq {err_q:.2e}, dv {err_v:.2e}")
    assert err_q < 1e-6 and err_v < 1e-6


def test_ball_gradients_match_finite_differences_at_zero_slip():
    f = lambda q, v: _flat(_cf(BALL, GROUND, P, q, v))  # noqa: E731 (reuses _cf's compile)
    jac = jax.jit(jax.jacfwd(lambda q, v: _flat(contact_forces(BALL, GROUND, P, q, v)), argnums=(0, 1)))
    for q, v in ((np.array([0.1, R_BALL - 0.002, 0.3]), np.zeros(3)),  # resting, zero slip
                 (np.array([0.1, R_BALL - 0.001, 0.3]), np.array([0.03, -0.2, 0.3])),  # rolling, v_t = 0
                 (np.array([0.1, R_BALL + 0.002, 0.3]), np.array([0.05, -0.1, 0.2]))):  # in the ramp
        Jq, Jv = (np.asarray(J) for J in jac(q, v))
        h = 1e-7
        fdq = np.stack([(f(q + h * e, v) - f(q - h * e, v)) / (2 * h) for e in np.eye(3)], axis=1)
        fdv = np.stack([(f(q, v + h * e) - f(q, v - h * e)) / (2 * h) for e in np.eye(3)], axis=1)
        print(f"ball FD rel error dq {np.abs(Jq - fdq).max() / np.abs(fdq).max():.2e}, "
              f"dv {np.abs(Jv - fdv).max() / np.abs(fdv).max():.2e}")
        np.testing.assert_allclose(Jq, fdq, rtol=0, atol=1e-6 * np.abs(fdq).max())
        np.testing.assert_allclose(Jv, fdv, rtol=0, atol=1e-6 * np.abs(fdv).max())


# ---------------------------------------------------------------------------------------
# Physics sanity: semi-implicit Euler with aba + contact (planar bases: q + dt v)
# ---------------------------------------------------------------------------------------

DT = 1e-3


def _simulate(model, env, params, q0, v0, n):
    def stp(carry, _):
        q, v = carry
        c = contact_forces(model, env, params, q, v)
        a = cs.aba(model, q, v, jnp.zeros(model.nv), c.f_ext)
        v = v + DT * a
        q = q + DT * v
        return (q, v), (q, v)

    return jax.lax.scan(stp, (q0, v0), None, length=n)[1]


_sim_ball = jax.jit(_simulate, static_argnums=5)
_sim_box = jax.jit(jax.vmap(_simulate, in_axes=(None, 0, None, 0, 0, None)), static_argnums=5)


def test_ball_bounces_lower_each_time_and_settles_at_spring_equilibrium():
    z0 = 0.3
    # c = 10 N s/m (damping ratio 0.11) so that several bounces happen within 3 s
    Pb = P.replace(damping=10.0)
    qs, vs = (np.asarray(a) for a in _sim_ball(BALL, GROUND, Pb, jnp.array([0.0, z0, 0.0]), jnp.zeros(3), 3000))
    z, vz = qs[:, 1], vs[:, 1]
    airborne = z - R_BALL > 0.004
    apex = [z[i] - R_BALL for i in range(1, len(z)) if vz[i - 1] > 0 >= vz[i] and airborne[i]]
    print("bounce apex heights (m above contact):", np.round(apex, 5))
    assert len(apex) >= 3
    assert apex[0] < z0 - R_BALL and all(a1 < a0 for a0, a1 in zip(apex, apex[1:]))
    d_eq = 0.004 - 1.0 * G / 2000.0
    assert abs(z[-1] - R_BALL - d_eq) < 1e-6 and abs(vz[-1]) < 1e-4
    assert np.all(np.abs(qs[:, 0]) < 1e-12)  # a vertical drop stays vertical


def _d_rest(theta, params, per_corner_load):
    """Distance at which one corner's static normal force carries its share of m g cos."""
    return brentq(lambda d: float(normal_force(d, 0.0, params)) - per_corner_load * np.cos(theta),
                  float(params.d_off) - 0.1, float(params.d_on))


def _creep_speed(theta, mu, v_max):
    """Steady slip speed on an incline with tan(theta) < mu: gamma(s) = tan(theta)/mu."""
    r = np.tan(theta) / mu
    return v_max * brentq(lambda x: 1.5 * x - 0.5 * x ** 3 - r, 0.0, 1.0)


def test_box_slides_decelerates_and_creeps_as_predicted():
    """One vmapped rollout of four cases of one box model: sliding on flat ground at 1.5
    m/s (decelerates at mu g), a 35 deg incline (tan > mu = 0.5: accelerates at
    g (sin - mu cos)), 5 and 20 deg inclines (creep at gamma^-1(tan/mu) v_max)."""
    angles = np.radians([0.0, 35.0, 5.0, 20.0])
    envs = [Environment([incline(a)]) for a in angles]
    env = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *envs)
    q0, v0 = [], []
    for a in angles:
        N = np.array([np.sin(a), 0.0, np.cos(a)])
        c = (HALF[2] + _d_rest(a, P, G / 4)) * N
        q0.append([c[0], c[2], a])
        v0.append([1.5, 0.0, 0.0] if a == 0 else [0.0, 0.0, 0.0])
    n = 800
    qs, vs = (np.asarray(x) for x in _sim_box(BOX, env, P, jnp.array(q0), jnp.array(v0), n))
    t = DT * np.arange(1, n + 1)
    down = np.stack([np.cos(angles), -np.sin(angles)], axis=1)  # downhill (x, z)
    s = np.einsum("ctk,ck->ct", vs[:, :, :2], down)  # slip speed along the slope
    mu, vmax = 0.5, 0.1
    # flat: linear deceleration at mu g while s > v_max
    w = (t > 0.03) & (s[0] > vmax + 0.05)
    dec = -np.polyfit(t[w], s[0][w], 1)[0]
    # steep: acceleration g (sin - mu cos)
    w = t > 0.2
    acc = np.polyfit(t[w], s[1][w], 1)[0]
    acc_ref = G * (np.sin(angles[1]) - mu * np.cos(angles[1]))
    creep5, creep20 = s[2][-1], s[3][-1]
    lin5 = vmax * np.tan(angles[2]) / (1.5 * mu)
    print(f"deceleration {dec:.5f} vs mu g {mu * G:.5f}; 35 deg acceleration {acc:.5f} vs {acc_ref:.5f}; "
          f"creep 5 deg {creep5:.6f} (cubic {_creep_speed(angles[2], mu, vmax):.6f}, linear {lin5:.6f}); "
          f"creep 20 deg {creep20:.6f} (cubic {_creep_speed(angles[3], mu, vmax):.6f})")
    assert abs(dec - mu * G) < 2e-3 * mu * G
    assert s[0][-1] < 0.01  # stopped (creeping down to zero on flat ground)
    assert abs(acc - acc_ref) < 2e-3 * acc_ref
    for sc, a in ((creep5, angles[2]), (creep20, angles[3])):
        assert abs(sc - _creep_speed(a, mu, vmax)) < 1e-3 * _creep_speed(a, mu, vmax)
    assert abs(creep5 - lin5) < 0.01 * lin5
    assert np.all(np.abs(np.diff(s[2][-100:])) < 1e-6)  # steady


# ---------------------------------------------------------------------------------------
# Environments and bad input
# ---------------------------------------------------------------------------------------


def test_environment_constructors_and_pair_selection():
    g = ground(0.2)
    assert isinstance(g.shape, cs.Plane) and float(g.pose[2, 3]) == 0.2
    inc = incline(0.3)
    np.testing.assert_allclose(inc.pose[:3, :3] @ inc.shape.normal, [np.sin(0.3), 0, np.cos(0.3)], atol=1e-15)
    p = platform(0.1, center=(1.0, 0.0), size=(0.4, 0.6))
    np.testing.assert_allclose(p.shape.half_extents, [0.2, 0.3, 0.05])
    np.testing.assert_allclose(p.pose[:3, 3], [1.0, 0.0, 0.05])
    env = Environment([ground(), step(0.05, x=1.0), sphere(0.2, (0, 0, 1))],
                      pairs=[("hand", "*"), ("base_box", "ground")])
    labels = contact_labels(ROBOT, env)
    assert {lb[:2] for lb in labels} == {("hand", "ground"), ("hand", "step"), ("hand", "sphere"),
                                        ("base_box", "ground")}
    assert Environment([cs.Sphere(1.0)]).names == ("obstacle0",)
    # default: every geom of a moving body against every obstacle, self-collision off
    assert len(contact_labels(ROBOT, Environment([ground()]))) == 8 + 2 + 1


def test_bad_input_errors_name_the_culprit():
    with pytest.raises(InputError, match="'grund'"):
        Environment([ground()], pairs=[("hand", "grund")])
    with pytest.raises(InputError, match="'fot'"):
        contact_labels(ROBOT, Environment([ground()], pairs=[("fot", "ground"), ("hand", "ground")]))
    with pytest.raises(InputError, match="'elbow'"):
        contact_forces(ROBOT, Environment([ground()], self_collision=[("hand", "elbow")]), P, ROBOT.neutral(),
                       np.zeros(7))
    with pytest.raises(InputError, match="same body"):
        contact_labels(ROBOT, Environment([], self_collision=[("hand", "arm_capsule")]))
    with pytest.raises(InputError, match="unique"):
        Environment([ground(), ground()])
    with pytest.raises(InputError, match="no entry of params"):
        contact_forces(BALL, GROUND, {("nothing", "*"): P}, np.zeros(3), np.zeros(3))
    with pytest.raises(InputError, match=r"ContactParams.stiffness has shape \(3,\)"):
        contact_forces(BALL, GROUND, P.replace(stiffness=np.ones(3)), np.zeros(3), np.zeros(3))
    with pytest.raises(InputError, match="Environment"):
        contact_forces(BALL, [ground()], P, np.zeros(3), np.zeros(3))
    with pytest.raises(InputError, match="pose"):
        Obstacle(cs.Sphere(1.0), pose=np.ones((4, 4)))
    with pytest.raises(InputError, match="contact must be one of"):
        platform(0.1, contact="corners")
    with pytest.raises(InputError, match="'ground'.*Plane obstacle takes contact='features' only"):
        Obstacle(cs.Plane([0, 0, 1], 0.0), name="ground", contact="near_point")
    with pytest.raises(InputError, match="'blob'.*ConvexMesh"):
        Obstacle(cs.ConvexMesh(_BOX_CORNERS), name="blob", contact="features")
