"""Contact geometry benchmark: `cstorm.signed_distance` per shape pair against coal.

    python -m benchmarks.contact [--quick] [--batch 1024] [--pairs box-box,cyl-plane] [--json]

For each ordered shape pair (sphere, capsule, box, cylinder, convex mesh, and each of
them against a half-space plane) on the same random poses (random orientations, centres
at random directions and distances so that about half of the pairs penetrate):

- **cstorm batched**: ``jit(vmap(signed_distance))`` over ``batch`` pose pairs, time per
  pair; and the same with the Jacobian of ``(d, p_a, p_b, n)`` w.r.t. body twists of
  both poses (``jacfwd``, 12 tangents: closed forms differentiated by JAX, GJK/EPA pairs
  by the implicit-function rule);
- **cstorm single call**: ``jit(signed_distance)`` on one pose pair (includes JAX's
  per-call dispatch, which dominates at this size);
- **coal**: ``coal.distance`` (signed distance with witness points and normal) and
  ``coal.collide`` (with contact information) called from a Python loop over the same
  poses, transforms and shapes built beforehand; coal gives no derivatives.

Compile times are measured separately (``jit(...).lower(...).compile()``) and are not in
the run times; run times are the best of several repeats. ``ratio`` = cstorm / peer
(< 1: cstorm faster). Times in microseconds per pose pair. On a machine shared with
other jobs both sides slow down and the ratios carry noise.

`run(quick=False)` returns rows (dicts with ``benchmark, case, cstorm_us, peer, peer_us,
ratio, compile_s, notes``) for the ``python -m benchmarks`` runner.
"""

from __future__ import annotations

import argparse
import json
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from benchmarks._common import best_of, machine, table, time_compile  # noqa: E402

PAIRS = ["sphere-plane", "capsule-plane", "box-plane", "cyl-plane", "mesh-plane",
         "sphere-sphere", "sphere-capsule", "capsule-capsule", "sphere-box", "sphere-cyl",
         "capsule-box", "capsule-cyl", "box-box", "box-cyl", "cyl-cyl",
         "sphere-mesh", "capsule-mesh", "box-mesh", "cyl-mesh", "mesh-mesh"]
QUICK_PAIRS = ["box-plane", "capsule-capsule", "sphere-box", "box-box", "box-cyl", "box-mesh"]
_BOUND = {"sphere": 0.2, "capsule": 0.3, "box": 0.27, "cyl": 0.21, "mesh": 0.3, "plane": 0.0}


def _shapes():
    from cstorm.geometry import Box, Capsule, ConvexMesh, Cylinder, Plane, Sphere

    return {
        "sphere": Sphere(0.2),
        "capsule": Capsule(0.1, 0.4),
        "box": Box([0.2, 0.15, 0.1]),
        "cyl": Cylinder(0.15, 0.3),
        "mesh": ConvexMesh(np.random.default_rng(5).normal(size=(32, 3)) * 0.15),
        "plane": Plane([0.0, 0.0, 1.0], 0.0),
    }


def _rotations(rng, n):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)


def pose_pairs(na, nb, n, seed=0):
    """(Ta, Tb), each (n, 4, 4): uniform random orientations; b's centre in
    [-0.3, 0.3]^3, a's at a random direction and distance U[0.2, 1.4] (r_a + r_b) from it
    (r: bounding radii), so that about half penetrate. Against the plane z <= 0 (b at
    the identity) a's centre is at height U[0.3, 1.5] r_a."""
    rng = np.random.default_rng(seed)
    Ta, Tb = np.tile(np.eye(4), (n, 1, 1)), np.tile(np.eye(4), (n, 1, 1))
    Ta[:, :3, :3] = _rotations(rng, n)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    if nb == "plane":
        Ta[:, :3, 3] = np.c_[rng.uniform(-0.3, 0.3, (n, 2)), rng.uniform(0.3, 1.5, n) * _BOUND[na]]
    else:
        Tb[:, :3, :3] = _rotations(rng, n)
        Tb[:, :3, 3] = rng.uniform(-0.3, 0.3, (n, 3))
        Ta[:, :3, 3] = Tb[:, :3, 3] + rng.uniform(0.2, 1.4, n)[:, None] * (_BOUND[na] + _BOUND[nb]) * u
    return Ta, Tb


def _coal_runner():
    """(distance_loop, collide_loop) timing functions, or None without coal."""
    try:
        import coal
    except ImportError:
        return None
    from cstorm.geometry.interop import to_coal as shape

    def loops(sa, Ta, sb, Tb, repeat):
        ca, cb = shape(sa), shape(sb)
        ta = [coal.Transform3s(T[:3, :3], T[:3, 3]) for T in Ta]
        tb = [coal.Transform3s(T[:3, :3], T[:3, 3]) for T in Tb]
        dreq = coal.DistanceRequest()
        dreq.enable_signed_distance = True
        dres = coal.DistanceResult()
        creq = coal.CollisionRequest()
        creq.enable_contact = True
        cres = coal.CollisionResult()
        dist = coal.distance
        coll = coal.collide

        def run_distance():
            for a, b in zip(ta, tb):
                dres.clear()
                dist(ca, a, cb, b, dreq, dres)

        def run_collide():
            for a, b in zip(ta, tb):
                cres.clear()
                coll(ca, a, cb, b, creq, cres)

        out = []
        for f in (run_distance, run_collide):
            best = float("inf")
            for _ in range(repeat):
                t0 = time.perf_counter()
                f()
                best = min(best, time.perf_counter() - t0)
            out.append(best / len(ta))
        return out

    return loops


