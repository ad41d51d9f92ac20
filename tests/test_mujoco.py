"""Gymnasium's MJCF models, loaded by `cs.load_mjcf`, against MuJoCo itself.

cstorm's q is MuJoCo's qpos; velocities differ only for free joints (cstorm
``[omega_body; v_body]``, MuJoCo ``[v_world; omega_body]``), converted with
`cstorm.model.mjcf.qvel_from_v` and friends: ``qvel = T(q) v``, ``qacc = T a + Tdot v``,
``tau = T^T qfrc``, ``M_cs = T^T M_mj T``. Rigid-body quantities are compared with
MuJoCo's constraints, actuation, springs and dampers disabled; passive forces
separately. Body frames: a cstorm body frame sits at its last joint's anchor; the MJCF
body frame is the named frame ``"<body>/origin"`` (compared with ``xpos``/``xquat``).

As in test_pinocchio.py, each model's quantities are computed once, op by op under
`jax.vmap` over K random states (cheaper than compiling the unrolled trees).
"""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest
import jax
import jax.numpy as jnp

import cstorm as cs

mujoco = pytest.importorskip("mujoco", reason="MuJoCo (pip install mujoco) is the reference implementation")
gymnasium = pytest.importorskip("gymnasium", reason="Gymnasium ships the MJCF models compared here")

from cstorm.model.mjcf import load_mjcf, qacc_from_a, qvel_from_v, tau_from_qfrc, v_from_qvel  # noqa: E402

ASSETS = os.path.join(os.path.dirname(gymnasium.__file__), "envs", "mujoco", "assets")
MODELS = ["hopper", "walker2d", "half_cheetah", "ant", "humanoid", "inverted_double_pendulum", "reacher"]
K = 4
TOL = 1e-9
D = mujoco.mjtDisableBit


def rel_err(ours, ref):
    ours, ref = np.asarray(ours), np.asarray(ref)
    return float(np.abs(ours - ref).max() / max(1.0, np.abs(ref).max()))


def mj_body_ids(m):
    """cstorm's names of MuJoCo bodies (unnamed ones are "body<i>") -> MuJoCo body id."""
    return {(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, i) or f"body{i}"): i for i in range(m.nbody)}


def T_matrix(model, q):
    """(nv, nv) T with qvel = T v."""
    return np.stack([qvel_from_v(model, q, e) for e in np.eye(model.nv)], axis=1)


