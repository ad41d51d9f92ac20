"""Analytic derivatives of the ground (plane) contact points w.r.t. the robot's state:
a `jax.custom_jvp` rule for the plane-pair block of `cstorm.contact.contact_forces`.

The block. Contact point ``i`` is a feature ball (centre ``c_i`` fixed in body
``b_i``, radius ``r_i``) against a plane with world unit normal ``N_i`` and offset
``off_i``. With the body's world pose ``(R_b, p_b)`` and its twist about the world origin
``ov_b = [omega_b; v_O]`` (``v_O``: velocity of the body point at the world origin):

    x   = R_b c + p_b                      feature centre, world
    p   = x - r N                          robot contact point (deepest point)
    d   = N . x - r - off                  signed distance
    u   = v_O + omega_b x p                velocity of the body point at p
    (N_mag, f_t) = force law (`cstorm.contact.point_contact_force`) at (d, N, u)
    W   = [p x f; f],  f = N_mag N + f_t   the point's wrench about the world origin

Derivatives (world frame; Carpentier & Mansard 2018's conventions). ``J`` (6, nv): the
joints' motion subspaces about the world origin, ``J_k = oX_{j(k)} S_k``; a tangent
perturbation ``q (+) dq`` (body-frame increments for free and ball joints, as
`cstorm.integrate`) moves the subtree of joint ``j(k)`` rigidly by the twist
``J_k dq_k``. ``m_ik`` = 1 when DoF ``k``'s joint is body ``b_i`` or one of its
ancestors. Then, per DoF ``k``,

    dx/dq_k  = m_ik (J_k,lin + J_k,ang x x)            (= dp/dq_k, N is fixed)
    dd/dq_k  = N . dx/dq_k
    dov_b/dq_k = m_ik J_k x (ov_b - ov_{lambda(k)})     (motion cross product;
                                                       lambda(k): parent of joint j(k))
    du/dq_k  = dov_lin + dov_ang x p + omega_b x dx/dq_k
    du/dv_k  = m_ik (J_k,lin + J_k,ang x p)

and the force law's partials w.r.t. ``(d, u)`` (4 directions of forward mode through the
same elementwise code that computes the value) complete the chain:
``dW = [dp x f + p x df; df]``. The cost is O(k nv) elementwise work, against forward
mode through the kinematics and the point code along ``nq + nv`` directions (on
Gymnasium's hopper ``jacfwd`` of the whole contact model costs ~17 evaluations of its
value).

Tangents of anything else (model parameters, feature geometry, plane pose, contact
parameters) are pushed through the plain code by a JVP, and only when they are nonzero.
Ambient ``dq`` is mapped to the tangent ``dq_t`` as in `cstorm.dynamics.derivatives_fast`
(the radial quaternion component is dropped; rollouts only make tangent perturbations).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .. import spatial as sp
from ..dynamics.derivatives import tree_masks
from ..dynamics.derivatives_fast import any_nonzero, instantiate_zero, is_symbolic_zero, ambient_to_tangent
from ..dynamics.kinematics import joint_placements, world_placements, world_twists
from .laws import point_contact_force

__all__ = ["plane_points"]


def plane_points(model, q, v, feats, params, bidx):
    """The plane-pair contact points and their wrenches, with analytic derivatives.

    Args:
      model: the robot `Model`.
      q (nq,), v (nv,): the state.
      feats: ``(c (k, 3), r (k,), N (k, 3), off (k,))``: feature centres in their body's
        frame (geom pose applied), radii (m), plane unit normals (world) and offsets
        (m; the plane is ``N . y = off``).
      params: `cstorm.ContactParams` whose leaves are scalars or ``(k,)``.
      bidx: static tuple of the k points' body indices.
    Returns:
      ``(d (k,), p (k, 3), u (k, 3), N_mag (k,), f_t (k, 3), W (k, 6))``: signed
      distances, robot contact points, their velocities, normal force magnitudes,
      friction forces and wrenches ``[p x f; f]`` about the world origin (world axes).
    """
    return _plane(tuple(int(b) for b in bidx), model, q, v, feats, params)


def _kin(model, q):
    Rs, ps, Ss = joint_placements(model, q)
    oR, op = world_placements(model, Rs, ps)
    return Rs, ps, Ss, oR, op


def plane_points_value(bidx, model, q, v, feats, params, kin=None):
    c, r, N, off = feats
    Rs, ps, Ss, oR, op = kin if kin is not None else _kin(model, q)
    Rw, pw = jnp.stack(oR), jnp.stack(op)
    w, vo = world_twists(model, Rs, ps, Ss, oR, v)
    b = np.asarray(bidx)
    # R_b c as a sum over R's columns: gathers of (k, 3), never a (k, 3, 3) array
    x = Rw[b, :, 0] * c[:, 0:1] + Rw[b, :, 1] * c[:, 1:2] + Rw[b, :, 2] * c[:, 2:3] + pw[b]
    p = x - r[:, None] * N
    d = jnp.sum(N * x, axis=1) - r - off
    u = vo[b] + jnp.cross(w[b], p - pw[b])
    f, N_mag, f_t = point_contact_force(d, N, u, params)
    W = jnp.concatenate([jnp.cross(p, f), f], axis=1)
    return d, p, u, N_mag, f_t, W, x


@partial(jax.custom_jvp, nondiff_argnums=(0,))
def _plane(bidx, model, q, v, feats, params):
    return plane_points_value(bidx, model, q, v, feats, params)[:6]


def _jvp(bidx, primals, tangents):
    model, q, v, feats, params = primals
    dmodel, dq, dv, dfeats, dparams = tangents
    kin = _kin(model, q)
    d, p, u, N_mag, f_t, W, x = plane_points_value(bidx, model, q, v, feats, params, kin)
    out = (d, p, u, N_mag, f_t, W)
    k = d.shape[0]
    N = feats[2]
    b = np.asarray(bidx)
    dtype = W.dtype
    douts = [jnp.zeros_like(y) for y in out]

    if not (is_symbolic_zero(dq) and is_symbolic_zero(dv)):
        _, _, Ss, oR, op = kin
        anc, dj, *_ = tree_masks(model)
        nv = model.nv
        # joint motion subspaces about the world origin (6, nv), body twists (nb, 6)
        J = jnp.concatenate([sp.act_motion(oR[i], op[i], Ss[i]) for i in range(model.n_bodies)], axis=1)
        ov = []
        for i, par in enumerate(model.parents):
            s = model.v_starts[i]
            vj = sp.mv(J[:, s: s + model.joints[i].nv], v[s: s + model.joints[i].nv])
            ov.append(vj if par < 0 else ov[par] + vj)
        ov = jnp.stack(ov)
        par_of_dof = np.array([model.parents[j] for j in dj], int)
        ov_par = jnp.where(par_of_dof[:, None] >= 0, ov[np.maximum(par_of_dof, 0)], 0.0).T  # (6, nv)
        m = jnp.asarray(anc[dj][:, b].T, dtype)  # (k, nv)

        # component-first layout: (3, k, nv) Jacobians of 3-vectors
        Jw, Jl = J[:3, None, :], J[3:, None, :]
        xT, pT = x.T[:, :, None], p.T[:, :, None]
        Jx = m * (Jl + sp._cross3(Jw, jnp.broadcast_to(xT, (3, k, 1))))  # dx/dq = dp/dq
        Jd = jnp.einsum("ck,ckn->kn", N.T, Jx)
        Juv = m * (Jl + sp._cross3(Jw, jnp.broadcast_to(pT, (3, k, 1))))  # du/dv
        ovb = ov[b].T  # (6, k)
        rel = ovb[:, :, None] - ov_par[:, None, :]  # (6, k, nv)
        Jb = jnp.broadcast_to(J[:, None, :], (6, k, nv))
        dov_w = m * sp._cross3(Jb[:3], rel[:3])
        dov_l = m * (sp._cross3(Jb[:3], rel[3:]) + sp._cross3(Jb[3:], rel[:3]))
        wb = jnp.broadcast_to(ovb[:3, :, None], (3, k, nv))
        Juq = dov_l + sp._cross3(dov_w, jnp.broadcast_to(pT, (3, k, nv))) + sp._cross3(wb, Jx)

        # the force law's partials w.r.t. (d, u): 4 forward-mode directions
        def law(dd, uu):
            _, nm, ft = point_contact_force(dd, N, uu, params)
            return nm, ft

        E = jnp.eye(4, dtype=dtype)
        dnm, dft = jax.vmap(lambda e: jax.jvp(law, (d, u), (jnp.broadcast_to(e[0], (k,)),
                                                          jnp.broadcast_to(e[1:], (k, 3))))[1])(E)
        # dnm (4, k), dft (4, k, 3) -> per-point partials
        a_d, a_u = dnm[0], dnm[1:]  # (k,), (3, k)
        b_d, b_u = dft[0].T, jnp.transpose(dft[1:], (2, 0, 1))  # (3, k), (3c, 3j, k)

        # Jacobians of every output w.r.t. q_t and v, (..., nv) each, built once (XLA
        # drops those of unused outputs), then one product per output. Under `jacfwd`
        # of a batch the tangent basis is the same for every configuration, so each
        # product is one large matrix product, not many tiny ones (5.6 against 12 us
        # per evaluation with per-direction elementwise contractions, hopper, vmap 2500)
        ax = lambda a: a[..., None]
        f = N * ax(N_mag) + f_t  # (k, 3)

        def law_chain(Jdd, Juu):  # (k, nv) or None, (3, k, nv) -> d N_mag, d f_t, d f
            dnm_ = jnp.sum(ax(a_u) * Juu, axis=0)
            dft_ = jnp.sum(ax(b_u) * Juu[None], axis=1)
            if Jdd is not None:
                dnm_ = dnm_ + ax(a_d) * Jdd
                dft_ = dft_ + ax(b_d) * Jdd[None]
            return dnm_, dft_, ax(N.T) * dnm_[None] + dft_

        nm_q, ft_q, f_q = law_chain(Jd, Juq)
        nm_v, ft_v, f_v = law_chain(None, Juv)
        W_q = jnp.concatenate([sp._cross3(Jx, jnp.broadcast_to(ax(f.T), Jx.shape))
                               + sp._cross3(jnp.broadcast_to(pT, f_q.shape), f_q), f_q])  # (6, k, nv)
        W_v = jnp.concatenate([sp._cross3(jnp.broadcast_to(pT, f_v.shape), f_v), f_v])
        jac_q = (Jd, jnp.moveaxis(Jx, 0, 1), jnp.moveaxis(Juq, 0, 1), nm_q, jnp.moveaxis(ft_q, 0, 1),
                 jnp.moveaxis(W_q, 0, 1))
        jac_v = (None, None, jnp.moveaxis(Juv, 0, 1), nm_v, jnp.moveaxis(ft_v, 0, 1), jnp.moveaxis(W_v, 0, 1))
        if not is_symbolic_zero(dq):
            dqt = ambient_to_tangent(model, q, instantiate_zero(dq))
            douts = [Jy @ dqt for Jy in jac_q]
        if not is_symbolic_zero(dv):
            dvv = instantiate_zero(dv)
            douts = [y if Jy is None else y + Jy @ dvv for y, Jy in zip(douts, jac_v)]

    if any_nonzero((dmodel, dfeats, dparams)):
        inst = lambda t: jax.tree_util.tree_map(instantiate_zero, t, is_leaf=is_symbolic_zero)
        extra = jax.jvp(lambda mm, ff, pp: plane_points_value(bidx, mm, q, v, ff, pp)[:6], (model, feats, params),
                        (inst(dmodel), inst(dfeats), inst(dparams)))[1]
        douts = [a + e for a, e in zip(douts, extra)]
    return out, tuple(douts)


_plane.defjvp(_jvp, symbolic_zeros=True)