def bench_pair(pair, batch, repeat, coal_loops, shapes):
    """Rows (dicts) for one ordered pair ``"a-b"``."""
    from cstorm.geometry import signed_distance
    from cstorm.spatial import homogeneous, se3_exp

    na, nb = pair.split("-")
    sa, sb = shapes[na], shapes[nb]
    Ta, Tb = pose_pairs(na, nb, batch)
    A, B = jnp.asarray(Ta), jnp.asarray(Tb)

    def val(Ta, Tb):
        return signed_distance(sa, Ta, sb, Tb)

    def pert(T, xi):
        R, p = se3_exp(xi)
        return T @ homogeneous(R, p)

    def val_jac(Ta, Tb):
        def f(xi):
            d, pa, pb, n = signed_distance(sa, pert(Ta, xi[:6]), sb, pert(Tb, xi[6:]))
            return jnp.concatenate([d[None], pa, pb, n])

        return jax.jacfwd(f)(jnp.zeros(12, Ta.dtype))

    single, c_single = time_compile(val, A[0], B[0])
    batched, c_batch = time_compile(jax.vmap(val), A, B)
    batched_j, c_jac = time_compile(jax.vmap(val_jac), A, B)
    d = np.asarray(batched(A, B)[0])
    pen = float(np.mean(d < 0))
    t_batch = best_of(lambda: batched(A, B), repeat) / batch
    t_jac = best_of(lambda: batched_j(A, B), repeat) / batch
    n1 = min(batch, 200)
    t_single = best_of(lambda: [single(A[k], B[k]) for k in range(n1)][-1], repeat) / n1
    if coal_loops is not None:
        t_cd, t_cc = coal_loops(sa, Ta, sb, Tb, repeat)
        peer = "coal.distance (Python loop)"
    else:
        t_cd = t_cc = None
        peer = "coal not installed"
    note = f"batch {batch}, {pen:.0%} penetrating"
    if t_cc is not None:
        note += f"; coal.collide {t_cc * 1e6:.2f} us"

    def row(case, t, c, extra=""):
        return dict(benchmark="contact", case=f"{pair} {case}", cstorm_us=t * 1e6, peer=peer,
                    peer_us=None if t_cd is None else t_cd * 1e6, ratio=None if t_cd is None else t / t_cd,
                    compile_s=c, notes=note + extra)

    return [row("distance, vmap batch", t_batch, c_batch),
            row("distance + Jacobian (12 twists), vmap batch", t_jac, c_jac, "; coal gives no derivatives"),
            row("distance, single jit call", t_single, c_single, "; includes JAX dispatch")]


def run(quick: bool = False, batch: int | None = None, pairs=None, repeat: int | None = None) -> list[dict]:
    """Benchmark rows (see the module docstring). ``quick``: 6 representative pairs,
    batch 256, 3 repeats; otherwise all 20 pairs, batch 1024, 5 repeats."""
    batch = batch or (256 if quick else 1024)
    repeat = repeat or (3 if quick else 5)
    pairs = list(pairs or (QUICK_PAIRS if quick else PAIRS))
    shapes = _shapes()
    coal_loops = _coal_runner()
    rows = []
    for p in pairs:
        if p.split("-")[0] not in shapes or p.split("-")[1] not in shapes:
            raise ValueError(f"unknown pair {p!r}; pairs are {PAIRS}")
        rows += bench_pair(p, batch, repeat, coal_loops, shapes)
    return rows


def _fmt(x, spec):
    return "-" if x is None else format(x, spec)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--batch", type=int, default=None)
    ap.add_argument("--repeat", type=int, default=None)
    ap.add_argument("--pairs", default=None, help="comma-separated, e.g. box-box,cyl-plane")
    ap.add_argument("--json", action="store_true", help="print the rows as one JSON list")
    args = ap.parse_args()
    rows = run(args.quick, args.batch, args.pairs.split(",") if args.pairs else None, args.repeat)
    if args.json:
        print(json.dumps(rows))
        return
    print(f"Machine: {machine()}; times in microseconds per pose pair; ratio = cstorm / coal.distance\n")
    print(table([[r["case"], _fmt(r["cstorm_us"], ".2f"), _fmt(r["peer_us"], ".2f"), f"**{_fmt(r['ratio'], '.2f')}**",
                  _fmt(r["compile_s"], ".1f"), r["notes"]] for r in rows],
                ["case", "cstorm (us)", "coal.distance (us)", "ratio", "compile (s)", "notes"]))


if __name__ == "__main__":
    main()
