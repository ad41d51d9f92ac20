"""Rollouts: measured convergence orders (RK4, RKMK4 on a free body, semi-implicit Euler),
energy conservation, exact tracking of active paths, the torque convention, divergence
reports and bounded-memory reverse mode over a long rollout.

Compile budget: each integrator/model pair is compiled once; runs of different lengths
share it through ``rollout(..., n_valid=...)`` (a traced step count) and a traced ``dt``.
"""

from __future__ import annotations

import numpy as np
import pytest
import jax
import jax.numpy as jnp

import cstorm as cs
from cstorm.errors import DivergenceError, ProblemError
from cstorm.examples.acrobot import acrobot_model
from cstorm.simulate import RolloutLayout, rollout, simulate
from cstorm.trajectory import QuinticBSpline

NMAX = 512


def _runner(model, active, integrator):
    """A jitted ``(h, n) -> (qT, vT)`` rollout with zero active motion, scan length NMAX."""
    lay = RolloutLayout.make(model, active)
    na = lay.n_active

    @jax.jit
    def run(q0, v0, h, n):
        z = jnp.zeros((NMAX + 1, na))
        paths = dict(qa=z + q0[np.array(lay.qa_idx, int)], va=z, aa=z, qm=z[:-1] + q0[np.array(lay.qa_idx, int)],
                     vm=z[:-1], am=z[:-1])
        r = rollout(model, lay, q0, v0, paths, h, NMAX, integrator=integrator, n_valid=n, record=False)
        return r["qT"], r["vT"]

    return run


def _orders(model, run, q0, v0, T, ns):
    """Richardson estimate of the order: log2 of successive differences between
    solutions with dt = T/n, T/2n, ... (manifold difference for q)."""
    sols = [run(q0, v0, T / n, n) for n in ns]
    d = [np.linalg.norm(np.concatenate([np.asarray(cs.difference(model, a[0], b[0])), np.asarray(a[1] - b[1])]))
         for a, b in zip(sols, sols[1:])]
    return np.log2(np.array(d[:-1]) / np.array(d[1:])), d, sols


@pytest.fixture(scope="module")
def pendulum():
    return acrobot_model()


@pytest.fixture(scope="module")
def rk4_run(pendulum):
    return _runner(pendulum, (), "rk4")


@pytest.fixture(scope="module")
def free_body():
    b = cs.ModelBuilder("tumbling_box", gravity=(0.0, 0.0, -9.81))
    b.add_link("box", mass=2.0, com=(0.05, -0.02, 0.1), inertia=np.diag([0.08, 0.12, 0.16]))
    return b.build(floating_base="free")


def test_rk4_order_double_pendulum(pendulum, rk4_run):
    q0, v0 = jnp.array([1.0, 0.5]), jnp.array([0.0, 0.3])
    slopes, d, sols = _orders(pendulum, rk4_run, q0, v0, 1.0, (32, 64, 128, 256, 512))
    # measured: 3.73, 3.89, 3.95 (approaching 4 from below; vs a fine reference: 4.35, 4.22)
    assert np.all(slopes > 3.6) and slopes[-1] > 3.85 and np.all(slopes < 4.5), (slopes, d)


def test_rk4_energy_conservation(pendulum, rk4_run):
    q0, v0 = jnp.array([1.0, 0.5]), jnp.array([0.0, 0.3])
    Ej = jax.jit(lambda q, v: cs.kinetic_energy(pendulum, q, v) + cs.potential_energy(pendulum, q))
    E = lambda q, v: float(Ej(q, v))
    E0 = E(q0, v0)
    drift = []
    for n in (64, 128, 256):
        qT, vT = rk4_run(q0, v0, 1.0 / n, n)
        drift.append(abs(E(qT, vT) - E0))
    # drift shrinks at 4th order (or faster) and is tiny at dt = 1/256 s
    assert drift[-1] < 1e-8 * max(1.0, abs(E0)), drift
    assert drift[0] / drift[-1] > 2 ** 7, drift


