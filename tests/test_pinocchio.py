"""Dynamics of real URDF robots (example-robot-data) against Pinocchio.

The same URDF is loaded by `cs.load_urdf` and by Pinocchio; joints are matched by name.
Pinocchio's traps, handled by the maps below: continuous joints have nq = 2 (cos, sin);
quaternions are (x, y, z, w); the free-flyer ("root_joint") velocity is
``[v_body; omega_body]`` (cstorm: ``[omega_body; v_body]``); spatial vectors are
``[linear; angular]``; external forces are per joint in the joint's local frame.

Speed: for a handful of configurations, op-by-op evaluation under `jax.vmap` (one
dispatch per primitive for the whole batch) is ~10-50x cheaper than compiling these
unrolled trees with XLA (a 6-DoF arm compiles in ~5-10 s per algorithm on 2 cores, a
38-DoF humanoid in minutes), so each model's quantities are computed once, batched over
`K` random states, in a module-scoped fixture. `test_jit_matches_eager` covers `jit` on a
loaded model.
"""

from __future__ import annotations

import importlib.metadata
import os
import warnings

import numpy as np
import pytest
import jax
import jax.numpy as jnp

import cstorm as cs
from cstorm.model.urdf import load_urdf

pin = pytest.importorskip("pinocchio", reason="Pinocchio (pip install pin) is the reference implementation")

K = 4  # random states per model
TOL = 1e-9  # max |ours - pin| / max(1, max |pin|)


def erd_robots_dir():
    """The `robots` folder of example-robot-data (the cmeel wheel, or the older Python module)."""
    try:
        d = importlib.metadata.distribution("example-robot-data")
        p = d.locate_file("cmeel.prefix/share/example-robot-data/robots")
        if os.path.isdir(p):
            return str(p)
    except importlib.metadata.PackageNotFoundError:
        pass
    try:
        import example_robot_data as erd

        return os.path.join(erd.getModelPath("ur_description/urdf/ur5_robot.urdf"), "..", "robots")
    except Exception:
        return None


ROBOTS = erd_robots_dir()
if ROBOTS is None:
    pytest.skip("example-robot-data is not installed", allow_module_level=True)

# (id, URDF path below robots/, floating base)
MODELS = [
    ("ur5", "ur_description/urdf/ur5_robot.urdf", None),  # fixed-base arm
    ("panda", "panda_description/urdf/panda.urdf", None),  # arm + prismatic fingers (mimic ignored)
    ("kinova", "kinova_description/robots/kinova.urdf", None),  # continuous joints
    ("double_pendulum_continuous", "double_pendulum_description/urdf/double_pendulum_continuous.urdf", None),
    ("solo12", "solo_description/robots/solo12.urdf", "free"),  # floating quadruped
    ("anymal", "anymal_b_simple_description/robots/anymal.urdf", "free"),  # quadruped (lenient inertias)
    ("talos", "talos_data/robots/talos_reduced.urdf", "free"),  # humanoid, nv = 38
]


def pin_joint(pm, name):
    jid = pm.getJointId("root_joint" if name == "root" else name)
    assert jid < pm.njoints, name
    return jid


def velocity_map(model, pm):
    """P (pin nv, nv) with v_pin = P v_cs (tau_cs = P^T tau_pin, M_cs = P^T M_pin P)."""
    P = np.zeros((pm.nv, model.nv))
    for i, (name, j) in enumerate(zip(model.joint_names, model.joints)):
        pj = pm.joints[pin_joint(pm, name)]
        vs = model.v_starts[i]
        if j.nv == 6:  # [omega; v] -> [v; omega]
            P[pj.idx_v: pj.idx_v + 3, vs + 3: vs + 6] = np.eye(3)
            P[pj.idx_v + 3: pj.idx_v + 6, vs: vs + 3] = np.eye(3)
        else:
            assert j.nv == pj.nv == 1, name
            P[pj.idx_v, vs] = 1.0
    assert np.allclose(P @ P.T, np.eye(pm.nv))
    return P