@pytest.fixture(scope="module", params=MODELS)
def case(request):
    path = os.path.join(ASSETS, request.param + ".xml")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = load_mjcf(path)
        m = mujoco.MjModel.from_xml_path(path)
    m.opt.disableflags |= D.mjDSBL_CONSTRAINT | D.mjDSBL_ACTUATION | D.mjDSBL_SPRING | D.mjDSBL_DAMPER
    d = mujoco.MjData(m)
    rng = np.random.default_rng(len(request.param))
    nb = model.n_bodies
    qs = np.stack([model.random_q(rng) for _ in range(K)])
    vs, as_, taus = (rng.normal(size=(K, model.nv)) for _ in range(3))
    origin_frames = [n for n in mj_body_ids(m) if n + "/origin" in model.frame_names]
    jac_bodies = sorted({0, nb // 2, nb - 1})
    jac_points = rng.uniform(-0.2, 0.2, size=(len(jac_bodies), 3))

    frames = [model.frame_pose(n + "/origin") for n in origin_frames]  # (body, body-from-frame)

    def f(q, v, a, tau):
        fk = cs.forward_kinematics(model, q)  # once; cs.frame_pose would redo it per frame
        return dict(
            frames=jnp.stack([fk[b] @ P if b >= 0 else P for b, P in frames]),
            fk=fk,
            M=cs.mass_matrix(model, q),
            bias=cs.bias_forces(model, q, v),
            rnea=cs.rnea(model, q, v, a),
            aba=cs.aba(model, q, v, tau),
            passive=cs.passive_forces(model, q, v),
            jac=jnp.stack([cs.point_jacobian(model, q, b, p) for b, p in zip(jac_bodies, jac_points)]),
        )

    ours = jax.vmap(f)(*(jnp.asarray(x) for x in (qs, vs, as_, taus)))
    ours = {k: np.asarray(v) for k, v in ours.items()}

    ids = mj_body_ids(m)
    ref = {k: [] for k in ours}
    for k in range(K):
        q, v, a, tau = qs[k], vs[k], as_[k], taus[k]
        T = T_matrix(model, q)
        d.qpos[:], d.qvel[:], d.qacc[:] = q, qvel_from_v(model, q, v), qacc_from_a(model, q, v, a)
        d.qfrc_applied[:] = np.linalg.solve(T.T, tau)  # tau = T^T qfrc
        mujoco.mj_forward(m, d)
        Mf = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, Mf)
        ref["M"].append(T.T @ Mf @ T)
        # h_cs = T^T (h_mj + M_mj Tdot v): qacc = T a + Tdot v
        ref["bias"].append(T.T @ (d.qfrc_bias + Mf @ qacc_from_a(model, q, v, np.zeros(model.nv))))
        ref["aba"].append(v_from_qvel(model, q, d.qacc - qacc_from_a(model, q, v, np.zeros(model.nv))))
        poses = []
        for n in origin_frames:
            P = np.eye(4)
            P[:3, :3], P[:3, 3] = d.xmat[ids[n]].reshape(3, 3), d.xpos[ids[n]]
            poses.append(P)
        ref["frames"].append(np.stack(poses))
        # cstorm body i: MJCF body's orientation, origin at its last joint's anchor
        fk = []
        for i, name in enumerate(model.body_names):
            jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, model.joint_names[i])
            P = np.eye(4)
            if name in ids:
                P[:3, :3] = d.xmat[ids[name]].reshape(3, 3)
            else:  # intermediate body of a multi-joint chain: no MuJoCo counterpart
                P[:3, :3] = np.asarray(ours["fk"][k, i, :3, :3])
            is_slide_or_free = int(m.jnt_type[jid]) in (int(mujoco.mjtJoint.mjJNT_SLIDE), int(mujoco.mjtJoint.mjJNT_FREE))
            P[:3, 3] = d.xpos[ids[name]] if (is_slide_or_free and name in ids) else d.xanchor[jid]
            if name not in ids and is_slide_or_free:
                P[:3, 3] = ours["fk"][k, i, :3, 3]
            fk.append(P)
        ref["fk"].append(np.stack(fk))
        Js = []
        for b, p in zip(jac_bodies, jac_points):
            Pw = ours["fk"][k, b] @ np.append(p, 1.0)
            jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
            bid = ids.get(model.body_names[b])
            if bid is None:  # intermediate body of a joint chain: no MuJoCo body to ask
                Js.append(np.asarray(ours["jac"][k, len(Js)]))
                continue
            mujoco.mj_jac(m, d, jacp, jacr, Pw[:3], bid)
            Js.append(np.vstack([jacr, jacp]) @ T)
        ref["jac"].append(np.stack(Js))
        d.qacc[:] = qacc_from_a(model, q, v, a)  # (mj_forward overwrote it)
        mujoco.mj_inverse(m, d)  # constraints and passive forces disabled
        ref["rnea"].append(tau_from_qfrc(model, q, d.qfrc_inverse))
        # passive forces with springs and dampers on (MuJoCo's own function)
        m.opt.disableflags &= ~(D.mjDSBL_SPRING | D.mjDSBL_DAMPER)
        mujoco.mj_fwdPosition(m, d)
        mujoco.mj_fwdVelocity(m, d)
        ref["passive"].append(tau_from_qfrc(model, q, d.qfrc_passive))
        m.opt.disableflags |= D.mjDSBL_SPRING | D.mjDSBL_DAMPER
    ref = {k: np.stack(v) for k, v in ref.items()}
    return request.param, model, m, ours, ref


@pytest.mark.parametrize("quantity", ["frames", "fk", "M", "bias", "rnea", "aba", "passive", "jac"])
def test_against_mujoco(case, quantity):
    name, model, m, ours, ref = case
    err = rel_err(ours[quantity], ref[quantity])
    assert err < TOL, f"{name}: {quantity} differs from MuJoCo by {err:.2e} (relative)"


def test_model_data(case):
    """Sizes, q order, gravity, masses, armature and damping are MuJoCo's."""
    name, model, m, _, _ = case
    assert (model.nq, model.nv) == (m.nq, m.nv)
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt)]
    assert list(model.joint_names) == names
    assert [model.joint_q(n).start for n in names] == list(m.jnt_qposadr)
    np.testing.assert_allclose(model.gravity, m.opt.gravity)
    np.testing.assert_allclose(float(np.sum(model.mass)), float(np.sum(m.body_mass)), rtol=1e-12)
    np.testing.assert_allclose(model.armature, m.dof_armature)
    np.testing.assert_allclose(model.damping, m.dof_damping)
    lo, hi = np.asarray(model.q_lower), np.asarray(model.q_upper)
    for j in range(m.njnt):
        if m.jnt_limited[j] and int(m.jnt_type[j]) in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            a = m.jnt_qposadr[j]
            assert (lo[a], hi[a]) == pytest.approx(tuple(m.jnt_range[j]))


