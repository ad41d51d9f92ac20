"""Contact points of a robot in an environment and their assembly into body wrenches
(`contact_forces`, `ContactData`, `contact_labels`; DESIGN.md items 3-4; see
`contact_forces` for the contact points of each shape). The force law at one point and
its conventions: `cstorm.contact.laws`.
"""

from __future__ import annotations

import jax
import numpy as np
import jax.numpy as jnp

import fnmatch as _fnmatch
from collections.abc import Mapping as _Mapping
from typing import NamedTuple as _NamedTuple

from .. import _pytree
from .. import spatial as _sp
from ..dynamics import _checks
from ..dynamics.kinematics import joint_placements, world_placements, world_twists
from ..errors import InputError
from ..geometry.closed_form import point_shape
from ..geometry.distance import signed_distance
from ..geometry.shapes import Box, Capsule, ConvexMesh, Cylinder, Plane, Sphere
from .environment import Environment
from .laws import ContactParams, point_contact_force
from .plane import plane_points, plane_points_value


_BOX_CORNERS = np.array([[sx, sy, sz] for sz in (-1.0, 1.0) for sy in (-1.0, 1.0) for sx in (-1.0, 1.0)])


def _n_features(shape, n_rim: int) -> int:
    if isinstance(shape, Sphere):
        return 1
    if isinstance(shape, Capsule):
        return 2
    if isinstance(shape, Box):
        return 8
    if isinstance(shape, Cylinder):
        return 2 * n_rim
    if isinstance(shape, ConvexMesh):
        return int(np.shape(shape.vertices)[0])
    raise InputError(f"contact_forces: no contact features for a robot geom of type {type(shape).__name__}")


def _features(shape, n_rim: int):
    """Contact features of a robot shape against a plane, in the shape's frame: centres
    ``(m, 3)`` and radii ``(m,)`` (the feature is the ball of that radius)."""
    if isinstance(shape, Sphere):
        r = jnp.asarray(shape.radius)
        return jnp.zeros((1, 3), r.dtype), r[None]
    if isinstance(shape, Capsule):
        h = 0.5 * jnp.asarray(shape.length)
        z = jnp.zeros_like(h)
        P = jnp.stack([jnp.stack([z, z, -h]), jnp.stack([z, z, h])])
        return P, jnp.broadcast_to(jnp.asarray(shape.radius), (2,))
    if isinstance(shape, Box):
        P = jnp.asarray(_BOX_CORNERS) * jnp.asarray(shape.half_extents)
        return P, jnp.zeros(8, P.dtype)
    if isinstance(shape, Cylinder):
        th = 2.0 * np.pi * np.arange(n_rim) / n_rim
        ring = np.stack([np.cos(th), np.sin(th)], axis=1)  # (n, 2)
        r, h = jnp.asarray(shape.radius), 0.5 * jnp.asarray(shape.length)
        xy = r * jnp.asarray(np.concatenate([ring, ring]))
        z = h * jnp.asarray(np.concatenate([-np.ones(n_rim), np.ones(n_rim)]))
        P = jnp.concatenate([xy, z[:, None]], axis=1)
        return P, jnp.zeros(2 * n_rim, P.dtype)
    if isinstance(shape, ConvexMesh):
        V = jnp.asarray(shape.vertices)
        return V, jnp.zeros(V.shape[0], V.dtype)
    raise InputError(f"contact_forces: no contact features for a robot geom of type {type(shape).__name__}")


class _Layout(_NamedTuple):
    plane_pairs: tuple  # (geom index, obstacle index, n features): features vs a Plane
    shape_pairs: tuple  # (geom index, obstacle index, n features): features vs a bounded obstacle
    near_pairs: tuple  # (geom index, obstacle index)
    self_pairs: tuple  # (geom index a, geom index b)
    labels: tuple  # per point: (geom name, obstacle or other geom name, feature index or -1)
    body: tuple  # per point: robot body index (geom a's body for self pairs)
    other_body: tuple  # per point: -1 (obstacle) or geom b's body (self pairs)
    pair_of_point: tuple  # per point: (geom name, other name), for per-pair parameters


def _is_pattern(s: str) -> bool:
    return any(c in s for c in "*?[")


def _movable(model, g: int) -> bool:
    return model.geom_bodies[g] >= 0 and not isinstance(model.geoms[g], Plane)