def q_to_pin(model, pm, q):
    qp = pin.neutral(pm)
    for i, (name, j) in enumerate(zip(model.joint_names, model.joints)):
        pj = pm.joints[pin_joint(pm, name)]
        s, t = model.q_starts[i], pj.idx_q
        if j.nq == 7:  # [x y z qw qx qy qz] -> [x y z qx qy qz qw]
            qp[t: t + 3], qp[t + 3: t + 6], qp[t + 6] = q[s: s + 3], q[s + 4: s + 7], q[s + 3]
        elif pj.nq == 2:  # continuous: (cos, sin)
            qp[t], qp[t + 1] = np.cos(q[s]), np.sin(q[s])
        else:
            qp[t] = q[s]
    return qp


def rel_err(ours, ref):
    ours, ref = np.asarray(ours), np.asarray(ref)
    return float(np.abs(ours - ref).max() / max(1.0, np.abs(ref).max()))


def _cs_quantities(model, active, jac_bodies, jac_points):
    def f(q, v, a, tau, fext):
        ia = np.nonzero(active)[0]
        ip = np.nonzero(~np.asarray(active))[0]
        tau_a, a_p = cs.hybrid_dynamics(model, q, v, a[ia], tau[ip], tuple(bool(x) for x in active), fext)
        return dict(
            fk=cs.forward_kinematics(model, q),
            rnea=cs.rnea(model, q, v, a, fext),
            M=cs.mass_matrix(model, q),
            nle=cs.bias_forces(model, q, v),
            aba=cs.aba(model, q, v, tau, fext),
            tau_a=tau_a,
            a_p=a_p,
            jac=jnp.stack([cs.point_jacobian(model, q, b, p) for b, p in zip(jac_bodies, jac_points)]),
        )

    return jax.vmap(f)