def test_free_joint_velocity_maps_roundtrip():
    model = load_mjcf(os.path.join(ASSETS, "ant.xml"))
    rng = np.random.default_rng(0)
    q, v = model.random_q(rng), rng.normal(size=model.nv)
    np.testing.assert_allclose(v_from_qvel(model, q, qvel_from_v(model, q, v)), v, atol=1e-14)
    # kinetic energy is convention-free: 1/2 v^T M_cs v == 1/2 qvel^T M_mj qvel
    m = mujoco.MjModel.from_xml_path(os.path.join(ASSETS, "ant.xml"))
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = q, qvel_from_v(model, q, v)
    mujoco.mj_forward(m, d)
    Mf = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, Mf)
    assert float(cs.kinetic_energy(model, jnp.asarray(q), jnp.asarray(v))) == pytest.approx(
        0.5 * d.qvel @ Mf @ d.qvel, rel=1e-12)


def test_hopper_ref_shifts_zero():
    """Hopper's rootz has ref=1.25: at q = qpos0 the torso is where the XML puts it."""
    model = load_mjcf(os.path.join(ASSETS, "hopper.xml"))
    m = mujoco.MjModel.from_xml_path(os.path.join(ASSETS, "hopper.xml"))
    assert m.qpos0[model.joint_q("rootz")][0] == 1.25
    T = cs.frame_pose(model, jnp.asarray(m.qpos0), "torso/origin")
    np.testing.assert_allclose(T[:3, 3], [0.0, 0.0, 1.25], atol=1e-12)
    T0 = cs.frame_pose(model, jnp.zeros(model.nq), "torso/origin")
    np.testing.assert_allclose(T0[:3, 3], [0.0, 0.0, 0.0], atol=1e-12)


def test_geoms_converted():
    model = load_mjcf(os.path.join(ASSETS, "hopper.xml"))
    m = mujoco.MjModel.from_xml_path(os.path.join(ASSETS, "hopper.xml"))
    floor = model.geom_names.index("floor")
    assert model.geom_bodies[floor] == -1 and isinstance(model.geoms[floor], cs.Plane)
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "thigh_geom")
    k = model.geom_names.index("thigh_geom")
    assert isinstance(model.geoms[k], cs.Capsule)
    assert float(model.geoms[k].radius) == pytest.approx(m.geom_size[g, 0])
    assert float(model.geoms[k].length) == pytest.approx(2 * m.geom_size[g, 1])
    # world pose of the geom at a random q equals MuJoCo's geom_xpos/geom_xmat
    d = mujoco.MjData(m)
    q = model.random_q(np.random.default_rng(3))
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    Tg = cs.forward_kinematics(model, jnp.asarray(q))[model.geom_bodies[k]] @ model.geom_poses[k]
    np.testing.assert_allclose(Tg[:3, 3], d.geom_xpos[g], atol=1e-12)
    np.testing.assert_allclose(Tg[:3, :3], d.geom_xmat[g].reshape(3, 3), atol=1e-12)


def test_every_gymnasium_model_loads():
    """Every MJCF Gymnasium ships loads; what cstorm does not model is named in one
    warning (humanoid's tendons, swimmer's fluid forces) and nothing else is; the mass
    matrix matches MuJoCo's at a random state (the models not compared above)."""
    files = sorted(f for f in os.listdir(ASSETS) if f.endswith(".xml"))
    assert len(files) >= 12
    expected = {"humanoid.xml": "<tendon> ['left_hipknee', 'right_hipknee']",
                "humanoidstandup.xml": "<tendon> ['left_hipknee', 'right_hipknee']",
                "swimmer.xml": "fluid forces are not modelled"}
    rng = np.random.default_rng(12)
    for f in files:
        path = os.path.join(ASSETS, f)
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            model = load_mjcf(path)
        msgs = [str(x.message) for x in w if issubclass(x.category, cs.ModelWarning)]
        if f in expected:
            assert len(msgs) == 1 and expected[f] in msgs[0], (f, msgs)
            with pytest.raises(cs.ModelError, match="strict=True"):
                load_mjcf(path, strict=True)
        else:
            assert msgs == [], (f, msgs)
        if f[:-4] in MODELS:
            continue
        m = mujoco.MjModel.from_xml_path(path)
        d = mujoco.MjData(m)
        q = model.random_q(rng)
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        Mf = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, Mf)
        T = T_matrix(model, q)
        assert rel_err(cs.mass_matrix(model, jnp.asarray(q)), T.T @ Mf @ T) < TOL, f
