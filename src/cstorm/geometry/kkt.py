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
from .support import core_of, support_keyed

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


def newton_polish(x, theta, keys: Keys, steps: int):
    """``steps`` Newton steps on the residual (for curved cores, whose GJK/EPA solutions
    are approximate); a step is kept only if it reduces the residual norm and leaves the
    weights in [-1e-9, 1 + 1e-9]."""
    F = lambda x_: residual(x_, theta, keys)  # noqa: E731
    for _ in range(steps):
        r = F(x)
        J = jax.jacfwd(F)(x)
        x_new = x - _pinv_solve(J, r)
        x_new = x_new.at[4:].set(_unit(x_new[4:]))
        r_new = F(x_new)
        lam = x_new[:3]
        ok = (r_new @ r_new < r @ r) & jnp.all(lam >= -1e-9) & jnp.all(lam <= 1.0 + 1e-9)
        x = jnp.where(ok, x_new, x)
    return x


def implicit_tangent(x, theta, keys: Keys, t_theta):
    """Tangent dx (7,) of the solution for a parameter tangent ``t_theta``."""
    F = lambda x_, th: residual(x_, th, keys)  # noqa: E731
    J = jax.jacfwd(F, argnums=0)(x, theta)
    _, Rt = jax.jvp(lambda th: F(x, th), (theta,), (t_theta,))
    return -_pinv_solve(J, Rt)
