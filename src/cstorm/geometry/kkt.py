"""Optimality (KKT) conditions of the distance / penetration problem on the active
features found by GJK or EPA, their Newton polish, and their implicit-function-theorem
tangents.

At a solution, the active features are ``k <= 3`` pairs of support points
``(a_i, b_i)`` (world), each re-evaluated from a body-fixed *key*: the local direction
that selected it (a vertex of a polytope; for a cylinder, which rim, and, when the
contact is on its curved surface, an angle that follows the normal). With
``w_i = a_i - b_i`` and weights ``lam`` the problem is, on the affine hull of the
``w_i``,

    minimize |z|^2 / 2,  z = sum_i lam_i w_i,  subject to  sum_i lam_i = 1,

whose KKT conditions are ``w_i . z = mu`` (active i) and ``sum lam = 1``. The normal
closes the system: ``n = z / |z|`` when separated, ``n = -z / |z|`` when penetrating
(the point of the Minkowski difference's boundary nearest to the origin), ``n = -nu``
(EPA's face normal) when the penetration is too shallow for ``z`` to give a direction,
or a fixed ``n`` at a degenerate tie. For polytopes this is exactly the KKT system of
``min |p_a - p_b|^2, p_a in feature(A), p_b in feature(B)`` (and of the support-function
form ``max_{|u|=1} -h_A(-u) - h_B(u)`` when penetrating); a cylinder's curved surface
enters through the keyed support's dependence on ``n``.

Unknowns ``x = (lam (3,), mu, n (3,))`` (7,); parameters ``theta = (shape_a, pose_a,
shape_b, pose_b)`` (pytree). ``dx = -J_x^+ (dR/dtheta . dtheta)`` is the tangent
(pseudo-inverse: at ties, where ``J_x`` is singular, the minimum-norm tangent, finite).
Outputs ``(d, p_a, p_b, n)`` with ``p_a = sum lam_i a_i``, ``p_b = sum lam_i b_i``,
``d = n . (p_a - p_b)``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..spatial import safe_norm
from .support import core_of, support, support_keyed

SEP, PEN_Z, PEN_FACE, FIXED = 0, 1, 2, 3


class Keys(NamedTuple):
    ref_a: jnp.ndarray  # (3, 3) local directions selecting a_i (rows)
    ref_b: jnp.ndarray  # (3, 3) local directions selecting b_i
    mask: jnp.ndarray  # (3,) bool: active pairs
    follow_a: jnp.ndarray  # bool: a's curved support follows n
    follow_b: jnp.ndarray  # bool
    mode: jnp.ndarray  # int: SEP, PEN_Z, PEN_FACE or FIXED (how n is determined)
    orient: jnp.ndarray  # +-1: EPA's face normal is orient * unit(cross(w1 - w0, w2 - w0))
    n0: jnp.ndarray  # (3,) the normal used in mode FIXED
    inv_s2: jnp.ndarray  # 1 / scale^2 (row scaling)


def _unit(x):
    nx = safe_norm(x)
    return x / jnp.where(nx > 0.0, nx, 1.0)


def support_pairs(n, theta, keys: Keys):
    """(A (3, 3), B (3, 3)) world support points re-evaluated from their keys."""
    shape_a, Ta, shape_b, Tb = theta
    core_a, _ = core_of(shape_a)
    core_b, _ = core_of(shape_b)
    Ra, ta, Rb, tb = Ta[:3, :3], Ta[:3, 3], Tb[:3, :3], Tb[:3, 3]
    fa = Ra.T @ (-n)
    fb = Rb.T @ n
    A = jax.vmap(lambda r: Ra @ support_keyed(core_a, r, fa, keys.follow_a) + ta)(keys.ref_a)
    B = jax.vmap(lambda r: Rb @ support_keyed(core_b, r, fb, keys.follow_b) + tb)(keys.ref_b)
    return A, B


def residual(x, theta, keys: Keys):
    """KKT residual (7,) of the active-feature problem (see the module docstring)."""
    lam, mu, n = x[:3], x[3], x[4:]
    A, B = support_pairs(n, theta, keys)
    W = A - B
    z = lam @ W
    r_stat = jnp.where(keys.mask, (W @ z - mu) * keys.inv_s2, lam)
    r_sum = jnp.sum(lam) - 1.0
    zu = _unit(z)
    face = keys.orient * _unit(jnp.cross(W[1] - W[0], W[2] - W[0]))
    r_n = jnp.select(
        [keys.mode == SEP, keys.mode == PEN_Z, keys.mode == PEN_FACE],
        [n - zu, n + zu, n + face],
        n - keys.n0,
    )
    return jnp.concatenate([r_stat, r_sum[None], r_n])


def outputs(x, theta, keys: Keys):
    """(d, p_a, p_b, n) from the unknowns x (7,)."""
    lam, n = x[:3], x[4:]
    A, B = support_pairs(n, theta, keys)
    p_a, p_b = lam @ A, lam @ B
    return n @ (p_a - p_b), p_a, p_b, n


def _pinv_solve(J, r):
    return jnp.linalg.pinv(J, rtol=1e-11) @ r


def merge_duplicates(x, theta, keys: Keys):
    """Merge active pairs whose re-evaluated support points coincide (a cylinder's
    followed points, a segment's repeated end): keep the first, add the weights. Returns
    ``(x, keys)`` with a smaller mask, so that weights in [0, 1] mean a valid point."""
    A, B = support_pairs(x[4:], theta, keys)
    tol = 1e-12 * jax.lax.rsqrt(keys.inv_s2)
    lam, mask = x[:3], keys.mask
    for i, j in ((0, 1), (0, 2), (1, 2)):
        same = mask[i] & mask[j] & (safe_norm(A[i] - A[j]) + safe_norm(B[i] - B[j]) <= tol)
        lam = lam.at[i].add(jnp.where(same, lam[j], 0.0)).at[j].set(jnp.where(same, 0.0, lam[j]))
        mask = mask.at[j].set(mask[j] & ~same)
    return x.at[:3].set(lam), keys._replace(mask=mask)


def _member(core, T, pts, lam, mask, tol):
    """Whether ``sum lam_i pts_i`` (world) lies in the core: geometrically for a
    cylinder (whose flat cap may be spanned by rim points with weights outside [0, 1]),
    else by the weights of the distinct points being >= 0."""
    p = lam @ pts
    if core.kind == "cylinder":
        r, hl = core.params
        q = T[:3, :3].T @ (p - T[:3, 3])
        return (safe_norm(q[:2]) <= r + tol) & (jnp.abs(q[2]) <= hl + tol)
    same = safe_norm(pts[:, None, :] - pts[None, :, :]) <= tol
    w = (same & mask[None, :]) @ lam
    return jnp.all(jnp.where(mask, w >= -1e-9, True))


def newton_polish(x, theta, keys: Keys, steps: int):
    """Polish an approximate solution (curved cores: GJK/EPA converge only linearly
    there) by ``steps`` Newton steps on the residual. A result is accepted if its residual
    is below 1e-10, its witnesses are support points of the true shapes along -n / n
    (certificate), they lie in their shapes, and n stayed within 60 deg of the input;
    if the first attempt fails, pairs with negative weight are dropped (contact on a
    lower-dimensional feature) and it is polished again; if that fails too the input is
    returned unchanged. Returns ``(x, keys)``."""
    shape_a, Ta, shape_b, Tb = theta
    core_a, _ = core_of(shape_a)
    core_b, _ = core_of(shape_b)
    scale = jax.lax.rsqrt(keys.inv_s2)
    tol = 1e-9 * scale

    def run(x, keys):
        F = lambda x_: residual(x_, theta, keys)  # noqa: E731

        def step(_, x):
            x = x - _pinv_solve(jax.jacfwd(F)(x), F(x))
            return x.at[4:].set(_unit(x[4:]))

        return jax.lax.fori_loop(0, steps, step, x)

    def accept(x, keys):
        r = residual(x, theta, keys)
        lam, n = x[:3], x[4:]
        A, B = support_pairs(n, theta, keys)
        p_a, p_b = lam @ A, lam @ B
        s_a = Ta[:3, :3] @ support(core_a, Ta[:3, :3].T @ (-n)) + Ta[:3, 3]
        s_b = Tb[:3, :3] @ support(core_b, Tb[:3, :3].T @ n) + Tb[:3, 3]
        cert = (jnp.abs(n @ (s_a - p_a)) < tol) & (jnp.abs(n @ (s_b - p_b)) < tol)
        inside = _member(core_a, Ta, A, lam, keys.mask, tol) & _member(core_b, Tb, B, lam, keys.mask, tol)
        return (jnp.max(jnp.abs(r)) < 1e-10) & cert & inside & (n @ keys.n0 > 0.5)

    def sel(c, a, b):
        return jax.tree_util.tree_map(lambda p, q: jnp.where(c, p, q), a, b)

    x1 = run(x, keys)
    ok1 = accept(x1, keys)
    neg = keys.mask & (x1[:3] < -1e-12)
    keys2 = keys._replace(mask=keys.mask & ~neg)
    lam2 = jnp.where(neg, 0.0, jnp.clip(x1[:3], 0.0, 1.0))
    lam2 = lam2 / jnp.maximum(jnp.sum(lam2), 1e-300)
    x2 = run(jnp.concatenate([lam2, x1[3:]]), keys2)
    ok2 = jnp.any(neg) & accept(x2, keys2)
    return sel(ok1, (x1, keys), sel(ok2, (x2, keys2), (x, keys)))


def implicit_tangent(x, theta, keys: Keys, t_theta):
    """Tangent dx (7,) of the solution for a parameter tangent ``t_theta``."""
    F = lambda x_, th: residual(x_, th, keys)  # noqa: E731
    J = jax.jacfwd(F, argnums=0)(x, theta)
    _, Rt = jax.jvp(lambda th: F(x, th), (theta,), (t_theta,))
    return -_pinv_solve(J, Rt)