def test_rkmk4_order_free_body(free_body):
    run = _runner(free_body, (), "rk4")
    quat = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])
    q0 = jnp.concatenate([jnp.array([0.1, 0.2, 0.3]), jnp.asarray(quat)])
    v0 = jnp.array([3.0, 0.2, -1.5, 0.5, 0.1, 2.0])  # tumbling about all three axes
    slopes, d, sols = _orders(free_body, run, q0, v0, 1.0, (16, 32, 64, 128, 256))
    # measured: 3.99, 4.00, 4.00 (RK4 without the dexp^-1 correction: 2.0)
    assert np.all(slopes > 3.8), (slopes, d)
    for q, _ in sols:
        assert abs(np.linalg.norm(np.asarray(q)[3:]) - 1.0) < 1e-12  # stays on the group
    E = lambda q, v: float(cs.kinetic_energy(free_body, q, v) + cs.potential_energy(free_body, q))
    assert abs(E(*sols[-1]) - E(q0, v0)) < 1e-6


def test_semi_implicit_euler_order_one(pendulum, rk4_run):
    run = _runner(pendulum, (), "euler")
    q0, v0 = jnp.array([1.0, 0.5]), jnp.array([0.0, 0.3])
    ref = rk4_run(q0, v0, 1.0 / NMAX, NMAX)  # RK4 error ~1e-9: exact at this scale
    err = []
    for n in (64, 128, 256, 512):
        q, v = run(q0, v0, 1.0 / n, n)
        err.append(np.linalg.norm(np.concatenate([np.asarray(q - ref[0]), np.asarray(v - ref[1])])))
    slopes = np.log2(np.array(err[:-1]) / np.array(err[1:]))
    # measured: 0.87, 0.94, 0.97 (approaching 1 from below)
    assert np.all(np.abs(slopes - 1.0) < 0.2) and abs(slopes[-1] - 1.0) < 0.05, (slopes, err)


@pytest.fixture(scope="module")
def damped():
    m = acrobot_model()
    return m.replace(damping=jnp.array([0.05, 0.2]))


