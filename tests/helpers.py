"""Test helpers: seeded random kinematic trees, manifold finite differences, and the
`cstorm` command run in-process."""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import jax.numpy as jnp

import cstorm as cs


def random_inertia(rng, mass):
    """A physically valid rotational inertia about the CoM (random box, rotated)."""
    dims = rng.uniform(0.05, 0.5, size=3)
    d = mass / 12.0 * np.array([dims[1] ** 2 + dims[2] ** 2, dims[0] ** 2 + dims[2] ** 2, dims[0] ** 2 + dims[1] ** 2])
    A = rng.normal(size=(3, 3))
    Q, _ = np.linalg.qr(A)
    return Q @ np.diag(d) @ Q.T


def random_tree(topology_seed: int, param_seed: int | None = None, n_bodies: int = 7, max_depth: int = 5,
                joint_types=("revolute", "prismatic", "free", "ball", "revolute"), floating: bool = True,
                fixed_links: bool = True, armature: bool = True):
    """A seeded random branched tree. The topology (parents, joint types, fixed links)
    depends only on ``topology_seed``; numbers (inertias, placements, axes) on
    ``param_seed``, so many parameter draws of one topology share compiled functions."""
    trng = np.random.default_rng(topology_seed)
    prng = np.random.default_rng(topology_seed * 1000 + (param_seed or 0))
    b = cs.ModelBuilder(f"random_tree_{topology_seed}_{param_seed}")
    depth = {}
    names = []
    for i in range(n_bodies):
        name = f"b{i}"
        if i == 0:
            parent, jt = None, ("free" if floating else "revolute")
            depth[name] = 1
        else:
            cands = [n for n in names if depth[n] < max_depth]
            parent = cands[trng.integers(len(cands))]
            jt = joint_types[trng.integers(len(joint_types))]
            depth[name] = depth[parent] + 1
        m = prng.uniform(0.2, 3.0)
        b.add_body(name, parent, jt, mass=m, com=prng.uniform(-0.2, 0.2, 3), inertia=random_inertia(prng, m),
                   xyz=prng.uniform(-0.5, 0.5, 3) if i else None, rpy=prng.uniform(-np.pi, np.pi, 3) if i else None,
                   axis=prng.normal(size=3),
                   armature=(prng.uniform(0, 0.1) if armature and jt in ("revolute", "prismatic") else 0.0))
        names.append(name)
        if fixed_links and trng.uniform() < 0.3:
            ln = f"{name}_fixed"
            mf = prng.uniform(0.1, 1.0)
            b.add_link(ln, mass=mf, com=prng.uniform(-0.1, 0.1, 3), inertia=random_inertia(prng, mf))
            b.add_joint(f"{ln}_joint", "fixed", name, ln, xyz=prng.uniform(-0.3, 0.3, 3), rpy=prng.uniform(-1, 1, 3))
    b.gravity = np.array([0.0, 0.0, -9.81])
    return b.build()


def random_state(model, rng):
    q = jnp.asarray(model.random_q(rng))
    v = jnp.asarray(rng.normal(size=model.nv))
    a = jnp.asarray(rng.normal(size=model.nv))
    return q, v, a


def manifold_fd(f, model, q, eps=1e-6):
    """Central finite-difference Jacobian of f(q) w.r.t. a tangent perturbation of q:
    columns ``(f(q (+) eps e_k) - f(q (+) -eps e_k)) / (2 eps)``."""
    cols = []
    for k in range(model.nv):
        e = jnp.zeros(model.nv).at[k].set(eps)
        cols.append((np.asarray(f(cs.integrate(model, q, e))) - np.asarray(f(cs.integrate(model, q, -e)))) / (2 * eps))
    return np.stack(cols, axis=-1)


def run_cli(argv):
    """Run the ``cstorm`` command in this process: ``(exit code, stdout, stderr)``."""
    from cstorm.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, out.getvalue(), err.getvalue()


def one_json(stdout):
    """The one JSON object a ``--json`` run prints on stdout (asserts there is exactly one)."""
    lines = [ln for ln in stdout.splitlines() if ln.strip()]
    assert len(lines) == 1, stdout
    obj = json.loads(lines[0])
    assert isinstance(obj, dict)
    return obj
