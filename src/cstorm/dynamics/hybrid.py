"""Hybrid dynamics: the recursive articulated-body algorithm with some joint
accelerations prescribed (Featherstone, RBDA 9.2 "HD"; Sohl & Bobrow 2001). This is the
paper's ``g``: ``(q, v, a_active, tau_passive, f_ext) -> (tau_active, a_passive)``.

Active DoFs follow a prescribed acceleration and the algorithm returns the force they
need; passive DoFs get a prescribed force and the algorithm returns their acceleration.
With all DoFs passive it is the ABA (forward dynamics); with all active, inverse
dynamics (RNEA). One recursive structure, O(n):

1. outward: body velocities ``v_i``, bias accelerations ``c_i = v_i x (S_i v_j)`` and the
   rigid-body bias forces ``pA_i = v_i x* I_i v_i - f_ext_i``;
2. inward: articulated inertias. A joint's known accelerations enter as part of its bias,
   ``c'_i = c_i + S_a qdd_a``; its passive DoFs are articulated as in the ABA
   (``U = IA S_p``, ``D = S_p^T U + armature``, ``u = tau_p - S_p^T pA``); a fully active
   joint passes its subtree's inertia through rigidly;
3. outward: accelerations ``a_i = X_i a_parent + c'_i + S_p qdd_p`` with
   ``qdd_p = D^-1 (u - U^T (X_i a_parent + c'_i))``;
4. active forces ``tau_a = S_a^T (IA_i a_i + pA_i) + armature qdd_a``: ``IA_i a_i + pA_i``
   is the whole force transmitted across joint i, so no further pass is needed.

Body-local frames throughout (as `rnea`). Gravity enters as the world's acceleration.
"""

from __future__ import annotations

import numpy as np
import jax
import jax.numpy as jnp

from .. import spatial as sp
from . import _checks
from .kinematics import joint_placements, world_placements
from .rnea import body_spatial_inertias, external_wrenches_local, gravity_acceleration


def hybrid_dynamics(model, q, v, a_active, tau_passive, active, f_ext=None):
    """Hybrid dynamics.

    Args:
        q: (nq,). v: (nv,).
        a_active: (n_active,) prescribed accelerations of the active DoFs, in v order.
        tau_passive: (n_passive,) prescribed generalized forces of the passive DoFs.
        active: static tuple of nv bools, True for active DoFs (`Model.active_mask`).
        f_ext: optional (n_bodies, 6) world wrenches ``[torque about world origin; force]``.
    Returns:
        (tau_active (n_active,), a_passive (n_passive,)).
    """
    q, v, a_active, tau_passive, active, f_ext = _checks.hybrid_inputs(model, q, v, a_active, tau_passive, active,
                                                                      f_ext, "hybrid_dynamics")
    return hybrid_unchecked(model, q, v, a_active, tau_passive, active, f_ext)


def aba(model, q, v, tau, f_ext=None):
    """Forward dynamics by the articulated-body algorithm: a (nv,) from q (nq,), v (nv,),
    tau (nv,) and optional world wrenches f_ext (n_bodies, 6)."""
    q = _checks.config(model, q, "aba")
    v = _checks.vec(model, v, model.nv, "v", "aba")
    tau = _checks.vec(model, tau, model.nv, "tau", "aba")
    f_ext = _checks.fext(model, f_ext, "aba")
    return hybrid_unchecked(model, q, v, jnp.zeros(0, dtype=v.dtype), tau, (False,) * model.nv, f_ext)[1]


@jax.custom_jvp
def small_spd_inverse(D):
    """Inverse of a small symmetric positive definite matrix ``D`` (n, n), n <= 6 (a
    multi-DoF joint's articulated inertia ``S^T IA S``: a free joint's 6x6), by Cholesky
    ``D = L L^T`` written out entry by entry: ``D^-1 = L^-T L^-1``. Scalar operations that
    XLA fuses into one elementwise loop under `vmap`; `jnp.linalg.inv` there becomes a
    batched LU call per matrix, which made ABA on a free-floating 38-DoF humanoid 1.6x
    slower than on the same robot fixed. Symmetric output."""
    n = D.shape[0]
    L = [[None] * n for _ in range(n)]
    for j in range(n):
        s = D[j, j]
        for k in range(j):
            s = s - L[j][k] * L[j][k]
        L[j][j] = jnp.sqrt(s)
        inv = 1.0 / L[j][j]
        for i in range(j + 1, n):
            s = D[i, j]
            for k in range(j):
                s = s - L[i][k] * L[j][k]
            L[i][j] = s * inv
    W = [[None] * n for _ in range(n)]  # W = L^-1, lower triangular
    for i in range(n):
        W[i][i] = 1.0 / L[i][i]
        for j in range(i):
            s = L[i][j] * W[j][j]
            for k in range(j + 1, i):
                s = s + L[i][k] * W[k][j]
            W[i][j] = -s * W[i][i]
    out = [[None] * n for _ in range(n)]
    for i in range(n):
        for j in range(i, n):
            s = W[j][i] * W[j][j]
            for k in range(j + 1, n):
                s = s + W[k][i] * W[k][j]
            out[i][j] = out[j][i] = s
    return jnp.stack([jnp.stack(row) for row in out])


@small_spd_inverse.defjvp
def _small_spd_inverse_jvp(primals, tangents):
    # d(D^-1) = -D^-1 dD D^-1: two small products instead of differentiating the
    # unrolled factorization entry by entry (whose tangent graph made the compile of
    # forward-mode Jacobians of a humanoid's dynamics run for many minutes)
    X = small_spd_inverse(primals[0])
    return X, -sp.mm(sp.mm(X, tangents[0]), X)