def test_active_path_exact_and_torque_convention(damped):
    """The elbow follows its spline exactly; tau_motor + passive force = inverse dynamics
    on active DoFs, and the passive DoF's inverse-dynamics force is its damper force."""
    spl = QuinticBSpline(8, 1.0)
    ctrl = np.array([0.0, 0.0, 0.4, -0.8, 1.2, 0.3, 0.5, 0.5])[:, None]
    tr = simulate(damped, np.array([0.3, 0.0]), np.array([0.2, 0.0]), t_final=1.0, dt=0.01, active=["elbow"],
                  ctrl=ctrl, spline=spl)
    B0, B1, B2 = spl.basis(tr.t)
    np.testing.assert_allclose(tr.q[:, 1], B0 @ ctrl[:, 0], atol=1e-13)
    np.testing.assert_allclose(tr.v[:, 1], B1 @ ctrl[:, 0], atol=1e-12)
    np.testing.assert_allclose(tr.a[:, 1], B2 @ ctrl[:, 0], atol=1e-10)
    for k in (0, 37, 100):
        id_tau = np.asarray(cs.rnea(damped, tr.q[k], tr.v[k], tr.a[k]))
        pf = np.asarray(cs.passive_forces(damped, tr.q[k], tr.v[k]))
        np.testing.assert_allclose(tr.tau[k, 1] + pf[1], id_tau[1], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(tr.tau[k, 0], pf[0], atol=1e-14)
        np.testing.assert_allclose(id_tau[0], pf[0], rtol=1e-8, atol=1e-9)


def test_divergence_error_names_time_and_joint(damped):
    # the same compiled function as above (bounds are traced): a swinging shoulder
    # exceeds a deliberately low velocity bound
    spl = QuinticBSpline(8, 1.0)
    ctrl = np.zeros((8, 1))
    with pytest.raises(DivergenceError, match=r"diverged at t = 0\.\d+ s .*velocity bound exceeded of joint 'shoulder'"):
        simulate(damped, np.array([1.5, 0.0]), np.array([0.0, 0.0]), t_final=1.0, dt=0.01, active=["elbow"],
                 ctrl=ctrl, spline=spl, v_bound=1.0)


def test_active_joint_must_be_one_dof(free_body):
    with pytest.raises(ProblemError, match="1-DoF"):
        RolloutLayout.make(free_body, ["root"])
    with pytest.raises(ProblemError, match="no joint named"):
        RolloutLayout.make(free_body, ["nope"])


def test_long_rollout_reverse_mode_bounded_memory():
    """20,000 RK4 steps differentiate in reverse mode through the checkpointed nested
    scan; the compiled gradient's temporary memory stays far below storing every step's
    intermediates."""
    b = cs.ModelBuilder("pendulum", gravity=(0.0, 0.0, -9.81))
    b.add_body("rod", None, "revolute", mass=1.0, com=(0.0, 0.0, -0.5), inertia=np.diag([0.08, 0.08, 1e-4]),
               axis=(0.0, 1.0, 0.0), damping=0.01)
    m = b.build()
    lay = RolloutLayout.make(m, ())
    N = 20000
    z = jnp.zeros((N + 1, 0))
    paths = dict(qa=z, va=z, aa=z, qm=z[:-1], vm=z[:-1], am=z[:-1])

    def final_energy(v0):
        r = rollout(m, lay, jnp.array([1.0]), v0, paths, 1e-3, N, record=False)
        return cs.kinetic_energy(m, r["qT"], r["vT"]) + cs.potential_energy(m, r["qT"])

    g = jax.jit(jax.grad(final_energy))
    comp = g.lower(jnp.array([0.5])).compile()
    mem = comp.memory_analysis()
    val = float(comp(jnp.array([0.5]))[0])
    eps = 1e-6
    fe = jax.jit(final_energy)
    fd = (float(fe(jnp.array([0.5 + eps]))) - float(fe(jnp.array([0.5 - eps])))) / (2 * eps)
    assert np.isfinite(val) and abs(val - fd) < 1e-5 * max(1.0, abs(fd)), (val, fd)
    if mem is not None and getattr(mem, "temp_size_in_bytes", None) is not None:
        # measured: 0.47 MB with sqrt(N) ~ 142 segments vs 51.6 MB as one segment;
        # storing all 20,000 steps' stage intermediates would take tens of MB
        assert mem.temp_size_in_bytes < 8e6, mem.temp_size_in_bytes


def test_ball_dropped_on_ground_comes_to_rest():
    """Contact wrenches enter the rollout: a ball dropped from 5 cm settles at the
    contact law's equilibrium depth, and the per-point contact data is recorded."""
    b = cs.ModelBuilder("ball", gravity=(0.0, 0.0, -9.81))
    b.add_link("ball", mass=1.0, inertia=np.eye(3) * 0.004)
    b.add_geom("ball", cs.Sphere(0.1))
    m = b.build(floating_base="free")
    P = cs.ContactParams(stiffness=2000.0, damping=40.0, d_on=0.004, d_off=0.0, friction=0.5)
    env = cs.Environment([cs.ground()])
    q0 = np.array([0.0, 0.0, 0.15, 1.0, 0.0, 0.0, 0.0])
    tr = simulate(m, q0, np.array([0.0, 0.0, 0.0, 0.3, 0.0, 0.0]), t_final=1.5, dt=2e-3, env=env, contact=P)
    d = tr.contact.d[:, 0]
    assert tr.contact.f_ext.shape == (tr.t.size, 1, 6)
    assert d[0] == pytest.approx(0.05, abs=1e-9) and d.min() < 0.0
    # at rest: N = k (d_on - d) = m g in the beta = 1 region
    assert d[-1] == pytest.approx(0.004 - 9.81 / 2000.0, abs=2e-4)
    assert abs(d[-1] - d[-50]) < 1e-5  # stopped bouncing
    # friction turned the initial slide into rolling: the contact point no longer slips
    assert np.linalg.norm(tr.contact.velocity[-1, 0]) < 2e-3 < np.linalg.norm(tr.v[-1, :3])
    assert tr.contact.normal_magnitude[-1, 0] == pytest.approx(9.81, rel=2e-2)
