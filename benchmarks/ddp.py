"""The constrained DDP solver on the shipped problems, each solved from a cold compile
cache in its own process: iterations, wall time, compile time, cost, constraint
violation, success, the worst torque/limit ratio on every step, and the paper method's
(SLSQP along the problem's plan) cost and time on the same problem, measured in the same
run.

    python -m benchmarks.ddp [--problems acrobot,tumbler:start,...] [--no-slsqp]
                             [--ddp-options '{"second_order": true}'] [--out PATH]

Problem names: a shipped example (``acrobot``) or ``tumbler:SEGMENT`` (one segment of
the tumbler sequence from its nominal start). Results go to
``benchmarks/results/ddp-<date>.json`` (date, commit, machine, versions, one row per
problem and method) and a table to stdout. ``--ddp-options``: DDP is also run with these
solver options (row ``ddp_options``, printed as ``ddp*``), next to its defaults. A
benchmark, never a test: its times depend on the machine and its load.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile

DEFAULT = ("acrobot", "tumbler:start", "tumbler:standing", "tumbler:roll", "tumbler:handstand")

_CHILD = r"""
import json, sys, time
import jax
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_compilation_cache_dir", sys.argv[3])
import numpy as np
import cstorm as cs
from cstorm.report import torque_check
name, method, options = sys.argv[1], sys.argv[2], json.loads(sys.argv[4]) or None
if name.startswith("tumbler:"):
    from cstorm.examples.tumbler import tumbler_segment
    p = tumbler_segment(name.split(":", 1)[1])
else:
    p = cs.examples.get(name)()
t0 = time.perf_counter()
try:
    s = cs.solve(p, method=method, max_iter=500, options=options)
    tc = torque_check(p, s)
    row = dict(success=s.success, message=s.message, cost=s.cost, violation=s.constraint_violation,
               iterations=s.iterations, wall_s=time.perf_counter() - t0, compile_s=s.compile_time_s,
               torque_ratio=tc["worst_ratio"])
except Exception as e:
    row = dict(success=False, message=f"{type(e).__name__}: {e}", wall_s=time.perf_counter() - t0)
print("RESULT " + json.dumps(row))
"""


def _run(name, method, timeout, options=None):
    with tempfile.TemporaryDirectory() as cache:  # a cold compile cache
        try:
            out = subprocess.run([sys.executable, "-c", _CHILD, name, method, cache, json.dumps(options or {})],
                                 capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return dict(success=False, message=f"no result within {timeout} s")
    for line in out.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    return dict(success=False, message=(out.stderr.strip().splitlines() or ["no output"])[-1])


def _provenance():
    from benchmarks._common import machine
    import cstorm

    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=os.path.dirname(__file__)).stdout.strip()
    except OSError:
        commit = None
    return dict(date=datetime.datetime.now().isoformat(timespec="seconds"), commit=commit, machine=machine(),
                cstorm=cstorm.__version__)


def run(quick=False, problems=DEFAULT, slsqp=True, timeout=1800, ddp_options=None):
    """Rows for the benchmark runner (``cstorm_us``: DDP's wall time in us; ``peer``: the
    paper's SLSQP on the same problem; ``ddp_options``: DDP with these options too)."""
    rows = []
    for name in (problems[:1] if quick else problems):
        d = _run(name, "ddp", timeout)
        d2 = _run(name, "ddp", timeout, ddp_options) if ddp_options else {}
        s = _run(name, "slsqp", timeout) if slsqp else {}
        rows.append(dict(benchmark="ddp", case=name, ddp=d, ddp_options=d2, options=ddp_options or {}, slsqp=s,
                         cstorm_us=d.get("wall_s", float("nan")) * 1e6,
                         peer="SLSQP along the problem's plan (the paper's method)",
                         peer_us=s.get("wall_s", float("nan")) * 1e6 if s else float("nan"),
                         ratio=(d.get("wall_s", float("nan")) / s["wall_s"]) if s.get("wall_s") else float("nan"),
                         compile_s=d.get("compile_s"),
                         notes=f"ddp: {'ok' if d.get('success') else 'FAILED'} cost {d.get('cost')}; "
                               f"slsqp cost {s.get('cost')}"))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problems", default=",".join(DEFAULT))
    ap.add_argument("--no-slsqp", action="store_true")
    ap.add_argument("--timeout", type=float, default=1800)
    ap.add_argument("--ddp-options", default=None, help="DDP options (JSON) to run next to the defaults")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    rows = run(problems=tuple(a.problems.split(",")), slsqp=not a.no_slsqp, timeout=a.timeout,
               ddp_options=json.loads(a.ddp_options) if a.ddp_options else None)
    prov = _provenance()
    out = a.out or os.path.join(os.path.dirname(__file__), "results", f"ddp-{prov['date'][:10]}.json")
    os.makedirs(os.path.dirname(out), exist_ok=True)
    with open(out + ".tmp", "w") as f:
        json.dump(dict(provenance=prov, rows=rows), f, indent=1)
    os.replace(out + ".tmp", out)
    g = lambda r, k, fmt: "-" if r.get(k) is None else format(r[k], fmt)
    print(f"{'problem':20s} {'method':6s} {'ok':3s} {'cost':>10s} {'viol':>8s} {'iter':>5s} {'wall s':>7s} "
          f"{'compile':>7s} {'tau/lim':>7s}")
    for r in rows:
        for m in ("ddp", "ddp_options", "slsqp"):
            x = r.get(m)
            if not x:
                continue
            label = "ddp*" if m == "ddp_options" else m
            print(f"{r['case']:20s} {label:6s} {'yes' if x.get('success') else 'no':3s} {g(x, 'cost', '10.4g')} "
                  f"{g(x, 'violation', '8.1e')} {g(x, 'iterations', '5d')} {g(x, 'wall_s', '7.1f')} "
                  f"{g(x, 'compile_s', '7.1f')} {g(x, 'torque_ratio', '7.2f')}")
    print(f"written to {out}")


if __name__ == "__main__":
    main()