def _match_geoms(model, pattern: str, argname: str):
    """Indices of the geoms matching ``pattern``; an exact name of a world-fixed or plane
    geom is an error, patterns skip those silently."""
    out = []
    for g, name in enumerate(model.geom_names):
        if _fnmatch.fnmatchcase(name, pattern):
            if _movable(model, g):
                out.append(g)
            elif not _is_pattern(pattern):
                why = "is attached to the world" if model.geom_bodies[g] < 0 else "is a plane"
                raise InputError(f"contact_forces: {argname} names geom {name!r}, which {why}; only geoms of moving "
                                 "bodies touch obstacles")
    return out


def _layout(model, env: Environment) -> _Layout:
    """Static contact-point layout of (model, environment): which pairs, how many points,
    their labels and bodies. Raises `InputError` on unknown names."""
    gnames, onames = model.geom_names, env.names
    if env.pairs is None:
        sel = [(g, o) for g in range(len(gnames)) if _movable(model, g) for o in range(len(onames))]
    else:
        bad = sorted({gp for gp, _ in env.pairs if not any(_fnmatch.fnmatchcase(n, gp) for n in gnames)})
        if bad:
            raise InputError(f"contact_forces: Environment.pairs name unknown robot geoms {bad}; the model "
                             f"{model.name!r} has geoms {list(gnames)}")
        chosen = set()
        for gp, op in env.pairs:
            for g in _match_geoms(model, gp, "Environment.pairs"):
                for o, on in enumerate(onames):
                    if _fnmatch.fnmatchcase(on, op):
                        chosen.add((g, o))
        sel = sorted(chosen)
    self_sel = set()
    if env.self_collision:
        bad = sorted({p for pair in env.self_collision for p in pair
                      if not any(_fnmatch.fnmatchcase(n, p) for n in gnames)})
        if bad:
            raise InputError(f"contact_forces: Environment.self_collision names unknown robot geoms {bad}; the "
                             f"model {model.name!r} has geoms {list(gnames)}")
        for pa, pb in env.self_collision:
            for a in _match_geoms(model, pa, "Environment.self_collision"):
                for b in _match_geoms(model, pb, "Environment.self_collision"):
                    if model.geom_bodies[a] == model.geom_bodies[b]:
                        if not (_is_pattern(pa) or _is_pattern(pb)):
                            raise InputError(
                                f"contact_forces: Environment.self_collision pairs geoms {gnames[a]!r} and "
                                f"{gnames[b]!r}, which are on the same body "
                                f"{model.body_names[model.geom_bodies[a]]!r}")
                        continue
                    self_sel.add((min(a, b), max(a, b)))
    plane_pairs, shape_pairs, near_pairs = [], [], []
    for g, o in sel:
        ob = env.obstacles[o]
        mode = getattr(ob, "contact", None) or ("features" if isinstance(ob.shape, Plane) else "near_point")
        if mode in ("features", "both"):
            m = _n_features(model.geoms[g], env.cylinder_rim_points)
            (plane_pairs if isinstance(ob.shape, Plane) else shape_pairs).append((g, o, m))
        if mode in ("near_point", "both"):
            near_pairs.append((g, o))
    self_pairs = sorted(self_sel)
    labels, body, other, pairs = [], [], [], []
    for g, o, m in plane_pairs + shape_pairs:
        for j in range(m):
            labels.append((gnames[g], onames[o], j)), body.append(model.geom_bodies[g]), other.append(-1)
            pairs.append((gnames[g], onames[o]))
    for g, o in near_pairs:
        labels.append((gnames[g], onames[o], -1)), body.append(model.geom_bodies[g]), other.append(-1)
        pairs.append((gnames[g], onames[o]))
    for a, b in self_pairs:
        labels.append((gnames[a], gnames[b], -1)), body.append(model.geom_bodies[a])
        other.append(model.geom_bodies[b]), pairs.append((gnames[a], gnames[b]))
    return _Layout(tuple(plane_pairs), tuple(shape_pairs), tuple(near_pairs), tuple(self_pairs), tuple(labels),
                   tuple(body), tuple(other), tuple(pairs))