def _scatter(active, a_active, tau_passive):
    """Full-length (nv,) vectors of prescribed accelerations / forces (zeros elsewhere)
    and index arrays of the active and passive DoFs."""
    act = np.array(active, dtype=bool)
    ia, ip = np.nonzero(act)[0], np.nonzero(~act)[0]
    nv = len(active)
    dtype = jnp.result_type(a_active, tau_passive)
    qdd = jnp.zeros(nv, dtype=dtype).at[ia].set(a_active)
    tau = jnp.zeros(nv, dtype=dtype).at[ip].set(tau_passive)
    return qdd, tau, ia, ip


def hybrid_unchecked(model, q, v, a_active, tau_passive, active, f_ext):
    """`hybrid_dynamics` without input checks (``active`` a static tuple, arrays of the right
    shapes): for callers inside compiled code that checked their inputs once."""
    nb = model.n_bodies
    qdd_known, tau_known, ia, ip = _scatter(active, a_active, tau_passive)
    Rs, ps, Ss = joint_placements(model, q)
    fl = external_wrenches_local(model, *world_placements(model, Rs, ps), f_ext) if f_ext is not None else [None] * nb
    I = body_spatial_inertias(model)

    # per joint: local indices of its active and passive DoFs (static)
    sl, loc_a, loc_p = [], [], []
    for i, j in enumerate(model.joints):
        s = model.v_starts[i]
        sl.append(slice(s, s + j.nv))
        loc_a.append([k for k in range(j.nv) if active[s + k]])
        loc_p.append([k for k in range(j.nv) if not active[s + k]])

    eye_S = [j.name == "free" and len(loc_p[i]) == 6 for i, j in enumerate(model.joints)]

    # pass 1: velocities, bias terms
    vs, cs_, IA, pA = [], [], [], []
    for i, par in enumerate(model.parents):
        vJ = sp.mv(Ss[i], v[sl[i]])
        vi = vJ if par < 0 else sp.inv_act_motion(Rs[i], ps[i], vs[par]) + vJ
        ci = sp.cross_motion(vi, vJ)
        if loc_a[i]:
            ci = ci + sp.mv(Ss[i][:, loc_a[i]], qdd_known[sl[i]][jnp.array(loc_a[i])])
        pi = sp.cross_force(vi, sp.mv(I[i], vi))
        if fl[i] is not None:
            pi = pi - fl[i]
        vs.append(vi), cs_.append(ci), IA.append(I[i]), pA.append(pi)

    # pass 2: articulated inertias, inward
    U, Dinv, u = [None] * nb, [None] * nb, [None] * nb
    for i in reversed(range(nb)):
        par = model.parents[i]
        if loc_p[i]:
            lp = jnp.array(loc_p[i])
            Sp = Ss[i][:, loc_p[i]]
            # a wholly passive free joint has S = I (body-frame twist): no products with it
            U[i] = IA[i] if eye_S[i] else sp.mm(IA[i], Sp)
            D = (U[i] if eye_S[i] else sp.mm(Sp.T, U[i])) + jnp.diag(model.armature[sl[i]][lp])
            Dinv[i] = small_spd_inverse(D) if len(loc_p[i]) > 1 else 1.0 / D
            u[i] = tau_known[sl[i]][lp] - (pA[i] if eye_S[i] else sp.mv(Sp.T, pA[i]))
            if par >= 0:
                UD = sp.mm(U[i], Dinv[i])
                Ia = IA[i] - sp.mm(UD, U[i].T)
                pa = pA[i] + sp.mv(Ia, cs_[i]) + sp.mv(UD, u[i])
        elif par >= 0:
            Ia = IA[i]
            pa = pA[i] + sp.mv(IA[i], cs_[i])
        if par >= 0:
            IA[par] = IA[par] + sp.transform_inertia(Rs[i], ps[i], Ia)
            pA[par] = pA[par] + sp.act_force(Rs[i], ps[i], pa)

    # pass 3: accelerations, outward; pass 4: active forces
    a0 = gravity_acceleration(model)
    acc = [None] * nb
    out = [None] * nb
    for i, par in enumerate(model.parents):
        ai = sp.inv_act_motion(Rs[i], ps[i], a0 if par < 0 else acc[par]) + cs_[i]
        parts = []  # (local DoF indices, values) of this joint's outputs
        if loc_p[i]:
            qp = sp.mv(Dinv[i], u[i] - sp.mv(U[i].T, ai))
            ai = ai + (qp if eye_S[i] else sp.mv(Ss[i][:, loc_p[i]], qp))
            parts.append((loc_p[i], qp))
        if loc_a[i]:
            la = jnp.array(loc_a[i])
            f = sp.mv(IA[i], ai) + pA[i]
            ta = sp.mv(Ss[i][:, loc_a[i]].T, f) + model.armature[sl[i]][la] * qdd_known[sl[i]][la]
            parts.append((loc_a[i], ta))
        acc[i] = ai
        if len(parts) == 1:
            out[i] = parts[0][1]
        else:  # a joint with both active and passive DoFs
            out[i] = jnp.zeros(model.joints[i].nv, dtype=ai.dtype)
            for idx, val in parts:
                out[i] = out[i].at[jnp.array(idx)].set(val)
    y = jnp.concatenate(out)
    return _take(y, ia), _take(y, ip)


def _take(y, idx):
    """``y[idx]`` for a static index array; a plain slice when idx is contiguous (the
    whole vector in ABA) instead of a gather."""
    if len(idx) and np.array_equal(idx, np.arange(idx[0], idx[0] + len(idx))):
        return y[int(idx[0]): int(idx[0]) + len(idx)]
    return y[idx]
