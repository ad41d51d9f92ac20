"""Analytic derivatives of RNEA, ABA and the hybrid dynamics (the paper's ``dg``).

(placeholder: dispatches to the autodiff reference until the analytic algorithms land)
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .. import spatial as sp
from . import _checks
from .kinematics import joint_placements, world_placements
from .rnea import gravity_acceleration


class HybridDerivatives(NamedTuple):
    """Value and Jacobians of the hybrid dynamics ``y = g(q, v, a_active, tau_passive, f_ext)``.

    y (nv,): tau_active in the active rows, a_passive in the passive rows (v order).
    dq (nv, nv): w.r.t. a tangent perturbation ``q (+) dq``. dv (nv, nv).
    da_active (nv, n_active). dtau_passive (nv, n_passive).
    df_ext (nv, n_bodies, 6): w.r.t. the world wrenches ``[torque about world origin; force]``.
    """

    y: jnp.ndarray
    dq: jnp.ndarray
    dv: jnp.ndarray
    da_active: jnp.ndarray
    dtau_passive: jnp.ndarray
    df_ext: jnp.ndarray


class RNEADerivatives(NamedTuple):
    """``tau = rnea(q, v, a, f_ext)`` (nv,) and its Jacobians: dq (nv, nv) w.r.t. ``q (+) dq``,
    dv (nv, nv), da (nv, nv) (= the mass matrix M, armature included), df_ext (nv, n_bodies, 6)."""

    tau: jnp.ndarray
    dq: jnp.ndarray
    dv: jnp.ndarray
    da: jnp.ndarray
    df_ext: jnp.ndarray


class ABADerivatives(NamedTuple):
    """``a = aba(q, v, tau, f_ext)`` (nv,) and its Jacobians: dq (nv, nv) w.r.t. ``q (+) dq``,
    dv (nv, nv), dtau (nv, nv) (= M^-1), df_ext (nv, n_bodies, 6)."""

    a: jnp.ndarray
    dq: jnp.ndarray
    dv: jnp.ndarray
    dtau: jnp.ndarray
    df_ext: jnp.ndarray


def _validate(model, q, v, a_active, tau_passive, active, f_ext, fn):
    active = _checks.active(model, active, fn)
    q = _checks.config(model, q, fn)
    v = _checks.vec(model, v, model.nv, "v", fn)
    na = sum(active)
    a_active = _checks.vec(model, a_active, na, "a_active", fn)
    tau_passive = _checks.vec(model, tau_passive, model.nv - na, "tau_passive", fn)
    f_ext = _checks.fext(model, f_ext, fn)
    return q, v, a_active, tau_passive, active, f_ext



# ============================================================================ analytic core
def _force_cross_matrix(h):
    """(6, 6) matrix ``B(h)`` with ``B(h) @ x == x x* h`` for any twist x:
    ``-[[ [n]x, [f]x ], [ [f]x, 0 ]]`` for ``h = [n; f]``."""
    n, f = sp.skew(h[:3]), sp.skew(h[3:])
    return -jnp.block([[n, f], [f, jnp.zeros((3, 3), dtype=h.dtype)]])


def _cross_force_cols(X, h):
    """Columns ``x x* h`` (6, k) for twists X (6, k) and one wrench h (6,): ``B(h) @ X``."""
    w, u = X[:3], X[3:]
    return jnp.concatenate([sp._cross3(w, h[:3]) + sp._cross3(u, h[3:]), sp._cross3(w, h[3:])])


class _Kin(NamedTuple):
    """Configuration- and velocity-dependent terms in world coordinates (lists over
    bodies; twists and wrenches about the world origin)."""

    J: list  # (6, nv_i) joint motion subspace
    ov: list  # (6,) body twists
    vJ: list  # (6,) joint twists J_i v_i
    oI: list  # (6, 6) body inertias
    h: list  # (6,) body momenta oI ov
    dVdq: list  # (6, nv_i) ov_parent x J_i, None at roots
    dAdv: list  # (6, nv_i) (ov_i + ov_parent) x J_i
    Ycrb: list  # (6, 6) composite (subtree) inertias
    doYcrb: list  # (6, 6) subtree sums of  ov x* oI - oI (ov x) + B(h)
    Fext: list  # (6,) subtree sums of the external wrenches, or None


def _kinematics(model, q, v, f_ext):
    nb = model.n_bodies
    Rs, ps, Ss = joint_placements(model, q)
    oR, op = world_placements(model, Rs, ps)
    J, ov, vJ, oI, h, dVdq, dAdv, dY = [], [], [], [], [], [], [], []
    for i, par in enumerate(model.parents):
        s = model.v_starts[i]
        Ji = sp.act_motion(oR[i], op[i], Ss[i])
        vJi = sp.mv(Ji, v[s: s + model.joints[i].nv])
        if par < 0:
            ovi = vJi
            dVdq.append(None)
            dAdv.append(sp.cross_motion(ovi, Ji))
        else:
            ovi = ov[par] + vJi
            dVdq.append(sp.cross_motion(ov[par], Ji))
            dAdv.append(sp.cross_motion(ovi + ov[par], Ji))
        c = sp.mv(oR[i], model.com[i]) + op[i]
        Ic = sp.mm(sp.mm(oR[i], model.inertia[i]), oR[i].T)
        oIi = sp.spatial_inertia(model.mass[i], c, Ic)
        hi = sp.mv(oIi, ovi)
        X = sp.mm(oIi, sp.ad(ovi))
        J.append(Ji), ov.append(ovi), vJ.append(vJi), oI.append(oIi), h.append(hi)
        dY.append(_force_cross_matrix(hi) - X - X.T)
    Y = list(oI)
    Fext = [f_ext[i] for i in range(nb)] if f_ext is not None else [None] * nb
    for i in reversed(range(nb)):
        par = model.parents[i]
        if par >= 0:
            Y[par] = Y[par] + Y[i]
            dY[par] = dY[par] + dY[i]
            if f_ext is not None:
                Fext[par] = Fext[par] + Fext[i]
    return _Kin(J, ov, vJ, oI, h, dVdq, dAdv, Y, dY, Fext)


def _dynamics(model, kin, a, f_ext):
    """World accelerations oa (gravity included: the world accelerates at ``[0; -g]``),
    subtree forces F (external wrenches subtracted) and tau = J^T F + armature a."""
    nb = model.n_bodies
    a0 = gravity_acceleration(model)
    oa, F = [], []
    for i, par in enumerate(model.parents):
        s = model.v_starts[i]
        oai = (a0 if par < 0 else oa[par]) + sp.mv(kin.J[i], a[s: s + model.joints[i].nv]) + sp.cross_motion(kin.ov[i], kin.vJ[i])
        fi = sp.mv(kin.oI[i], oai) + sp.cross_force(kin.ov[i], kin.h[i])
        if f_ext is not None:
            fi = fi - f_ext[i]
        oa.append(oai), F.append(fi)
    for i in reversed(range(nb)):
        par = model.parents[i]
        if par >= 0:
            F[par] = F[par] + F[i]
    tau = jnp.concatenate([sp.mv(kin.J[i].T, F[i]) for i in range(nb)]) + model.armature * a
    return oa, F, tau


def _mass_matrix(model, kin):
    """M (nv, nv) from the world Jacobian columns and composite inertias:
    ``M_jk = J_j^T Ycrb_k J_k`` for j an ancestor of k (or k itself)."""
    nb = model.n_bodies
    A = [sp.mm(kin.Ycrb[k], kin.J[k]) for k in range(nb)]
    blocks = [[None] * nb for _ in range(nb)]
    for k in range(nb):
        j = k
        while j >= 0:
            blk = sp.mm(kin.J[j].T, A[k])
            blocks[j][k] = blk
            if j != k:
                blocks[k][j] = blk.T
            j = model.parents[j]
    M = _assemble(model, blocks)
    return M + jnp.diag(model.armature), A


def _assemble(model, blocks):
    """Dense (nv, nv) matrix from per-joint blocks (None = zero)."""
    nb = model.n_bodies
    dtype = next(b for row in blocks for b in row if b is not None).dtype
    rows = []
    for j in range(nb):
        nj = model.joints[j].nv
        rows.append(jnp.concatenate(
            [blocks[j][k] if blocks[j][k] is not None else jnp.zeros((nj, model.joints[k].nv), dtype=dtype)
             for k in range(nb)], axis=1))
    return jnp.concatenate(rows, axis=0)


def _rnea_partials(model, kin, A, oa, F, f_ext):
    """dtau/dq (tangent), dtau/dv (nv, nv) and dtau/df_ext (nv, nb, 6) at the
    accelerations oa and subtree forces F of `_dynamics` (Carpentier & Mansard 2018,
    world-frame form, with world-fixed external wrenches)."""
    nb = model.n_bodies
    par = model.parents
    J, Y, dY = kin.J, kin.Ycrb, kin.doYcrb
    a0 = gravity_acceleration(model)
    dAdq, dFdq, dFdv, Bv, dFdq_anc, dFdq_own, E = [], [], [], [], [], [], []
    for k in range(nb):
        p = par[k]
        if p < 0:
            dAdq_k = sp.cross_motion(a0, J[k])
            dFdq_k = sp.mm(Y[k], dAdq_k)
        else:
            dAdq_k = sp.cross_motion(oa[p], J[k]) + sp.cross_motion(kin.ov[p], kin.dVdq[k])
            dFdq_k = sp.mm(dY[k], kin.dVdq[k]) + sp.mm(Y[k], dAdq_k)
        dAdq.append(dAdq_k), dFdq.append(dFdq_k)
        dFdv.append(sp.mm(dY[k], J[k]) + sp.mm(Y[k], kin.dAdv[k]))
        Bv.append(sp.mm(dY[k].T, J[k]))
        if f_ext is not None:
            G = F[k] + kin.Fext[k]
            BF = _cross_force_cols(J[k], kin.Fext[k])  # B(Fext) J;  B(h)^T = -B(h)
            dFdq_anc.append(dFdq_k + _cross_force_cols(J[k], G))
            dFdq_own.append(dFdq_k + BF)
            E.append(-BF)
        else:
            dFdq_anc.append(dFdq_k + _cross_force_cols(J[k], F[k]))
            dFdq_own.append(dFdq_k)
            E.append(None)
    bq = [[None] * nb for _ in range(nb)]
    bv = [[None] * nb for _ in range(nb)]
    for k in range(nb):
        # rows of k and of its ancestors j, column k
        bq[k][k] = sp.mm(J[k].T, dFdq_own[k])
        bv[k][k] = sp.mm(J[k].T, dFdv[k])
        j = par[k]
        while j >= 0:
            bq[j][k] = sp.mm(J[j].T, dFdq_anc[k])
            bv[j][k] = sp.mm(J[j].T, dFdv[k])
            # row k (descendant), column j (ancestor)
            lq = sp.mm(A[k].T, dAdq[j]) + (sp.mm(Bv[k].T, kin.dVdq[j]) if kin.dVdq[j] is not None else 0.0)
            if E[k] is not None:
                lq = lq + sp.mm(E[k].T, J[j])
            bq[k][j] = lq
            bv[k][j] = sp.mm(A[k].T, kin.dAdv[j]) + sp.mm(Bv[k].T, J[j])
            j = par[j]
    dq = _assemble(model, bq)
    dv = _assemble(model, bv)
    # dtau_j / df_ext_b = -J_j^T for b in the subtree of j
    sub = np.zeros((nb, nb))
    for b in range(nb):
        j = b
        while j >= 0:
            sub[j, b] = 1.0
            j = par[j]
    df = jnp.concatenate([-(jnp.asarray(sub[j])[None, :, None] * J[j].T[:, None, :]) for j in range(nb)], axis=0)
    return dq, dv, df


# ============================================================================ hybrid layer
def _rows(ia, ip, top, bottom):
    """Interleave the active-row block ``top`` and passive-row block ``bottom`` in v order."""
    perm = np.argsort(np.concatenate([ia, ip]), kind="stable")
    parts = [x for x in (top, bottom) if x.shape[0]]
    return jnp.concatenate(parts, axis=0)[perm]


def _hybrid_derivatives(model, q, v, a_active, tau_passive, active, f_ext):
    act = np.array(active, dtype=bool)
    ia, ip = np.nonzero(act)[0], np.nonzero(~act)[0]
    nv, nb = model.nv, model.n_bodies
    dtype = jnp.result_type(v, a_active, tau_passive)
    kin = _kinematics(model, q, v, f_ext)
    M, A = _mass_matrix(model, kin)
    a = jnp.zeros(nv, dtype=dtype).at[ia].set(a_active)
    if len(ip):
        # passive accelerations from M_pp a_p = tau_p - rnea_p(q, v, [a_a; 0], f_ext)
        _, _, tau0 = _dynamics(model, kin, a, f_ext)
        Mpp = M[np.ix_(ip, ip)]
        L = jnp.linalg.cholesky(Mpp)
        solve = lambda B: jax.scipy.linalg.cho_solve((L, True), B)
        a_p = solve(tau_passive - tau0[ip])
        a = a.at[ip].set(a_p)
    oa, F, tau = _dynamics(model, kin, a, f_ext)
    dq, dv, df = _rnea_partials(model, kin, A, oa, F, f_ext)
    if not len(ip):
        return HybridDerivatives(tau, dq, dv, M, jnp.zeros((nv, 0), dtype=dtype), df)
    # differentiate rnea(q, v, [a_a; a_p], f) = [tau_a; tau_p]:
    #   passive rows: d a_p = M_pp^-1 (d tau_p - d rnea_p - M_pa d a_a)
    #   active rows:  d tau_a = d rnea_a + M_aa d a_a + M_ap d a_p
    npas, nact = len(ip), len(ia)
    rhs = jnp.concatenate([dq[ip], dv[ip], df[ip].reshape(npas, nb * 6), M[np.ix_(ip, ia)],
                           jnp.eye(npas, dtype=dtype)], axis=1)
    X = solve(rhs)
    o = np.cumsum([0, nv, nv, nb * 6, nact, npas])
    Pq, Pv, Pf, Pa, Pt = (X[:, o[i]: o[i + 1]] for i in range(5))
    Pq, Pv, Pf, Pa = -Pq, -Pv, -Pf, -Pa
    Pf = Pf.reshape(npas, nb, 6)
    if nact:
        Map = M[np.ix_(ia, ip)]
        Aq = dq[ia] + Map @ Pq
        Av = dv[ia] + Map @ Pv
        Af = df[ia] + jnp.einsum("ij,jbk->ibk", Map, Pf)
        Aa = M[np.ix_(ia, ia)] + Map @ Pa
        At = Map @ Pt
    else:
        Aq = Av = jnp.zeros((0, nv), dtype=dtype)
        Af = jnp.zeros((0, nb, 6), dtype=dtype)
        Aa = jnp.zeros((0, 0), dtype=dtype)
        At = jnp.zeros((0, npas), dtype=dtype)
    y = _rows(ia, ip, tau[ia], a_p)
    return HybridDerivatives(y, _rows(ia, ip, Aq, Pq), _rows(ia, ip, Av, Pv), _rows(ia, ip, Aa, Pa),
                             _rows(ia, ip, At, Pt), _rows(ia, ip, Af, Pf))


# ============================================================================ public API
def hybrid_dynamics_derivatives(model, q, v, a_active, tau_passive, active, f_ext=None, method="analytic"):
    """Hybrid dynamics and its exact Jacobians (the paper's ``dg``).

    Args:
        q: (nq,). v: (nv,). a_active: (n_active,) prescribed accelerations of the active
            DoFs, v order. tau_passive: (n_passive,) prescribed forces of the passive DoFs.
        active: static tuple of nv bools (`Model.active_mask`).
        f_ext: optional (n_bodies, 6) world wrenches ``[torque about world origin; force]``;
            None means zero (df_ext is still returned).
        method: "analytic" (recursive, default) or "autodiff" (jacfwd reference).
    Returns:
        `HybridDerivatives` ``(y, dq, dv, da_active, dtau_passive, df_ext)``: y (nv,) holds
        tau_active in the active rows and a_passive in the passive rows; dq (nv, nv) is
        w.r.t. a tangent perturbation ``integrate(model, q, dq)``; dv (nv, nv);
        da_active (nv, n_active); dtau_passive (nv, n_passive); df_ext (nv, n_bodies, 6).
    """
    fn = "hybrid_dynamics_derivatives"
    q, v, a_active, tau_passive, active, f_ext = _validate(model, q, v, a_active, tau_passive, active, f_ext, fn)
    if method == "autodiff":
        from .derivatives_ad import _hybrid_derivatives_ad
        return _hybrid_derivatives_ad(model, q, v, a_active, tau_passive, active, f_ext)
    _check_method(method, fn)
    return _hybrid_derivatives(model, q, v, a_active, tau_passive, active, f_ext)


def rnea_derivatives(model, q, v, a, f_ext=None, method="analytic"):
    """Inverse dynamics ``tau = rnea(q, v, a, f_ext)`` and its exact Jacobians.

    Args: q (nq,), v (nv,), a (nv,), f_ext None or (n_bodies, 6) world wrenches;
    method "analytic" | "autodiff".
    Returns: `RNEADerivatives` ``(tau (nv,), dq (nv, nv) w.r.t. q (+) dq, dv (nv, nv),
    da (nv, nv) = M, df_ext (nv, n_bodies, 6))``.
    """
    fn = "rnea_derivatives"
    q = _checks.config(model, q, fn)
    v = _checks.vec(model, v, model.nv, "v", fn)
    a = _checks.vec(model, a, model.nv, "a", fn)
    f_ext = _checks.fext(model, f_ext, fn)
    if method == "autodiff":
        from .derivatives_ad import rnea_derivatives_ad
        return rnea_derivatives_ad(model, q, v, a, f_ext)
    _check_method(method, fn)
    r = _hybrid_derivatives(model, q, v, a, jnp.zeros(0, dtype=v.dtype), (True,) * model.nv, f_ext)
    return RNEADerivatives(r.y, r.dq, r.dv, r.da_active, r.df_ext)


def aba_derivatives(model, q, v, tau, f_ext=None, method="analytic"):
    """Forward dynamics ``a = aba(q, v, tau, f_ext)`` and its exact Jacobians
    (``da/dx = -M^-1 drnea/dx`` at ``(q, v, a)``; ``da/dtau = M^-1``).

    Args: q (nq,), v (nv,), tau (nv,), f_ext None or (n_bodies, 6) world wrenches;
    method "analytic" | "autodiff".
    Returns: `ABADerivatives` ``(a (nv,), dq (nv, nv) w.r.t. q (+) dq, dv (nv, nv),
    dtau (nv, nv) = M^-1, df_ext (nv, n_bodies, 6))``.
    """
    fn = "aba_derivatives"
    q = _checks.config(model, q, fn)
    v = _checks.vec(model, v, model.nv, "v", fn)
    tau = _checks.vec(model, tau, model.nv, "tau", fn)
    f_ext = _checks.fext(model, f_ext, fn)
    if method == "autodiff":
        from .derivatives_ad import aba_derivatives_ad
        return aba_derivatives_ad(model, q, v, tau, f_ext)
    _check_method(method, fn)
    r = _hybrid_derivatives(model, q, v, jnp.zeros(0, dtype=v.dtype), tau, (False,) * model.nv, f_ext)
    return ABADerivatives(r.y, r.dq, r.dv, r.dtau_passive, r.df_ext)


def _check_method(method, fn):
    if method != "analytic":
        raise _checks.InputError(f"{fn}: method must be 'analytic' or 'autodiff', got {method!r}")
