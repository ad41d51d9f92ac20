"""Analytic derivatives of RNEA, ABA and the hybrid dynamics (the paper's ``dg``):
Carpentier & Mansard 2018, "Analytical derivatives of rigid body dynamics algorithms"
(RSS), world-frame form, extended to world-fixed external wrenches and to the hybrid
partition (Featherstone RBDA 9.2; Sohl & Bobrow 2001).

    rnea_derivatives(model, q, v, a, f_ext=None)   -> (tau, dq, dv, da, df_ext)
    aba_derivatives(model, q, v, tau, f_ext=None)  -> (a, dq, dv, dtau, df_ext)
    hybrid_dynamics_derivatives(model, q, v, a_active, tau_passive, active, f_ext=None)
        -> (y, dq, dv, da_active, dtau_passive, df_ext)

Shapes: q (nq,), v/a/tau (nv,), f_ext (n_bodies, 6) world wrenches ``[torque about the
world origin; force]`` (None: zero; df_ext is still returned). ``dq`` is always w.r.t. a
tangent perturbation ``integrate(model, q, dq)`` (body-frame increments for free and
ball joints), so it is (nv, nv). ``y`` holds tau_active in the active rows and a_passive
in the passive rows (v order). Each function takes ``method="autodiff"`` to use the
jacfwd reference of `derivatives_ad` instead.

Algorithm. Per-body and per-DoF quantities are stacked along a trailing axis (twists
(6, n), 3x3 blocks (3, 3, n)), so each step is one elementwise expression over all bodies
or DoFs; sums along the tree (twists towards the leaves, inertias and forces towards
the roots) are products with the static ancestor matrix. (On TALOS under `vmap` this
compiles about 5x faster than a per-body unrolled form and runs ~10 % faster.)
1. `_kinematics`: world placements, world motion subspace columns ``J`` (6, nv), body
   twists ``ov``, world inertias ``oI``, momenta ``h``, and the composite (subtree)
   inertias ``Ycrb`` and their velocity variations ``doYcrb = sum (ov x* oI - oI ov x
   + B(h))`` (``B(h) x = x x* h``). Both are kept in structured form (`_Inertia`: mass,
   first moment, 3x3 inertia; `_InertiaRate`: a 3x3 block and a 3-vector, since the
   right half of ``doYcrb`` is zero) and applied without forming 6x6 matrices.
2. `_dynamics`: world accelerations ``oa`` (gravity as the world's acceleration),
   subtree forces ``F`` (external wrenches subtracted), ``tau = J^T F + armature a``.
3. `_rnea_partials`: dtau/dq, dtau/dv and M as masked dense products of stacked world
   columns (formulas in its docstring). Pinocchio's external forces are body-fixed; ours
   are fixed in the world, which adds ``J x* Fext`` terms to dtau/dq.
4. Hybrid layer (`hybrid_derivatives_unchecked`): ``a_p`` from ``M_pp a_p = tau_p - rnea_p(q, v,
   [a_a; 0])``, then differentiate ``rnea(q, v, [a_a; a_p], f) = [tau_a; tau_p]``:
   ``d a_p = -M_pp^-1 (d rnea_p)``, ``d tau_a = d rnea_a + M_ap d a_p``. ABA is the
   all-passive case (``dA/dx = -M^-1 dRNEA/dx``, ``dA/dtau = M^-1``), RNEA the all-active one.
Matrix products of per-configuration operands are written as sums of outer products
(`spatial.mm`): under `vmap` on CPU a batched ``dot_general`` of these sizes is 3-5x
slower (TALOS, 38x6x38 and 38x22x92 products).

Cost: O(n) stacked per-body work, O(n^2) products with the ancestor matrix for the
tree sums, O(nv^2) masked products for the partials;
an O(n_p^3) Cholesky-based inverse of M_pp and O(nv^2 n_p) products for the hybrid/ABA
rows. df_ext (`_df_ext`) costs O(nv n_bodies depth).

Everything has static shapes from the static tree, for `jit` and `vmap`; the functions
are themselves differentiable by JAX (second derivatives).
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
from .derivative_types import ABADerivatives, HybridDerivatives, RNEADerivatives, validate_inputs
from .derivatives_ad import aba_derivatives_ad, hybrid_derivatives_ad, rnea_derivatives_ad



def tree_masks(model):
    """Static structure. anc (nb, nb): anc[j, k] when body j is k or an ancestor of k.
    Over DoFs (nv, nv), by the DoFs' joints: up (row joint is the column joint or an
    ancestor of it), same (same joint), strict_up, strict_down = strict_up^T."""
    nb = model.n_bodies
    anc = np.zeros((nb, nb), dtype=bool)
    for k in range(nb):
        j = k
        while j >= 0:
            anc[j, k] = True
            j = model.parents[j]
    dj = np.array(model.dof_joint(), dtype=int)
    up = anc[np.ix_(dj, dj)]
    same = dj[:, None] == dj[None, :]
    return anc, dj, up, same, up & ~same, (up & ~same).T


# ============================================================================ analytic core
# Per-body and per-DoF quantities are stacked along a trailing axis, component first:
# twists and wrenches (6, n), 3-vectors (3, n), 3x3 blocks (3, 3, n). Each step is then
# one elementwise expression over all bodies (or DoFs) instead of one small expression
# per body, and the sums along the tree (twists down to the leaves, inertias and forces
# up to the roots) are products with the static ancestor matrix. `spatial`'s cross
# products, `skew` and `mm` act elementwise over such trailing axes.
def _bmv(A, x):
    """Stacked matrix-vector products ``A[:, :, n] @ x[:, n]``: A (r, c, n), x (c, n) -> (r, n)."""
    out = A[:, 0] * x[0]
    for k in range(1, A.shape[1]):
        out = out + A[:, k] * x[k]
    return out


def _bmtv(A, x):
    """Stacked ``A[:, :, n]^T @ x[:, n]``: A (r, c, n), x (r, n) -> (c, n)."""
    out = A[0] * x[0]
    for k in range(1, A.shape[0]):
        out = out + A[k] * x[k]
    return out


class _Inertia(NamedTuple):
    """Stacked spatial inertias about the world origin in structured form: masses ``m``
    (n,), first moments ``mc = m c`` (3, n) (c: centre of mass) and rotational inertias
    about the origin ``Ib`` (3, 3, n). Each matrix is ``[[Ib, [mc]x], [-[mc]x, m 1]]``;
    sums of inertias (composite inertias) are sums of the three parts."""

    m: jnp.ndarray
    mc: jnp.ndarray
    Ib: jnp.ndarray

    def apply(self, x):
        """``I x`` for stacked twists x (6, n)."""
        w, u = x[:3], x[3:]
        return jnp.concatenate([_bmv(self.Ib, w) + sp._cross3(self.mc, u), self.m * u - sp._cross3(self.mc, w)])

    def take(self, idx):
        return _Inertia(self.m[idx], self.mc[:, idx], self.Ib[..., idx])


class _InertiaRate(NamedTuple):
    """``dI/dt + B(h) = ov x* oI - oI (ov x) + B(h)`` stacked over bodies (or subtree
    sums), in structured form. For a rigid body with twist ``[w; u]`` and momentum
    ``h = [n; f]`` the linear momentum ``f = m u + w x mc`` is also ``d(mc)/dt``, so the
    upper-right block cancels and the lower-right is zero: the matrix is
    ``[[D, 0], [-2 [f]x, 0]]`` with ``D = dIb/dt - [n]x`` (3, 3, n), f (3, n) and
    ``dIb/dt = [w]x Ib - Ib [w]x - (u mc^T + mc u^T) + 2 (mc . u) 1``."""

    D: jnp.ndarray
    f: jnp.ndarray

    def apply(self, x):
        """The rate times stacked twists x (6, n): only their angular rows enter."""
        return jnp.concatenate([_bmv(self.D, x[:3]), -2.0 * sp._cross3(self.f, x[:3])])

    def apply_T(self, x):
        """The (3, n) nonzero rows of the transpose times stacked twists x (6, n)."""
        return _bmtv(self.D, x[:3]) + 2.0 * sp._cross3(self.f, x[3:])

    def take(self, idx):
        return _InertiaRate(self.D[..., idx], self.f[:, idx])


class _Tree(NamedTuple):
    """Static structure (numpy): dj (nv,) the body of each DoF, anc (nb, nb)
    float with anc[j, k] = 1 when body j is k or an ancestor of k, member (nb, nv) with
    member[b, k] = 1 when DoF k is body b's, up/same/strict_up/strict_down (nv, nv) over
    DoFs as in `tree_masks`."""

    dj: np.ndarray
    anc: np.ndarray
    member: np.ndarray
    up: np.ndarray
    same: np.ndarray
    sup: np.ndarray
    sdown: np.ndarray


def _tree(model):
    anc, dj, up, same, sup, sdown = tree_masks(model)
    member = (np.arange(model.n_bodies)[:, None] == dj[None, :]).astype(float)
    return _Tree(dj, anc.astype(float), member, up, same, sup, sdown)


class _Kin(NamedTuple):
    """Configuration- and velocity-dependent terms in world coordinates, twists and
    wrenches about the world origin. Per DoF (trailing axis nv): J (6, nv) world motion
    subspace columns, dVdq = ov_parent x J, dAdv = (ov + ov_parent) x J. Per body
    (trailing axis nb): ov (6, nb) twists, vJ (6, nb) joint twists, ovp (6, nb) parent
    twists (zero at roots), oI `_Inertia`, h (6, nb) momenta, Ycrb `_Inertia` composite
    (subtree) inertias, doYcrb `_InertiaRate` subtree sums, Fext (6, nb) subtree sums of
    the external wrenches or None."""

    J: jnp.ndarray
    dVdq: jnp.ndarray
    dAdv: jnp.ndarray
    ov: jnp.ndarray
    vJ: jnp.ndarray
    ovp: jnp.ndarray
    oI: _Inertia
    h: jnp.ndarray
    Ycrb: _Inertia
    doYcrb: _InertiaRate
    Fext: jnp.ndarray


def _kinematics(model, tree, q, v, f_ext):
    Rs, ps, Ss = joint_placements(model, q)
    oR, op = world_placements(model, Rs, ps)
    R, p = jnp.stack(oR, axis=-1), jnp.stack(op, axis=-1)  # (3, 3, nb), (3, nb)
    S = jnp.concatenate(Ss, axis=1)  # (6, nv), local (constant for every joint type)
    dj, anc = tree.dj, jnp.asarray(tree.anc, dtype=R.dtype)
    Rd, pd = R[..., dj], p[:, dj]
    w = _bmv(Rd, S[:3])
    J = jnp.concatenate([w, _bmv(Rd, S[3:]) + sp._cross3(pd, w)])
    vJ = (J * v) @ jnp.asarray(tree.member.T, dtype=R.dtype)  # (6, nb)
    ov = vJ @ anc
    ovp = ov - vJ
    ovd, ovpd = ov[:, dj], ovp[:, dj]
    dVdq, dAdv = sp.cross_motion(ovpd, J), sp.cross_motion(ovd + ovpd, J)
    # world inertias, momenta and inertia rates, all bodies at once
    m = model.mass
    c = _bmv(R, model.com.T) + p
    mc = m * c
    eye = jnp.eye(3, dtype=c.dtype)[:, :, None]
    RI = sp.mm(R, jnp.moveaxis(model.inertia, 0, -1))
    Ib = sp.mm(RI, jnp.swapaxes(R, 0, 1)) + m * (jnp.sum(c * c, axis=0) * eye - c[:, None] * c[None, :])
    oI = _Inertia(m, mc, Ib)
    h = oI.apply(ov)
    w, u = ov[:3], ov[3:]
    Z = sp.mm(sp.skew(w), Ib)
    uc = u[:, None] * mc[None, :]
    ZT, ucT = jnp.swapaxes(Z, 0, 1), jnp.swapaxes(uc, 0, 1)
    D = Z + ZT - uc - ucT + 2.0 * jnp.sum(mc * u, axis=0) * eye - sp.skew(h[:3])
    # subtree sums of all parts in one product with the ancestor matrix
    nb = model.n_bodies
    parts = jnp.concatenate([m[None].astype(c.dtype), mc, Ib.reshape(9, nb), D.reshape(9, nb), h[3:]])
    if f_ext is not None:
        parts = jnp.concatenate([parts, f_ext.T])
    sums = parts @ anc.T
    Ycrb = _Inertia(sums[0], sums[1:4], sums[4:13].reshape(3, 3, nb))
    doY = _InertiaRate(sums[13:22].reshape(3, 3, nb), sums[22:25])
    Fext = sums[25:31] if f_ext is not None else None
    return _Kin(J, dVdq, dAdv, ov, vJ, ovp, oI, h, Ycrb, doY, Fext)


def _dynamics(model, tree, kin, a, f_ext):
    """World accelerations oa (6, nb) (gravity included: the world accelerates at
    ``[0; -g]``), parent accelerations oap (6, nb) (``[0; -g]`` at roots), subtree forces
    F (6, nb) (external wrenches subtracted) and tau (nv,) = J^T F + armature a."""
    anc = jnp.asarray(tree.anc, dtype=kin.J.dtype)
    local = (kin.J * a) @ jnp.asarray(tree.member.T, dtype=kin.J.dtype) + sp.cross_motion(kin.ov, kin.vJ)
    oa = gravity_acceleration(model)[:, None] + local @ anc
    f = kin.oI.apply(oa) + sp.cross_force(kin.ov, kin.h)
    if f_ext is not None:
        f = f - f_ext.T
    F = f @ anc.T
    tau = jnp.sum(kin.J * F[:, tree.dj], axis=0) + model.armature * a
    return oa, oa - local, F, tau


def _rnea_partials(model, tree, kin, oap, F, f_ext, M=None):
    """M, dtau/dq (tangent) and dtau/dv (nv, nv) at the parent accelerations oap and
    subtree forces F of `_dynamics` (Carpentier & Mansard 2018, world-frame form, with
    world-fixed external wrenches).

    With per-DoF world columns (k: the column's joint, lambda(k) its parent)
      J_k, dVdq_k = ov_lambda x J_k, dAdq_k = oa_lambda x J_k + ov_lambda x dVdq_k,
      dAdv_k = (ov_k + ov_lambda) x J_k, and composite (subtree) Ycrb, doYcrb, forces F,
      external wrenches Fext, G = F + Fext:
    row j ancestor of or equal to column k (upper part):
      dtau_j/dq_k = J_j^T (doYcrb_k dVdq_k + Ycrb_k dAdq_k + J_k x* (G_k if j != k else Fext_k))
      dtau_j/dv_k = J_j^T (doYcrb_k J_k + Ycrb_k dAdv_k),  M_jk = J_j^T Ycrb_k J_k
    row j strict descendant of column k (lower part):
      dtau_j/dq_k = (Ycrb_j J_j)^T dAdq_k + (doYcrb_j^T J_j)^T dVdq_k - (J_j x* Fext_j)^T J_k
      dtau_j/dv_k = (Ycrb_j J_j)^T dAdv_k + (doYcrb_j^T J_j)^T J_k
    The columns are computed for all DoFs at once; each part is then one dense product
    of stacked (6, nv) columns, masked by the static tree structure. M depends on q
    only: a caller that already has it (the hybrid layer) passes it in.
    """
    dj, J = tree.dj, kin.J
    dtype = J.dtype
    Y, dY = kin.Ycrb.take(dj), kin.doYcrb.take(dj)
    dAdq = sp.cross_motion(oap[:, dj], J) + sp.cross_motion(kin.ovp[:, dj], kin.dVdq)
    dFdq = dY.apply(kin.dVdq) + Y.apply(dAdq)
    dFdv = dY.apply(J) + Y.apply(kin.dAdv)
    A = Y.apply(J)
    Bv = dY.apply_T(J)
    G = F if f_ext is None else F + kin.Fext
    XG = sp.cross_force(J, G[:, dj])
    mask = lambda m: jnp.asarray(m, dtype=dtype)
    if M is None:
        M = _mass_from_columns(model, tree, J, A)
    JT = J.T
    dq = mask(tree.up) * sp.mm(JT, dFdq) + mask(tree.sup) * sp.mm(JT, XG)
    if f_ext is None:
        low = sp.mm(jnp.concatenate([A, Bv]).T, jnp.concatenate([dAdq, kin.dVdq[:3]]))
    else:
        XE = sp.cross_force(J, kin.Fext[:, dj])
        dq = dq + mask(tree.same) * sp.mm(JT, XE)
        low = sp.mm(jnp.concatenate([A, Bv, -XE]).T, jnp.concatenate([dAdq, kin.dVdq[:3], J]))
    dq = dq + mask(tree.sdown) * low
    dv = mask(tree.up) * sp.mm(JT, dFdv) + mask(tree.sdown) * sp.mm(
        jnp.concatenate([A, Bv]).T, jnp.concatenate([kin.dAdv, J[:3]]))
    return M, dq, dv


def _mass_only(model, tree, kin):
    """M (nv, nv) from the world Jacobian columns and composite inertias."""
    return _mass_from_columns(model, tree, kin.J, kin.Ycrb.take(tree.dj).apply(kin.J))


def _mass_from_columns(model, tree, J, A):
    """M = the up-masked ``J^T A`` (A = Ycrb_k J_k per column, both (6, nv)), mirrored,
    plus armature."""
    U = sp.mm(J.T, A)
    dtype = U.dtype
    return jnp.asarray(tree.up, dtype=dtype) * U + (jnp.asarray(tree.sup, dtype=dtype) * U).T + jnp.diag(model.armature)


def spd_inverse(A):
    """Inverse (n, n) of a symmetric positive definite matrix ``A`` (n, n): Cholesky
    ``A = L L^T``, ``W = L^-1`` (`tril_inverse`), ``A^-1 = W^T W``. Pure JAX; under
    `vmap` on CPU the blocked triangular inverse is faster than a batched triangular
    solve for W, at the same accuracy (both use the same L)."""
    n = A.shape[0]
    if n == 1:
        return 1.0 / A
    W = tril_inverse(jnp.linalg.cholesky(A))
    return sp.mm(W.T, W)


def tril_inverse(L):
    """Inverse (n, n), lower-triangular, of a lower-triangular matrix ``L`` (n, n) with a
    positive diagonal, by recursive 2x2 blocking: ``[[A, 0], [B, C]]^-1 = [[A^-1, 0],
    [-C^-1 B A^-1, C^-1]]``, the products as sums of outer products (`spatial.mm`)."""
    n = L.shape[0]
    if n == 1:
        return 1.0 / L
    h = n // 2
    Ai, Ci = tril_inverse(L[:h, :h]), tril_inverse(L[h:, h:])
    X = -sp.mm(Ci, sp.mm(L[h:, :h], Ai))
    top = jnp.concatenate([Ai, jnp.zeros((h, n - h), dtype=L.dtype)], axis=1)
    return jnp.concatenate([top, jnp.concatenate([X, Ci], axis=1)], axis=0)


# ============================================================================ hybrid layer
def _runs(idx):
    """Static sorted indices -> list of contiguous ``(start, stop)`` runs."""
    runs = []
    for i in np.asarray(idx, dtype=int):
        if runs and runs[-1][1] == i:
            runs[-1][1] = i + 1
        else:
            runs.append([int(i), int(i) + 1])
    return [tuple(r) for r in runs]


def _rows(ia, ip, top, bottom):
    """Interleave the active-row block ``top`` and passive-row block ``bottom`` (along
    axis 0) in v order, as a concatenation of static slices (no gather)."""
    if not len(ip):
        return top
    if not len(ia):
        return bottom
    pieces, na, npas = [], 0, 0
    act = np.zeros(len(ia) + len(ip), dtype=bool)
    act[np.asarray(ia)] = True
    # walk v order, switching between the blocks at each change of activity
    edges = [0] + [r for r in range(1, len(act)) if act[r] != act[r - 1]] + [len(act)]
    for s0, s1 in zip(edges[:-1], edges[1:]):
        n = s1 - s0
        if act[s0]:
            pieces.append(jax.lax.slice_in_dim(top, na, na + n, axis=0))
            na += n
        else:
            pieces.append(jax.lax.slice_in_dim(bottom, npas, npas + n, axis=0))
            npas += n
    return pieces[0] if len(pieces) == 1 else jnp.concatenate(pieces, axis=0)


def _take(X, idx, axis=0):
    """X restricted to the static sorted indices idx along axis, as a concatenation of
    static slices (no gather)."""
    idx = np.asarray(idx)
    if len(idx) == X.shape[axis] and np.all(idx == np.arange(len(idx))):
        return X
    pieces = [jax.lax.slice_in_dim(X, a, b, axis=axis) for a, b in _runs(idx)]
    if not pieces:
        return jax.lax.slice_in_dim(X, 0, 0, axis=axis)
    return pieces[0] if len(pieces) == 1 else jnp.concatenate(pieces, axis=axis)


# Above this many DoFs the hybrid layer multiplies S into dq, dv and M[:, a] separately
# rather than into their concatenation: under `vmap` the concatenation is faster for
# Solo12 (18 DoF), the separate products for TALOS (38 DoF).
_CONCAT_MAX_NV = 24


def hybrid_derivatives_unchecked(model, q, v, a_active, tau_passive, active, f_ext):
    """Differentiate the identity ``rnea(q, v, [a_a; a_p], f_ext) = [tau_a; tau_p]``.

    With R = rnea and a residual perturbation dR (any of dR/dq, dR/dv, dR/df_ext, and
    M[:, a] for da_active), the passive rows give ``d a_p = -M_pp^-1 dR_p`` and the active
    rows ``d tau_a = dR_a + M_ap d a_p``: ``dy = S dR`` with ``S[:, a] = I[:, a]`` and
    ``S[:, p] = Sp = [-M_ap M_pp^-1 ; -M_pp^-1]`` (rows a; p); ``dy/dtau_p = -Sp``.
    dR/df_ext_b = -J_j^T on the DoFs j supporting body b, so ``dy/df_ext_b =
    -sum_j S[:, j] J_j^T`` over them (`_df_ext`).
    """
    act = np.array(active, dtype=bool)
    ia, ip = np.nonzero(act)[0], np.nonzero(~act)[0]
    nv = model.nv
    dtype = jnp.result_type(v, a_active, tau_passive)
    tree = _tree(model)
    kin = _kinematics(model, tree, q, v, f_ext)
    a = _rows(ia, ip, a_active, jnp.zeros(len(ip), dtype=dtype))
    M0 = None
    if len(ip):
        # passive accelerations from M_pp a_p = tau_p - rnea_p(q, v, [a_a; 0], f_ext)
        *_, tau0 = _dynamics(model, tree, kin, a, f_ext)
        M0 = _mass_only(model, tree, kin)
        Minv = spd_inverse(_take(_take(M0, ip, 0), ip, 1))
        a_p = sp.mv(Minv, tau_passive - _take(tau0, ip))
        a = _rows(ia, ip, a_active, a_p)
    _, oap, F, tau = _dynamics(model, tree, kin, a, f_ext)
    M, dq, dv = _rnea_partials(model, tree, kin, oap, F, f_ext, M0)
    Jc = kin.J
    if not len(ip):
        return HybridDerivatives(tau, dq, dv, M, jnp.zeros((nv, 0), dtype=dtype), _df_ext(model, act, None, Jc))
    if len(ia):
        K = sp.mm(_take(_take(M, ia, 0), ip, 1), Minv)
        Sp = _rows(ia, ip, -K, -Minv)
    else:
        Sp = -Minv
    amask = jnp.asarray(act, dtype=dtype)[:, None]

    def S_times(X):  # S @ X for X (nv, c)
        out = sp.mm(Sp, _take(X, ip))
        return out + amask * X if len(ia) else out

    y = _rows(ia, ip, _take(tau, ia), a_p)
    blocks = [dq, dv] + ([_take(M, ia, 1)] if len(ia) else [])
    if nv > _CONCAT_MAX_NV:
        # three products: concatenating [dq | dv | M[:, a]] first is one more pass over
        # nv (2 nv + n_a) values (28 KB per configuration on TALOS)
        Dq, Dv, *Da = [S_times(X) for X in blocks]
    else:
        # one product of the concatenation: fewer, larger kernels
        SX = S_times(jnp.concatenate(blocks, axis=1))
        Dq, Dv, Da = SX[:, :nv], SX[:, nv: 2 * nv], [SX[:, 2 * nv:]]
    Da = Da[0] if len(ia) else jnp.zeros((nv, 0), dtype=dtype)
    return HybridDerivatives(y, Dq, Dv, Da, -Sp, _df_ext(model, act, Sp, Jc))


def _df_ext(model, act, Sp, Jc):
    """``dy/df_ext`` (nv, n_bodies, 6). ``dR/df_ext_b = -J_j^T`` on the DoFs j supporting
    body b (its joint's and its ancestors'), so ``dy/df_ext_b = -sum_j S[:, j] J_j^T``:
    for a passive DoF j the column ``S[:, j]`` is ``Sp``'s (``Sp`` (nv, n_passive), None
    when every DoF is active), for an active one the unit vector ``e_j``, which only
    writes ``-J_j^T`` into row j (a static mask). Each body's passive sum is written out
    directly rather than accumulated down the tree: under `vmap` that fuses into one loop
    over the output (on TALOS about 30 % faster than the accumulation)."""
    anc, dj, *_ = tree_masks(model)
    nv, nb = model.nv, model.n_bodies
    dtype = Jc.dtype
    ip = np.nonzero(~act)[0]
    pos = np.full(nv, -1)
    pos[ip] = np.arange(len(ip))
    amask = anc[dj] & act[:, None]  # (nv, nb): active row j supports body b
    out = -(jnp.asarray(amask, dtype=dtype)[:, :, None] * Jc.T[:, None, :])
    if not len(ip):
        return out
    cols = []
    for b in range(nb):
        terms = [Sp[:, pos[j], None] * Jc[None, :, j] for j in ip if anc[dj[j], b]]
        cols.append(sum(terms[1:], terms[0]) if terms else jnp.zeros((nv, 6), dtype=dtype))
    return out - jnp.stack(cols, axis=1)


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
    q, v, a_active, tau_passive, active, f_ext = validate_inputs(model, q, v, a_active, tau_passive, active, f_ext, fn)
    if method == "autodiff":
        return hybrid_derivatives_ad(model, q, v, a_active, tau_passive, active, f_ext)
    _check_method(method, fn)
    return hybrid_derivatives_unchecked(model, q, v, a_active, tau_passive, active, f_ext)


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
        return rnea_derivatives_ad(model, q, v, a, f_ext)
    _check_method(method, fn)
    r = hybrid_derivatives_unchecked(model, q, v, a, jnp.zeros(0, dtype=v.dtype), (True,) * model.nv, f_ext)
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
        return aba_derivatives_ad(model, q, v, tau, f_ext)
    _check_method(method, fn)
    r = hybrid_derivatives_unchecked(model, q, v, jnp.zeros(0, dtype=v.dtype), tau, (False,) * model.nv, f_ext)
    return ABADerivatives(r.y, r.dq, r.dv, r.dtau_passive, r.df_ext)


def _check_method(method, fn):
    if method != "analytic":
        raise _checks.InputError(f"{fn}: method must be 'analytic' or 'autodiff', got {method!r}")
