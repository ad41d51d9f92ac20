"""Every URDF of example-robot-data against Pinocchio: what Pinocchio loads, cstorm loads
with its default settings, as a fixed base and with a free floating base, and its
dynamics agree.

The test walks the installed package's ``robots`` directory (no hand-picked list). For
each file and base: Pinocchio's ``buildModelFromUrdf`` first; a file Pinocchio refuses is
counted and skipped. cstorm must then load it, or refuse it with a `cstorm.ModelError`
whose reason Pinocchio's own model confirms (no moving joints: ``nv == 0``; singular
dynamics: the named joint's mass-matrix diagonal is zero in Pinocchio's CRBA; an
indefinite body: the named body's inertia has a negative principal moment in Pinocchio's
model). Loaded models are compared at `K` seeded random states: RNEA with external
forces, the mass matrix, bias forces, ABA and the hybrid dynamics (against a partitioned
solve with Pinocchio's M and h). Errors are relative, ``max |ours - pin| / max |pin|``;
ABA and the hybrid's passive accelerations, solves with M, are judged by their normwise
backward error ``max |M (a - a_pin)| / (max |M| max |a_pin| + max |rhs|)``, and by their
forward error too where M is well conditioned (cond(M) <= 1e6; iCub's point-mass legs
give cond(M) ~ 1e8, where a forward error of eps cond(M) is all any solver can promise).

Slow (each model is evaluated op by op, uncompiled: compiling these unrolled trees costs
minutes per large model; 15 min for ~140 models on 2 busy cores, twice that at a load
of 8): run it with ``-m slow -s`` to see each model's errors.
"""

from __future__ import annotations

import os
import re
import warnings

import numpy as np
import pytest
import jax
import jax.numpy as jnp

import cstorm as cs

pin = pytest.importorskip("pinocchio", reason="Pinocchio (pip install pin) is the reference implementation")
from test_pinocchio import ROBOTS, pin_joint, q_to_pin, velocity_map  # noqa: E402

if ROBOTS is None:
    pytest.skip("example-robot-data is not installed", allow_module_level=True)

K = 1  # random states per model and base (each URDF: one fixed-base and one free-base state)
TOL = 1e-12


def _urdf_files():
    return sorted(os.path.join(d, f) for d, _, fs in os.walk(ROBOTS) for f in fs if f.endswith(".urdf"))


def _rel(ours, ref):
    ours, ref = np.asarray(ours), np.asarray(ref)
    return float(np.abs(ours - ref).max() / max(np.abs(ref).max(), 1e-300))


def _backward(M, a, a_ref, rhs):
    """Normwise backward error of ``a`` as a solution of ``M a = rhs``, measured against
    the reference solution: ``max |M (a - a_ref)| / (max |M| max |a_ref| + max |rhs|)``
    (a backward-stable solve has ~1e-16 however ill-conditioned M is)."""
    return float(np.abs(M @ (a - a_ref)).max() / (np.abs(M).max() * np.abs(a_ref).max() + np.abs(rhs).max()))


def _cs_quantities(model, active, q, v, a, tau, fext):
    ia, ip = np.nonzero(active)[0], np.nonzero(~active)[0]
    q, v, a, tau, fext = (jnp.asarray(x) for x in (q, v, a, tau, fext))
    tau_a, a_p = cs.hybrid_dynamics(model, q, v, a[ia], tau[ip], tuple(bool(x) for x in active), fext)
    out = dict(rnea=cs.rnea(model, q, v, a, fext), M=cs.mass_matrix(model, q), aba=cs.aba(model, q, v, tau, fext),
               tau_a=tau_a, a_p=a_p)
    return {k: np.asarray(x) for k, x in out.items()}


def _confirmed_refusal(msg, pm):
    """Why Pinocchio's model confirms cstorm's refusal ``msg``, or None."""
    if "has no moving joints" in msg:
        return "no moving joints" if pm.nv == 0 else None
    m = re.search(r"joint '([^']+)' moves a subtree with no mass or no inertia", msg)
    if m:
        pd = pm.createData()
        M = pin.crba(pm, pd, pin.neutral(pm))
        jid = pm.getJointId(m.group(1))
        if jid < pm.njoints and abs(M[pm.joints[jid].idx_v, pm.joints[jid].idx_v]) <= 1e-12 * np.abs(M).max():
            return "singular"
        return None
    m = re.search(r"body '([^']+)'.*inertia is not positive semi-definite", msg)
    if m:
        name = m.group(1)
        jids = [j for j in range(1, pm.njoints) if pm.frames[pm.getFrameId(name)].parentJoint == j] \
            if pm.existFrame(name) else []
        for j in jids:
            ev = np.linalg.eigvalsh(pm.inertias[j].inertia)
            if ev[0] < -1e-9 * np.abs(ev).max():
                return "indefinite"
        return None
    return None


