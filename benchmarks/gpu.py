"""Batched dynamics and derivatives on an accelerator (or any JAX backend): throughput per
configuration as the batch grows, and batched whole-rollout gradients.

    python -m benchmarks.gpu [--batches 4096,65536] [--models ur5,solo12,talos] [--algos ...]
                             [--models-dir DIR] [--rollout-batches 1,1024] [--budget-s S]
                             [--json PATH]

Not part of `python -m benchmarks` (it has no `run`): that runner measures against peers
on the same CPU, and this script is for a machine with a GPU, where no peer of ours runs
(Pinocchio has no GPU path). Its table is reported separately in benchmarks/README.md
next to the CPU figures of the same code.

What is timed, all in float64, each row's compile separately from its run (best of 5):

- per configuration, `jax.vmap` over `batch` random states of UR5 (6 DoF), Solo12 (18 DoF,
  free base) and TALOS reduced (38 DoF, free base): `hybrid_dynamics` (the forward
  hybrid algorithm), and the analytic `hybrid_dynamics_derivatives`, `aba_derivatives`,
  `rnea_derivatives`. Hybrid split as in benchmarks/derivatives.py: the free base and
  every other joint passive.
- per rollout, `jax.vmap` over `B` independent control sequences of the gradient of the
  Solo12 rollout loss of benchmarks/derivatives.py (100 explicit-Euler steps, joints
  active, free base passive, the custom JVP rule), reverse mode.

`--models-dir DIR` reads the URDFs from DIR/<relative path as in example-robot-data>
(a machine without the package can be given copies of the three files; no meshes are
read). Rows run in priority order (the hybrid derivatives on every model, the rollout
gradients, then the other algorithms); `--budget-s` starts no new row after that many
seconds, and `--json` rewrites its file atomically after each row, so a run cut short
keeps what it measured.
"""

from __future__ import annotations

import argparse
import json
import os
import time
import warnings

import numpy as np

from benchmarks._common import best_of, erd_dir, time_compile
from benchmarks.derivatives import MODELS, rollout_loss

import jax
import jax.numpy as jnp


def load(key, models_dir):
    import cstorm as cs

    label, rel, fb = MODELS[key]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = cs.load_urdf(os.path.join(models_dir, rel), floating_base=fb, load_meshes=False,
                         inertia_check="lenient")
    return label, m, (6 if fb else 0)


def per_config(jobs, models_dir, repeat=5, deadline=float("inf"), sink=None):
    """Rows: per-configuration time of `algo` on `model` at `batch`, for each
    (model, algo, batch) in `jobs`, in that order; jobs not started before `deadline`
    (time.perf_counter()) are skipped. `sink(row)` is called after each row."""
    import cstorm as cs
    from cstorm.dynamics import derivatives as D

    rows, loaded = [], {}
    for key, name, b in jobs:
        if time.perf_counter() > deadline:
            print(f"skipped (time budget): {key} {name} x {b}", flush=True)
            continue
        if key not in loaded:
            label, m, nfb = load(key, models_dir)
            act = tuple(bool(i % 2) if i >= nfb else False for i in range(m.nv))
            ia = np.nonzero(act)[0]
            ip = np.nonzero(~np.array(act))[0]
            algos = {
                "hybrid_dynamics": lambda q, v, a, m=m, act=act, ia=ia, ip=ip: cs.hybrid_dynamics(
                    m, q, v, a[ia], a[ip], act),
                "hybrid_dynamics_derivatives": lambda q, v, a, m=m, act=act, ia=ia, ip=ip:
                    D.hybrid_dynamics_derivatives(m, q, v, a[ia], a[ip], act),
                "aba_derivatives": lambda q, v, a, m=m: D.aba_derivatives(m, q, v, a),
                "rnea_derivatives": lambda q, v, a, m=m: D.rnea_derivatives(m, q, v, a),
            }
            rng = np.random.default_rng(0)
            nmax = max(bb for kk, _, bb in jobs if kk == key)
            Q = np.stack([m.random_q(rng) for _ in range(nmax)])
            V, A = rng.normal(size=(2, nmax, m.nv))
            loaded[key] = (label, algos, Q, V, A)
        label, algos, Q, V, A = loaded[key]
        Qj, Vj, Aj = (jax.device_put(jnp.asarray(x[:b])) for x in (Q, V, A))
        c, ct = time_compile(jax.vmap(algos[name]), Qj, Vj, Aj)
        t = best_of(lambda: c(Qj, Vj, Aj), repeat=repeat)
        del c
        rows.append(dict(case=f"{label}: {name}", batch=b, us_per_config=t / b * 1e6,
                         call_ms=t * 1e3, compile_s=ct))
        print(_line(rows[-1]), flush=True)
        if sink:
            sink(rows[-1])
    return rows