def contact_labels(model, env: Environment) -> tuple:
    """The static labels of the contact points `contact_forces` returns, in its order:
    a tuple of ``(geom name, obstacle name (or other geom name), feature index)``, the
    feature index being -1 for near-point pairs. Use it to build per-point parameters."""
    if not isinstance(env, Environment):
        raise InputError(f"contact_labels: env must be a cstorm Environment, got {type(env).__name__}")
    return _layout(model, env).labels


def _point_params(params, lay: _Layout) -> ContactParams:
    """ContactParams whose leaves broadcast against the (k,) contact points."""
    k = len(lay.labels)
    if isinstance(params, ContactParams):
        for name in params._data_fields:
            shp = np.shape(getattr(params, name))
            if shp not in ((), (k,)):
                raise InputError(f"contact_forces: ContactParams.{name} has shape {shp}; it must be a scalar or have "
                                 f"one entry per contact point ({k},) (see cstorm.contact.contact_labels)")
        return params
    if not isinstance(params, _Mapping):
        raise InputError("contact_forces: params must be a ContactParams or a mapping {(geom, obstacle): "
                         f"ContactParams}}, got {type(params).__name__}")
    keys = list(params.keys())
    for key in keys:
        if not (isinstance(key, tuple) and len(key) == 2 and all(isinstance(s, str) for s in key)):
            raise InputError(f"contact_forces: params keys must be (geom, obstacle) name patterns, got {key!r}")
        if not isinstance(params[key], ContactParams):
            raise InputError(f"contact_forces: params[{key!r}] must be a ContactParams, got "
                             f"{type(params[key]).__name__}")
    if not keys:
        raise InputError("contact_forces: params is an empty mapping")
    pulling = {params[key].pulling for key in keys}
    if len(pulling) > 1:
        raise InputError("contact_forces: all ContactParams in params must have the same `pulling`")

    def find(g, o):
        for key in keys:
            if (_fnmatch.fnmatchcase(g, key[0]) and _fnmatch.fnmatchcase(o, key[1])):
                return key
        return None

    per_point = []
    unmatched = set()
    for g, o in lay.pair_of_point:
        key = find(g, o) or find(o, g)
        if key is None:
            unmatched.add((g, o))
        per_point.append(key)
    if unmatched:
        raise InputError(f"contact_forces: no entry of params matches the contact pairs {sorted(unmatched)}; keys "
                         f"are {keys} (first match wins; add ('*', '*') for a default)")
    first = params[keys[0]]
    fields = {}
    for name in first._data_fields:
        fields[name] = jnp.stack([jnp.asarray(getattr(params[key], name), dtype=jnp.float64) for key in per_point]) \
            if k else jnp.zeros((0,))
    return _pytree.replace(first, **fields)


@_pytree.pytree_dataclass(meta=("body", "other_body", "labels"))
class ContactData:
    """Per-contact-point data and the assembled external wrenches (a JAX pytree).

    Array fields (``k`` contact points, world coordinates, SI units):
      d (k,): signed distance of the feature to the obstacle, m (< 0 penetrating).
      p_robot (k, 3): the robot's contact point (deepest point of the feature).
      p_obstacle (k, 3): the near point on the obstacle (``p_robot - d n``).
      n (k, 3): unit normal from the obstacle towards the robot.
      velocity (k, 3): velocity of ``p_robot`` as a point of its body, m/s (for
        self-collision: of body a relative to body b at the midpoint of the witness
        points).
      normal_magnitude (k,): ``N`` (N), along ``n``.
      normal_force (k, 3), friction_force (k, 3): N, force on the robot (on body a).
      f_ext (n_bodies, 6): ``[torque about the world origin; force]`` per body, world
        coordinates, what `rnea`/`aba`/`hybrid_dynamics` take.
    Static fields:
      body (k,): robot body of each point; other_body (k,): -1, or body b of a
        self-collision pair (which receives the opposite force);
      labels (k,): ``(geom name, obstacle name (or geom b's name), feature index)``,
        feature index -1 for near-point pairs.
    """

    d: jnp.ndarray
    p_robot: jnp.ndarray
    p_obstacle: jnp.ndarray
    n: jnp.ndarray
    velocity: jnp.ndarray
    normal_magnitude: jnp.ndarray
    normal_force: jnp.ndarray
    friction_force: jnp.ndarray
    f_ext: jnp.ndarray
    body: tuple = ()
    other_body: tuple = ()
    labels: tuple = ()

    @property
    def force(self):
        """(k, 3) total contact force on the robot point, N."""
        return self.normal_force + self.friction_force