@pytest.fixture(scope="module", params=MODELS, ids=[m[0] for m in MODELS])
def case(request):
    """Our quantities and Pinocchio's for K random states of one robot."""
    _, rel, floating = request.param
    path = os.path.join(ROBOTS, rel)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # mimic joints, lenient inertias
        model = load_urdf(path, floating_base=floating, load_meshes=False, inertia_check="lenient")
    pm = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(path)
    pd = pm.createData()
    assert pm.nv == model.nv
    rng = np.random.default_rng(abs(hash(rel)) % 2**32)
    # armature on 1-DoF joints in both (URDFs have none)
    arm = rng.uniform(0.0, 0.05, model.nv) * np.array([j.nv == 1 for j in model.joints for _ in range(j.nv)])
    model = model.replace(armature=jnp.asarray(arm))
    P = velocity_map(model, pm)
    pm.armature = P @ arm

    nb = model.n_bodies
    qs = np.stack([model.random_q(rng) for _ in range(K)])
    vs, as_, taus = (rng.normal(size=(K, model.nv)) for _ in range(3))
    fexts = rng.normal(size=(K, nb, 6))
    active = rng.uniform(size=model.nv) < 0.5
    if floating:
        active[model.joint_v("root")] = False  # a floating base is passive
    active[-1], active[0] = True, False  # at least one of each
    jac_bodies = sorted({0, nb // 2, nb - 1})
    jac_points = rng.uniform(-0.2, 0.2, size=(len(jac_bodies), 3))
    ours = _cs_quantities(model, active, jac_bodies, jac_points)(*(jnp.asarray(x) for x in (qs, vs, as_, taus, fexts)))
    ours = {k: np.asarray(v) for k, v in ours.items()}

    ref = {k: [] for k in ours}
    for k in range(K):
        qp, vp, ap, taup = q_to_pin(model, pm, qs[k]), P @ vs[k], P @ as_[k], P @ taus[k]
        pin.forwardKinematics(pm, pd, qp)
        fext = [pin.Force.Zero() for _ in range(pm.njoints)]
        for i, name in enumerate(model.joint_names):
            jid = pin_joint(pm, name)  # world wrench [torque about origin; force] -> joint-local pin.Force
            fext[jid] = pd.oMi[jid].actInv(pin.Force(fexts[k, i, 3:], fexts[k, i, :3]))
        ref["fk"].append(np.stack([pd.oMi[pin_joint(pm, n)].homogeneous for n in model.joint_names]))
        ref["rnea"].append(P.T @ pin.rnea(pm, pd, qp, vp, ap, fext))
        Mp = pin.crba(pm, pd, qp)
        Mp = np.triu(Mp) + np.triu(Mp, 1).T  # crba fills the upper triangle
        M = P.T @ Mp @ P
        ref["M"].append(M)
        ref["nle"].append(P.T @ pin.nonLinearEffects(pm, pd, qp, vp))
        h = P.T @ pin.rnea(pm, pd, qp, vp, np.zeros(pm.nv), fext)
        ref["aba"].append(P.T @ pin.aba(pm, pd, qp, vp, taup, fext))
        # hybrid: brute-force partitioned solve of M a + h = tau
        ia, ip = np.nonzero(active)[0], np.nonzero(~active)[0]
        a_p = np.linalg.solve(M[np.ix_(ip, ip)], taus[k][ip] - h[ip] - M[np.ix_(ip, ia)] @ as_[k][ia])
        ref["a_p"].append(a_p)
        ref["tau_a"].append(M[np.ix_(ia, ia)] @ as_[k][ia] + M[np.ix_(ia, ip)] @ a_p + h[ia])
        # point Jacobians: pin joint Jacobian (LOCAL_WORLD_ALIGNED, [lin; ang] of the joint origin)
        pin.computeJointJacobians(pm, pd, qp)
        Js = []
        for b, p in zip(jac_bodies, jac_points):
            jid = pin_joint(pm, model.joint_names[b])
            J = pin.getJointJacobian(pm, pd, jid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            r = pd.oMi[jid].rotation @ p
            lin = J[:3] - np.cross(r[:, None], J[3:], axis=0)  # v_point = v_origin + omega x r
            Js.append(np.vstack([J[3:], lin]) @ P)
        ref["jac"].append(np.stack(Js))
    ref = {k: np.stack(v) for k, v in ref.items()}
    return request.param[0], model, ours, ref


@pytest.mark.parametrize("quantity", ["fk", "rnea", "M", "nle", "aba", "tau_a", "a_p", "jac"])
def test_against_pinocchio(case, quantity):
    name, model, ours, ref = case
    err = rel_err(ours[quantity], ref[quantity])
    assert err < TOL, f"{name}: {quantity} differs from Pinocchio by {err:.2e} (relative)"


def test_joint_names_and_limits(case):
    """Same DoFs (name, type, limits) as Pinocchio's model of the same URDF."""
    name, model, _, _ = case
    rel = dict((m[0], m[1]) for m in MODELS)[name]
    floating = dict((m[0], m[2]) for m in MODELS)[name]
    path = os.path.join(ROBOTS, rel)
    pm = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(path)
    assert set(model.joint_names) - {"root"} == set(pm.names[1:]) - {"root_joint"}
    lo, hi = np.asarray(model.q_lower), np.asarray(model.q_upper)
    for i, (jn, j) in enumerate(zip(model.joint_names, model.joints)):
        pj = pm.joints[pin_joint(pm, jn)]
        if j.nq == 1 and pj.nq == 1 and np.isfinite(lo[model.q_starts[i]]):
            assert lo[model.q_starts[i]] == pytest.approx(pm.lowerPositionLimit[pj.idx_q])
            assert hi[model.q_starts[i]] == pytest.approx(pm.upperPositionLimit[pj.idx_q])
            assert float(model.effort_limit[model.v_starts[i]]) == pytest.approx(pm.effortLimit[pj.idx_v])
    total = sum(I.mass for I in pm.inertias[1:])  # [0]: links welded to the world
    assert float(np.sum(model.mass)) == pytest.approx(total, rel=1e-12)


def test_jit_matches_eager():
    """A loaded model is a pytree argument of jitted dynamics."""
    path = os.path.join(ROBOTS, "double_pendulum_description/urdf/double_pendulum_continuous.urdf")
    model = load_urdf(path)
    rng = np.random.default_rng(1)
    q, v, tau = jnp.asarray(model.random_q(rng)), jnp.asarray(rng.normal(size=2)), jnp.asarray(rng.normal(size=2))
    np.testing.assert_allclose(jax.jit(cs.aba)(model, q, v, tau), cs.aba(model, q, v, tau), rtol=1e-12, atol=1e-12)