def rollout_batched(batches, models_dir, steps=100, repeat=5, deadline=float("inf"), sink=None):
    """Rows: vmap over B control sequences of the Solo12 rollout-loss gradient."""
    from cstorm.dynamics.derivatives_fast import hybrid_dynamics_fast

    label, m, nfb = load("solo12", models_dir)
    act = tuple(i >= nfb for i in range(m.nv))
    ia = np.nonzero(act)[0]
    rng = np.random.default_rng(0)
    q0 = jnp.asarray(m.neutral())
    v0 = jnp.asarray(rng.normal(size=m.nv) * 0.1)
    g = jax.vmap(jax.grad(rollout_loss(m, act, hybrid_dynamics_fast, q0, v0)))
    rows = []
    for b in batches:
        if time.perf_counter() > deadline:
            print(f"skipped (time budget): rollout x {b}", flush=True)
            continue
        U = jnp.asarray(rng.normal(size=(b, steps, len(ia))))
        c, ct = time_compile(g, U)
        t = best_of(lambda: c(U), repeat=repeat)
        del c
        rows.append(dict(case=f"{label}: rollout gradient ({steps} Euler steps), grad", batch=b,
                         us_per_config=t / b * 1e6, call_ms=t * 1e3, compile_s=ct))
        print(_line(rows[-1]), flush=True)
        if sink:
            sink(rows[-1])
    return rows


def _line(r):
    return (f"{r['case']} x {r['batch']}: {r['us_per_config']:.3f} us each, call {r['call_ms']:.2f} ms, "
            f"compile {r['compile_s']:.1f} s")


def _table(rows):
    out = ["| case | batch | us per item | call (ms) | compile (s) |", "|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['case']} | {r['batch']} | {r['us_per_config']:.3f} | {r['call_ms']:.2f} | "
                   f"{r['compile_s']:.1f} |")
    return "\n".join(out)


def _device():
    d = jax.devices()[0]
    return f"{d.platform}: {getattr(d, 'device_kind', d)}; jax {jax.__version__}; float64"


ALGOS = ("hybrid_dynamics_derivatives", "hybrid_dynamics", "aba_derivatives", "rnea_derivatives")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--batches", default="4096,65536", help="batch sizes of the per-configuration rows")
    ap.add_argument("--models", default="ur5,solo12,talos")
    ap.add_argument("--algos", default=",".join(ALGOS))
    ap.add_argument("--models-dir", default=None)
    ap.add_argument("--rollout-batches", default="1,1024", help="empty: no rollout rows")
    ap.add_argument("--budget-s", type=float, default=float("inf"),
                    help="start no new row after this many seconds (rows run in priority order)")
    ap.add_argument("--json", default=None, help="rows written here after each row")
    args = ap.parse_args()
    mdir = args.models_dir or erd_dir()
    print(_device(), flush=True)
    t0 = time.perf_counter()
    deadline = t0 + args.budget_s
    done = []

    def sink(row):
        done.append(row)
        if args.json:
            tmp = args.json + ".tmp"
            with open(tmp, "w") as fh:
                json.dump(dict(device=_device(), rows=done), fh, indent=1)
            os.replace(tmp, args.json)

    models = args.models.split(",")
    batches = [int(b) for b in args.batches.split(",")]
    algos = args.algos.split(",")
    # Priority: the hybrid derivatives on every model first, then the rollout gradients,
    # then the other algorithms.
    first = [(k, algos[0], b) for k in models for b in batches]
    rest = [(k, a, b) for a in algos[1:] for k in models for b in batches]
    per_config(first, mdir, deadline=deadline, sink=sink)
    if args.rollout_batches:
        rollout_batched([int(b) for b in args.rollout_batches.split(",")], mdir, deadline=deadline, sink=sink)
    per_config(rest, mdir, deadline=deadline, sink=sink)
    print(f"\n{_device()}; total {time.perf_counter() - t0:.0f} s\n")
    print(_table(done))