def _slice_params(P, i0, i1, k):
    """ContactParams for points ``i0:i1`` of ``k`` (leaves scalars or (k,))."""
    if i0 == 0 and i1 == k:
        return P
    fields = {name: (getattr(P, name)[i0:i1] if np.ndim(getattr(P, name)) else getattr(P, name))
              for name in P._data_fields}
    return _pytree.replace(P, **fields)


def _plane_value(model, q, v, feats, params, bidx):
    """`plane_points` without its derivative rule (plain autodiff; the test oracle)."""
    return plane_points_value(tuple(bidx), model, q, v, feats, params)[:6]


def contact_forces(model, env: Environment, params, q, v, *, jacobians: str = "analytic") -> ContactData:
    """Smooth penalty contact forces between a robot and its environment, and the body
    wrenches they make.

    Args:
      model: the robot `Model` (collision shapes ``model.geoms`` on ``geom_bodies`` at
        ``geom_poses``, body from shape).
      env: `cstorm.Environment` (obstacles and pair selection).
      params: `ContactParams` applied to every point (its leaves scalars or ``(k,)``, one
        entry per contact point in the order of `contact_labels`), or a mapping
        ``{(geom pattern, obstacle pattern): ContactParams}`` for per-pair values
        (``fnmatch`` patterns, first matching key in insertion order wins, self-collision
        pairs match either order; every pair must match a key; all entries must share
        ``pulling``). E.g. ``{("hand*", "ground"): rubber, ("*", "*"): default}``.
      q: (nq,) configuration. v: (nv,) velocity.
    Returns:
      `ContactData` with per-point ``d, p_robot, p_obstacle, n, velocity,
      normal_magnitude, normal_force, friction_force`` and ``f_ext`` (n_bodies, 6).

    Contact points (``k`` in all, static; order: plane pairs with their features, then
    feature pairs against other obstacles (boxes), then near-point pairs, then
    self-collision pairs; pairs in (geom, obstacle) index order within each group):

    - Robot geom vs a `Plane` obstacle (ground, incline): one point per feature, each
      the ball ``(centre c, radius r)`` whose distance to the plane
      ``d = N . c - r - offset`` is smooth in ``q``; the robot point is the feature's
      deepest point ``c - r N``:
        * `Sphere`: 1 (its centre, r = radius);
        * `Capsule`: 2 (the end spheres, centres ``(0, 0, +-length/2)``);
        * `Box`: 8 corners (r = 0);
        * `Cylinder`: ``env.cylinder_rim_points`` (default 8) equally spaced points on
          each end circle, angles ``2 pi i / n`` from local x, first the ``z = -length/2``
          rim then the ``+length/2`` rim: 16 in all by default. A cylinder lying on its
          side thus rests on a ``n``-gon prism: its centre height varies by
          ``radius (1 - cos(pi / n))`` (7.6 % of the radius for n = 8) as it rolls;
          raise ``n`` or use a capsule for wheels;
        * `ConvexMesh`: every vertex (r = 0).
    - Robot geom vs a bounded obstacle whose ``contact`` is ``"features"`` (the default
      for boxes: `cstorm.contact.box`, ``platform``, ``step``) or ``"both"``: the
      same features, each with the closed-form signed distance of its centre to the
      obstacle minus its radius (`cstorm.geometry.closed_form.point_shape`), robot point
      ``c - r n``, obstacle point the nearest surface point. A box resting on a platform
      top is thus held at its four lower corners, like on the ground; near the
      obstacle's edges the normal turns round the edge (C1 outside the obstacle; inside,
      where the nearest face changes, values are continuous and derivatives finite).
    - Robot geom vs an obstacle whose ``contact`` is ``"near_point"`` (the default for
      spheres, capsules, cylinders and meshes) or ``"both"``: one near-point pair from
      `cstorm.signed_distance` (robot shape as ``a``, obstacle as ``b``), so it jumps
      between witnesses where the nearest feature changes.
    - Self-collision pairs (opt-in): one near-point pair; the force ``f`` on body a and
      ``-f`` on body b both act at the midpoint of the witness points (no net wrench),
      ``velocity`` is that of a relative to b at that point.

    Forces follow `point_contact_force` with the velocity of ``p_robot`` as a point of
    its body (``v_o + omega x (p_robot - o)`` from the body twists, computed once for
    all bodies). Each point's wrench ``[p x f; f]`` (``p = p_robot``) is summed into its
    body's row of ``f_ext``, so ``rnea(.., f_ext=0) - rnea(.., f_ext) = sum_k J_k^T f_k``
    with ``J_k`` the linear rows of ``point_jacobian`` at ``p_robot``.

    Friction near zero slip is a viscous damper ``1.5 mu N / v_max`` (N s/m). A body on
    an incline of angle ``theta`` with ``tan(theta) < mu`` therefore creeps downhill at
    the speed ``s`` that solves ``gamma(s) = tan(theta) / mu``, i.e.
    ``1.5 x - 0.5 x^3 = tan(theta)/mu`` with ``x = s / v_max``; for small ratios
    ``s ~= v_max tan(theta) / (1.5 mu)`` (e.g. 0.0117 m/s at 5 deg, mu = 0.5,
    v_max = 0.1; verified by simulation in tests/test_contact.py). Lower ``v_max``
    to creep less (at the price of a stiffer damper).

    Works under ``jit``, ``vmap`` and ``grad``/``jacfwd`` (w.r.t. q, v, model, env and
    params leaves). Unknown geom or obstacle names in ``env.pairs`` raise `InputError`.

    ``jacobians``: ``"analytic"`` (default): the plane-pair points carry the analytic
    derivative rule of `cstorm.contact.plane` (the same values; their JVP w.r.t.
    ``(q, v)`` costs O(k nv) instead of forward mode through the kinematics);
    ``"autodiff"``: plain JAX differentiation of the same code (the reference the rule
    is tested against). Other pairs are always differentiated by JAX.
    """
    if jacobians not in ("analytic", "autodiff"):
        raise InputError(f"contact_forces: jacobians must be 'analytic' or 'autodiff', got {jacobians!r}")
    if not isinstance(env, Environment):
        raise InputError(f"contact_forces: env must be a cstorm Environment, got {type(env).__name__}")
    q = _checks.config(model, q, "contact_forces")
    v = _checks.vec(model, v, model.nv, "v", "contact_forces")
    lay = _layout(model, env)
    P = _point_params(params, lay)
    k, nb = len(lay.labels), model.n_bodies
    dtype = jnp.result_type(q.dtype, v.dtype, jnp.float64 if jax.config.jax_enable_x64 else jnp.float32)
    if k == 0:
        z1, z3 = jnp.zeros((0,), dtype), jnp.zeros((0, 3), dtype)
        return ContactData(z1, z3, z3, z3, z3, z1, z3, z3, jnp.zeros((nb, 6), dtype), (), (), ())

    kp = sum(m for _, _, m in lay.plane_pairs)
    if kp < k:  # kinematics for the other pairs (the plane block computes its own)
        Rs, ps, Ss = joint_placements(model, q)
        oR, op = world_placements(model, Rs, ps)
        Rw, pw = jnp.stack(oR), jnp.stack(op)
        w, vo = world_twists(model, Rs, ps, Ss, oR, v)

    def point_velocity(b, x):  # b: static index array, x: (m, 3) world points
        return vo[b] + jnp.cross(w[b], x - pw[b])

    ds, p_rob, p_obs, ns, vel, app = [], [], [], [], [], []
    # --- plane pairs: all features stacked, one array computation with analytic
    # derivatives w.r.t. (q, v) (`cstorm.contact.plane`) ----------------------------
    if lay.plane_pairs:
        feats = {}
        Pb, rad, Nw, off, bidx = [], [], [], [], []
        for g, o, m in lay.plane_pairs:
            if g not in feats:
                Pl, r = _features(model.geoms[g], env.cylinder_rim_points)
                Tg = model.geom_poses[g]
                feats[g] = (Pl @ Tg[:3, :3].T + Tg[:3, 3], r)
            pb, r = feats[g]
            ob = env.obstacles[o]
            N = ob.pose[:3, :3] @ ob.shape.normal
            Pb.append(pb), rad.append(r)
            Nw.append(jnp.broadcast_to(N, (m, 3)))
            off.append(jnp.broadcast_to(ob.shape.offset + N @ ob.pose[:3, 3], (m,)))
            bidx += [model.geom_bodies[g]] * m
        Pb, rad, Nw, off = (jnp.concatenate(a) for a in (Pb, rad, Nw, off))
        plane_fn = plane_points if jacobians == "analytic" else _plane_value
        d, pr, u, N_mag_p, f_t_p, W_p = plane_fn(model, q, v, (Pb, rad, Nw, off), _slice_params(P, 0, kp, k),
                                                 tuple(bidx))
        ds.append(d), p_rob.append(pr), p_obs.append(pr - d[:, None] * Nw), ns.append(Nw)
        vel.append(u), app.append(pr)
    # --- features vs bounded obstacles (boxes: platform tops, steps) ---------------------
    for g, o, m in lay.shape_pairs:
        ob = env.obstacles[o]
        Pl, r = _features(model.geoms[g], env.cylinder_rim_points)
        Tg = model.geom_poses[g]
        b = model.geom_bodies[g]
        x = (Pl @ Tg[:3, :3].T + Tg[:3, 3]) @ Rw[b].T + pw[b]  # (m, 3) feature centres, world
        dc, po, nn = jax.vmap(lambda xi: point_shape(xi, ob.shape, ob.pose[:3, :3], ob.pose[:3, 3]))(x)
        d = dc - r
        pr = x - r[:, None] * nn
        bidx = np.full(m, b)
        ds.append(d), p_rob.append(pr), p_obs.append(po), ns.append(nn)
        vel.append(point_velocity(bidx, pr)), app.append(pr)
    # --- near-point pairs (robot geom vs a bounded obstacle) ---------------------------
    def geom_pose(g):
        b = model.geom_bodies[g]
        return _sp.homogeneous(Rw[b], pw[b]) @ model.geom_poses[g]

    for g, o in lay.near_pairs:
        ob = env.obstacles[o]
        d, pa, pb, n = signed_distance(model.geoms[g], geom_pose(g), ob.shape, ob.pose)
        b = np.asarray([model.geom_bodies[g]])
        ds.append(d[None]), p_rob.append(pa[None]), p_obs.append(pb[None]), ns.append(n[None])
        vel.append(point_velocity(b, pa[None])), app.append(pa[None])
    # --- self-collision pairs ------------------------------------------------------------
    for a, bg in lay.self_pairs:
        d, pa, pb, n = signed_distance(model.geoms[a], geom_pose(a), model.geoms[bg], geom_pose(bg))
        mid = 0.5 * (pa + pb)[None]
        ba, bb = np.asarray([model.geom_bodies[a]]), np.asarray([model.geom_bodies[bg]])
        ds.append(d[None]), p_rob.append(pa[None]), p_obs.append(pb[None]), ns.append(n[None])
        vel.append(point_velocity(ba, mid) - point_velocity(bb, mid)), app.append(mid)
    d, pr, po, n, vv, ap = (jnp.concatenate(a) for a in (ds, p_rob, p_obs, ns, vel, app))

    if kp < k:  # the other points' forces and wrenches (k, 6) about the world origin
        f, N_mag, f_t = point_contact_force(d[kp:], n[kp:], vv[kp:], _slice_params(P, kp, k, k))
        W = jnp.concatenate([jnp.cross(ap[kp:], f), f], axis=1)
        if kp:
            N_mag, f_t, W = (jnp.concatenate(a) for a in ((N_mag_p, N_mag), (f_t_p, f_t), (W_p, W)))
    else:
        N_mag, f_t, W = N_mag_p, f_t_p, W_p
    A = np.zeros((nb, k))
    A[np.asarray(lay.body), np.arange(k)] = 1.0
    oth = np.asarray(lay.other_body)
    sel = np.nonzero(oth >= 0)[0]
    A[oth[sel], sel] -= 1.0
    f_ext = jnp.asarray(A, W.dtype) @ W
    return ContactData(d=d, p_robot=pr, p_obstacle=po, n=n, velocity=vv, normal_magnitude=N_mag,
                       normal_force=N_mag[:, None] * n, friction_force=f_t, f_ext=f_ext, body=lay.body,
                       other_body=lay.other_body, labels=lay.labels)