def _compare(path, floating, rng):
    """Returns the dict of relative errors for one model and base."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", cs.ModelWarning)
        model = cs.load_urdf(path, floating_base=floating)
    pm = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating else pin.buildModelFromUrdf(path)
    pd = pm.createData()
    assert pm.nv == model.nv and pm.nq == model.nq + sum(pm.joints[pin_joint(pm, n)].nq - j.nq
                                                         for n, j in zip(model.joint_names, model.joints))
    P = velocity_map(model, pm)
    nb, nv = model.n_bodies, model.nv
    active = rng.uniform(size=nv) < 0.5
    if floating:
        active[model.joint_v("root")] = False
    active[-1], active[0] = True, False
    ia, ip = np.nonzero(active)[0], np.nonzero(~active)[0]
    err = dict(rnea=0.0, M=0.0, aba=0.0, aba_backward=0.0, tau_a=0.0, a_p=0.0, a_p_backward=0.0)
    for _ in range(K):
        q = model.random_q(rng)
        v, a, tau = (rng.normal(size=nv) for _ in range(3))
        fexts = rng.normal(size=(nb, 6))
        ours = _cs_quantities(model, active, q, v, a, tau, fexts)
        qp, vp, ap, taup = q_to_pin(model, pm, q), P @ v, P @ a, P @ tau
        pin.forwardKinematics(pm, pd, qp)
        fext = [pin.Force.Zero() for _ in range(pm.njoints)]
        for i, name in enumerate(model.joint_names):
            jid = pin_joint(pm, name)
            fext[jid] = pd.oMi[jid].actInv(pin.Force(fexts[i, 3:], fexts[i, :3]))
        Mp = pin.crba(pm, pd, qp)
        M = P.T @ (np.triu(Mp) + np.triu(Mp, 1).T) @ P
        h = P.T @ pin.rnea(pm, pd, qp, vp, np.zeros(pm.nv), fext)
        a_ref = P.T @ pin.aba(pm, pd, qp, vp, taup, fext)
        Mpp = M[np.ix_(ip, ip)]
        rhs = tau[ip] - h[ip] - M[np.ix_(ip, ia)] @ a[ia]
        a_p = np.linalg.solve(Mpp, rhs)
        tau_a = M[np.ix_(ia, ia)] @ a[ia] + M[np.ix_(ia, ip)] @ a_p + h[ia]
        e = dict(
            rnea=_rel(ours["rnea"], P.T @ pin.rnea(pm, pd, qp, vp, ap, fext)),
            M=_rel(ours["M"], M),
            aba=_rel(ours["aba"], a_ref),
            aba_backward=_backward(M, ours["aba"], a_ref, tau - h),
            a_p=_rel(ours["a_p"], a_p),
            a_p_backward=_backward(Mpp, ours["a_p"], a_p, rhs),
            tau_a=_rel(ours["tau_a"], tau_a),
        )
        err = {n: max(err[n], e[n]) for n in err}
    err["cond"] = float(np.linalg.cond(M))
    return err


def _passes(err):
    ok = all(err[n] < TOL for n in ("rnea", "M", "aba_backward", "a_p_backward", "tau_a"))
    # forward errors of the solves: at 1e-12 where M is well conditioned (see the module docstring)
    return ok and (err["cond"] > 1e6 or (err["aba"] < TOL and err["a_p"] < TOL))


@pytest.mark.slow
@pytest.mark.timeout(7200)
def test_every_example_robot_data_urdf_loads_and_matches_pinocchio():
    files = _urdf_files()
    assert len(files) >= 60, f"expected example-robot-data's URDFs under {ROBOTS}, found {len(files)}"
    rng = np.random.default_rng(37)
    pin_refused, loaded, refused, failures, worst = [], [], [], [], {}
    for path in files:
        rel = os.path.relpath(path, ROBOTS)
        for floating in (None, "free"):
            tag = f"{rel} ({'free' if floating else 'fixed'} base)"
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    pm = (pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if floating
                          else pin.buildModelFromUrdf(path))
            except Exception:
                pin_refused.append(tag)
                continue
            try:
                err = _compare(path, floating, rng)
            except cs.ModelError as e:
                why = _confirmed_refusal(str(e), pm)
                (refused if why else failures).append(f"{tag}: {why or 'unconfirmed refusal'}: {e}")
                continue
            loaded.append(tag)
            print(f"  {tag}: nv {pm.nv}, " + ", ".join(f"{n} {x:.1e}" for n, x in err.items()), flush=True)
            for n, x in err.items():
                if x > worst.get(n, (0.0, ""))[0]:
                    worst[n] = (x, tag)
            if not _passes(err):
                failures.append(f"{tag}: dynamics differ from Pinocchio's: "
                                + ", ".join(f"{n} {x:.2e}" for n, x in err.items()))
    n_files = len(files)
    print(f"\nexample-robot-data: {n_files} URDF files x 2 bases; Pinocchio loads {2 * n_files - len(pin_refused)}, "
          f"cstorm loads {len(loaded)}, refuses {len(refused)} (confirmed by Pinocchio's model), fails {len(failures)}")
    for r in refused:
        print("  refused:", r[:300])
    for n, (x, tag) in sorted(worst.items()):
        print(f"  worst {n}: {x:.2e} ({tag})")
    assert not failures, "\n".join(failures)
