"""Time-parallel tangents of a rollout: the step Jacobians of all steps at once, then a
linear recurrence (the rollout's ``derivatives="parallel"``, opt-in).

A rollout is a recurrence ``z_{k+1} = F(z_k, u_k; theta)`` over the passive state
``z = (q_p, v_p)`` (ambient coordinates; ``n_z = n_qp + n_vp``) with per-step inputs
``u_k`` (the active paths at ``t_k``, ``t_k + h/2``, ``t_k + h``: ``n_u = 9 n_active``
for RK4, ``6 n_active`` for Euler) and constants ``theta`` (the model, contact and cost
parameters, ``h``, ``t0``: whatever the step closes over). Each step also emits a
running-cost increment ``dJ_k`` and the recorded grid-point data ``o_k`` (states,
accelerations, torques, contact data at ``t_k``).

Plain autodiff differentiates the scan: forward mode carries every tangent through every
step, reverse mode re-runs each checkpointed segment and then a backward pass, one step
after the other. Here instead:

1. the primal scan runs once and emits the states ``z_k``;
2. the step Jacobians ``D_k = d(z_{k+1}, dJ_k) / d(z_k, u_k)`` ``(n_z + 1, n_z + n_u)``
   and the grid-point Jacobians ``E_k = d o_k / d(z_k, u_k^0)`` (one stage; ``u_k^0``
   the paths at ``t_k``) of **all** steps are evaluated at once (``jacfwd``, vmapped
   over steps in batches of at most `BATCH`): large batched array operations instead
   of a long chain of small kernels, with the analytic hybrid-dynamics Jacobians inside
   (`derivatives_fast`) and the contact forces' Jacobian taken once per stage w.r.t.
   ``(q, v)`` and composed with the dynamics' (`contact_hybrid`);
   With ``rows`` (`cstorm.simulate.rollout`'s ``record_rows``: the constraint grid) the
   grid-point Jacobians are evaluated at those points only, and ``o`` holds only them;
3. the tangent map is then linear algebra: ``w_k = D_k^{zu} du_k (+ r_k)``, the
   recurrence ``dz_{k+1} = D_k^{zz} dz_k + w_k`` (a scan of ``n_z x n_z`` matrix-vector
   products), ``dJ = sum_k D_k^{J} [dz_k; du_k]`` and ``do_k = E_k [dz_k; du_k^0]``,
   where ``r_k`` is the JVP of the step along the tangents of ``theta`` (only traced
   when they are not zero: free final time, design derivatives w.r.t. masses, lengths,
   contact parameters).

The rule is a `jax.custom_jvp`; JAX transposes its linear part for reverse mode (the
recurrence runs backwards with ``D_k^{zz T}``), and under ``jacfwd`` / ``vmap`` of
``jvp`` the Jacobians are evaluated once, shared by every tangent. Values are those of
the plain scan (same code); derivatives equal plain autodiff's to rounding (tests).

Frozen steps (after divergence, or beyond ``n_valid``) have ``D^{zz} = I`` and no input
or cost sensitivity, as the frozen state of the primal. Memory: the Jacobians of every
step are kept, ``N ((n_z + 1)(n_z + n_u) + n_o (n_z + 3 n_active))`` numbers (the
tumbler's 1000 steps: a few MB); the batched evaluation bounds the temporaries to
`BATCH` steps.

Under ``jax.jvp(..., has_aux=True)`` vmapped over tangents, the primal outputs are the
scan's own (unbatched), so a caller needing values and a forward Jacobian gets both from
one pass (`cstorm.MotionProblem`'s ``derivatives="parallel"`` does).

Cost: a gradient is 2-3 forward rollouts (for the tumbler handstand's values+Jacobian,
1000 steps and 26 parameters, the step Jacobians take a little more than the primal
rollout and the recurrence almost nothing). Compiling it can take longer than compiling
the plain scan's derivative (three traced copies of the step: the primal scan, the step
Jacobian, the grid-point Jacobian; about 2x for the tumbler's segments), which is why it
is opt-in.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..dynamics.derivatives_fast import any_nonzero, float0_zeros, instantiate_zero, is_inexact, is_symbolic_zero
from .steps import initial_carry

# steps per batch of step Jacobians: bounds the temporaries (BATCH x n_y x n_w each).
# One batch is faster to run and to compile than several (the batches run as a loop).
BATCH = 1024


def scan_steps(core, point, layout, q0, v0, xs, n_run, q_bound, v_bound, *, run, rows=None):
    """The rollout's scan over steps with the time-parallel tangent rule.

    Args:
      core: ``core(q, v, x) -> (qn, vn, dJ, out)``, one step (`cstorm.simulate.steps.step_core`); it
        may close over traced values (model, contact and cost parameters, ``h``): they
        are hoisted by `jax.closure_convert` and differentiated too.
      point: ``point(q, v, x) -> out``: the grid point's recorded data alone (what
        ``core`` emits as ``out``, from the same stage evaluation), whose Jacobian is
        taken separately: one stage, ``n_z + 3 n_active`` directions.
      layout: the `RolloutLayout` (static).
      q0 (nq,), v0 (nv,): initial state (active entries are overwritten by the paths).
      xs: dict of step inputs, leaves ``(n_seg, seg, ...)``; ``"k"`` the int step index.
      n_run, q_bound, v_bound: as `simulate.rollout` (not differentiated).
      run: `cstorm.simulate.steps.run_steps`.
      rows: None, or a sorted tuple of step indices (into the flattened ``n_seg * seg``
        steps): the recorded data is returned (and differentiated: the grid-point
        Jacobians ``E_k``) at these steps only.
    Returns:
      ``((zq_N (n_qp,), zv_N (n_vp,), J, bad, bad_step, bad_dof, bad_reason), outs, keeps)``
      with ``keeps`` stacked ``(n_seg, seg)`` and ``outs`` likewise ``(n_seg, seg, ...)``,
      or ``(len(rows), ...)`` with ``rows``.
    """
    x_ex = jax.tree_util.tree_map(lambda a: a[0, 0], xs)
    core_c, consts = jax.closure_convert(core, q0, v0, x_ex)
    # the grid point sees the paths at t_k only (keys ending in 0) and the step index
    x_ex0 = {k: x for k, x in x_ex.items() if k.endswith("0") or not is_inexact(x)}
    point_c, pconsts = jax.closure_convert(point, q0, v0, x_ex0)
    xf = {k: x for k, x in xs.items() if jnp.issubdtype(x.dtype, jnp.inexact)}
    xi = {k: x for k, x in xs.items() if k not in xf}
    rows = None if rows is None else tuple(int(i) for i in rows)
    return _steps((core_c, point_c), layout, run, rows, (tuple(consts), tuple(pconsts)), q0, v0, xf, xi,
                  jnp.asarray(n_run), jnp.asarray(q_bound), jnp.asarray(v_bound))


def _primal_full(fns, layout, run, consts, q0, v0, xf, xi, n_run, q_bound, v_bound):
    """The primal scan; the recorded data on every step ``(n_seg, seg, ...)``."""

    iqp, ivp = np.array(layout.qp_idx, int), np.array(layout.vp_idx, int)
    core = lambda q, v, x: fns[0](q, v, x, *consts[0])
    carry, (outs, keeps) = run(core, initial_carry(q0, v0), {**xf, **xi}, n_run, q_bound, v_bound, layout)
    qN, vN, J, bad, bstep, bdof, breason = carry
    return (qN[iqp], vN[ivp], J, bad, bstep, bdof, breason), outs, keeps


def _at_rows(outs, rows):
    """The recorded data at the flattened steps ``rows`` (None: all, unchanged)."""
    if rows is None:
        return outs
    idx = np.asarray(rows, int)
    return jax.tree_util.tree_map(lambda y: y.reshape((-1,) + y.shape[2:])[idx], outs)


def _primal(fns, layout, run, rows, consts, q0, v0, xf, xi, n_run, q_bound, v_bound):
    carry, outs, keeps = _primal_full(fns, layout, run, consts, q0, v0, xf, xi, n_run, q_bound, v_bound)
    return carry, _at_rows(outs, rows), keeps


_steps = jax.custom_jvp(_primal, nondiff_argnums=(0, 1, 2, 3))


def _batched(f, args, K):
    """``vmap(f)`` over the leading axis (length K) of ``args``, in equal batches of at
    most `BATCH` rows (the last rows are repeated to fill the last batch, so that one
    batched body is compiled, not a second one for a remainder)."""
    nb = -(-K // BATCH)
    if nb == 1:
        return jax.vmap(f)(args)
    bs = -(-K // nb)
    pad = nb * bs - K
    fill = lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)]) if pad else a
    args = jax.tree_util.tree_map(lambda a: fill(a).reshape((nb, bs) + a.shape[1:]), args)
    out = jax.lax.map(jax.vmap(f), args)
    return jax.tree_util.tree_map(lambda y: y.reshape((nb * bs,) + y.shape[2:])[:K], out)


def _steps_jvp(fns, layout, run, rows, primals, tangents):
    consts, q0, v0, xf, xi, n_run, q_bound, v_bound = primals
    dconsts, dq0, dv0, dxf = tangents[:4]
    core_c, point_c = fns
    (zq, zv, J, bad, bstep, bdof, breason), outs, keeps = _primal_full(fns, layout, run, *primals)
    iqp, ivp = np.array(layout.qp_idx, int), np.array(layout.vp_idx, int)
    nqp, nvp = len(iqp), len(ivp)
    nz = nqp + nvp
    n_seg, seg = keeps.shape
    K = n_seg * seg
    flat = lambda y: y.reshape((K,) + y.shape[2:])

    # step inputs, flattened per step: u_k (n_u,); the grid point's own inputs (the
    # paths at t_k: qa0, va0, aa0) are the columns `cols0` of u
    ukeys = sorted(xf)
    usz = [int(np.prod(xf[k].shape[2:])) for k in ukeys]
    ushape = [xf[k].shape[2:] for k in ukeys]
    uoff = np.concatenate([[0], np.cumsum(usz)]).astype(int)
    U = (jnp.concatenate([flat(xf[k]).reshape(K, -1) for k in ukeys], axis=1) if ukeys
         else jnp.zeros((K, 0), q0.dtype))
    keys0 = [k for k in ukeys if k.endswith("0")]
    cols0 = np.concatenate([np.arange(uoff[ukeys.index(k)], uoff[ukeys.index(k) + 1]) for k in keys0] or
                           [np.zeros(0, int)]).astype(int)
    XI = {k: flat(x) for k, x in xi.items()}
    Q, V = flat(outs[0]), flat(outs[1])  # grid states (passive entries = z_k)
    keep = flat(keeps)
    Z = jnp.concatenate([Q[:, iqp], V[:, ivp]], axis=1)
    nw = nz + U.shape[1]

    def inputs(w, q, v, xik, keys, offs):
        x = dict(xik)
        for k, (o0, o1) in zip(keys, offs):
            x[k] = w[nz + o0: nz + o1].reshape(ushape[ukeys.index(k)])
        q = q.at[iqp].set(w[:nqp]) if nqp else q
        v = v.at[ivp].set(w[nqp:nz]) if nvp else v
        return q, v, x

    offs_all = [(uoff[j], uoff[j + 1]) for j in range(len(ukeys))]
    offs0, o = [], 0
    for k in keys0:
        n = usz[ukeys.index(k)]
        offs0.append((o, o + n))
        o += n

    def G(w, cst, q, v, xik):  # the step: [z_{k+1}; dJ_k]
        qn, vn, dJ, _ = core_c(*inputs(w, q, v, xik, ukeys, offs_all), *cst[0])
        return jnp.concatenate([qn[iqp], vn[ivp], jnp.reshape(dJ, (1,))])

    out_leaves, out_tree = jax.tree_util.tree_flatten(jax.tree_util.tree_map(lambda y: y[0, 0], outs))
    fl = [i for i, y in enumerate(out_leaves) if is_inexact(y)]
    osz = [int(np.prod(np.shape(out_leaves[i]))) for i in fl]
    ooff = np.concatenate([[0], np.cumsum(osz)]).astype(int)

    def P(w0, cst, q, v, xik):  # the grid point's recorded data (float leaves, flat)
        leaves = jax.tree_util.tree_leaves(point_c(*inputs(w0, q, v, xik, keys0, offs0), *cst[1]))
        return jnp.concatenate([jnp.reshape(leaves[i], (-1,)) for i in fl])

    W = jnp.concatenate([Z, U], axis=1)
    W0 = jnp.concatenate([Z, U[:, cols0]], axis=1)

    # the grid points whose recorded data is returned: all K steps, or `rows`; their
    # inputs to the grid-point Jacobians (and to its parameter tangents below)
    at = (lambda y: y) if rows is None else (lambda y: y[np.asarray(rows, int)])
    R_ = K if rows is None else len(rows)
    args0 = (at(W0), at(Q), at(V), jax.tree_util.tree_map(at, XI))

    def jac_step(args):
        w, q, v, xik = args
        return jax.jacfwd(G)(w, consts, q, v, xik)

    def jac_point(args):
        w0, q, v, xik = args
        return jax.jacfwd(P)(w0, consts, q, v, xik)

    D = _batched(jac_step, (W, Q, V, XI), K)  # (K, nz + 1, nw)
    E = _batched(jac_point, args0, R_)  # (R, n_out, nz + 3 na)
    # frozen steps: the state is carried over, no input or cost sensitivity
    eye = jnp.eye(nz, nw, dtype=D.dtype)
    D = jnp.concatenate([jnp.where(keep[:, None, None], eye, D[:, :nz]),
                         jnp.where(keep[:, None, None], 0.0, D[:, nz:])], axis=1)

    # tangents of the inputs
    dz0 = jnp.concatenate([instantiate_zero(dq0)[iqp], instantiate_zero(dv0)[ivp]])
    if ukeys:
        dU = jnp.concatenate([flat(instantiate_zero(dxf[k])).reshape(K, -1) for k in ukeys], axis=1)
    else:
        dU = jnp.zeros((K, 0), D.dtype)
    R = RP = None
    if any_nonzero(dconsts):
        dc = jax.tree_util.tree_map(instantiate_zero, dconsts, is_leaf=is_symbolic_zero)

        R = jax.vmap(lambda w, q, v, xik: jax.jvp(lambda c: G(w, c, q, v, xik), (consts,), (dc,))[1])(W, Q, V, XI)
        R = jnp.where(keep[:, None], 0.0, R)
        RP = jax.vmap(lambda w0, q, v, xik: jax.jvp(lambda c: P(w0, c, q, v, xik), (consts,), (dc,))[1])(*args0)

    # the recurrence dz_{k+1} = D_zz dz_k + w_k
    wk = jnp.einsum("kij,kj->ki", D[:, :nz, nz:], dU)
    if R is not None:
        wk = wk + R[:, :nz]

    def body(dz, a):
        A, w = a
        return A @ dz + w, dz

    dzN, dZ = jax.lax.scan(body, dz0, (D[:, :nz, :nz], wk))
    dJ = jnp.sum(jnp.einsum("kj,kj->k", D[:, nz], jnp.concatenate([dZ, dU], axis=1)))
    if R is not None:
        dJ = dJ + jnp.sum(R[:, nz])
    dP = jnp.einsum("kij,kj->ki", E, jnp.concatenate([at(dZ), at(dU[:, cols0])], axis=1))
    if RP is not None:
        dP = dP + RP
    lead = (n_seg, seg) if rows is None else (R_,)
    douts = [None] * len(out_leaves)
    for j, i in enumerate(fl):
        douts[i] = dP[:, ooff[j]: ooff[j + 1]].reshape(lead + tuple(np.shape(out_leaves[i])))
    outs = _at_rows(outs, rows)
    outs_leaves = jax.tree_util.tree_leaves(outs)
    for i, y in enumerate(outs_leaves):
        if douts[i] is None:
            douts[i] = float0_zeros(y)
    dout = jax.tree_util.tree_unflatten(out_tree, douts)
    primal_out = ((zq, zv, J, bad, bstep, bdof, breason), outs, keeps)
    tangent_out = ((dzN[:nqp], dzN[nqp:], dJ, float0_zeros(bad), float0_zeros(bstep), float0_zeros(bdof), float0_zeros(breason)),
                   dout, float0_zeros(keeps))
    return primal_out, tangent_out


_steps.defjvp(_steps_jvp, symbolic_zeros=True)
