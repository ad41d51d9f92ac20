"""Run every benchmark and write each one's results to benchmarks/results/NAME.json.

    python -m benchmarks [--quick] [--only NAME[,NAME...]] [--write | --no-write] [--json PATH]

Each benchmark module in this package (every ``benchmarks/<name>.py`` not starting with
``_``) exposes ``run(quick=False) -> list[dict]``; each row has the keys

    benchmark  the module's name (dynamics, derivatives, contact, trajectory, ...)
    case       what was timed (model, algorithm, shape pair, ...)
    cstorm_us  cstorm's time in microseconds (per configuration for batched runs)
    peer       the peer measured in the same run (e.g. "Pinocchio computeABADerivatives")
    peer_us    the peer's time in microseconds, same unit as cstorm_us
    ratio      cstorm_us / peer_us (< 1: cstorm faster)
    compile_s  cstorm's compile time in seconds (separate from the run time)
    notes      free text

A module without ``run``, or whose import or ``run`` fails, is skipped with a printed
note (its results file then records the reason), so the runner works while modules are
being changed. ``--quick`` asks each module for a short smoke run (small batches, few
repeats): its numbers are noisy and it writes no results file unless ``--write``.
A results file holds ``benchmark, date, commit, machine, versions, load_average, quick``
and ``rows`` (or ``error``); the markdown table of the run is printed.
"""

from __future__ import annotations

import argparse
import datetime
import importlib
import json
import math
import os
import pkgutil
import platform
import subprocess
import sys
import time
import traceback

from benchmarks._common import machine

KEYS = ("benchmark", "case", "cstorm_us", "peer", "peer_us", "ratio", "compile_s", "notes")
HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
ORDER = ("dynamics", "derivatives", "contact", "trajectory")
# Run by hand on a machine with an accelerator (no peer of ours runs there): see gpu.py.
EXCLUDE = ("gpu",)


def modules() -> list[str]:
    """Benchmark module names: the known ones first, then any others in the package."""
    found = sorted(m.name for m in pkgutil.iter_modules([HERE])
                   if not m.name.startswith("_") and m.name not in EXCLUDE)
    return [n for n in ORDER if n in found] + [n for n in found if n not in ORDER]


def _num(x, spec):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    if isinstance(x, (int, float)):
        return format(x, spec)
    return str(x)


def _us(x):
    """Microseconds with about three significant digits."""
    if not isinstance(x, (int, float)) or x is None:
        return _num(x, "")
    return _num(x, ".3g" if abs(x) < 100 else ".0f")


def markdown(rows: list[dict]) -> str:
    """The rows as one markdown table (columns in KEYS order, `benchmark` omitted when
    all rows share it)."""
    hdr = ["case", "cstorm (us)", "peer", "peer (us)", "ratio cstorm / peer", "compile (s)", "notes"]
    out = ["| " + " | ".join(hdr) + " |", "|" + "|".join("---" for _ in hdr) + "|"]
    for r in rows:
        ratio = r.get("ratio")
        cells = [str(r.get("case", "")), _us(r.get("cstorm_us")), str(r.get("peer") or "-"), _us(r.get("peer_us")),
                 f"**{ratio:.2f}**" if isinstance(ratio, (int, float)) and math.isfinite(ratio) else _num(ratio, ""),
                 _num(r.get("compile_s"), ".1f"), str(r.get("notes") or "").replace("|", "/")]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out)


def _normalize(name, rows):
    out = []
    for r in rows:
        r = dict(r)
        r.setdefault("benchmark", name)
        for k in KEYS:
            r.setdefault(k, None)
        if r["ratio"] is None and isinstance(r["cstorm_us"], (int, float)) and isinstance(r["peer_us"], (int, float)) \
                and r["peer_us"]:
            r["ratio"] = r["cstorm_us"] / r["peer_us"]
        out.append(r)
    return out


def run_all(names, quick):
    """{name: rows or an error string}, running one module at a time."""
    results = {}
    for name in names:
        t0 = time.perf_counter()
        print(f"== {name}", flush=True)
        try:
            mod = importlib.import_module(f"benchmarks.{name}")
        except Exception as e:  # noqa: BLE001 - report and go on
            traceback.print_exc()
            results[name] = f"skipped: import failed ({type(e).__name__}: {e})"
            print(f"-- {name}: {results[name]}", flush=True)
            continue
        if not callable(getattr(mod, "run", None)):
            results[name] = "skipped: the module has no run(quick=False)"
            print(f"-- {name}: {results[name]}", flush=True)
            continue
        try:
            rows = mod.run(quick=quick)
        except Exception as e:  # noqa: BLE001
            traceback.print_exc()
            results[name] = f"skipped: run() failed ({type(e).__name__}: {e})"
            print(f"-- {name}: {results[name]}", flush=True)
            continue
        results[name] = _normalize(name, rows or [])
        print(f"-- {name}: {len(results[name])} rows in {time.perf_counter() - t0:.0f} s", flush=True)
    return results


def commit() -> str:
    """The checked-out commit (with ``+dirty`` when the tree has changes), or "unknown"."""
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=HERE, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=HERE,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")


def versions() -> dict:
    """Versions of Python and of the libraries the benchmarks time or compare with."""
    out = {"python": platform.python_version()}
    for name in ("cstorm", "jax", "jaxlib", "numpy", "pinocchio", "mujoco", "coal"):
        try:
            out[name] = str(importlib.import_module(name).__version__)
        except Exception:  # noqa: BLE001 - a peer that is not installed is recorded as absent
            out[name] = None
    return out


def record(name, rows, quick) -> dict:
    """One module's results file: the run's provenance and its rows (or the reason it was skipped)."""
    out = dict(benchmark=name, date=datetime.date.today().isoformat(), commit=commit(), machine=machine(),
               versions=versions(), load_average=[round(x, 2) for x in os.getloadavg()], quick=quick)
    out.update(error=rows) if isinstance(rows, str) else out.update(rows=rows)
    return out


def write_results(results, quick, directory=RESULTS):
    """Write ``directory/NAME.json`` for each module run (atomically)."""
    os.makedirs(directory, exist_ok=True)
    for name, rows in results.items():
        path = os.path.join(directory, f"{name}.json")
        with open(path + ".tmp", "w") as f:
            json.dump(record(name, rows, quick), f, indent=1, default=str)
            f.write("\n")
        os.replace(path + ".tmp", path)
        print(f"wrote {path}")


def report(results) -> str:
    """The run's tables, one markdown section per module."""
    return "\n\n".join(f"### {n}\n\n" + (r if isinstance(r, str) else markdown(r)) for n, r in results.items())


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short smoke run (noisy numbers; no results file)")
    ap.add_argument("--only", default=None, help="comma-separated module names, e.g. derivatives,dynamics")
    ap.add_argument("--write", action="store_true", help="write the results files even with --quick")
    ap.add_argument("--no-write", action="store_true", help="print the tables only")
    ap.add_argument("--json", default=None, help="also write all rows to this JSON file")
    args = ap.parse_args(argv)
    names = modules()
    if args.only:
        want = [n.strip() for n in args.only.split(",") if n.strip()]
        unknown = [n for n in want if n not in names]
        if unknown:
            ap.error(f"unknown benchmark(s) {unknown}; available: {names}")
        names = want
    results = run_all(names, args.quick)
    print(report(results))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({n: record(n, r, args.quick) for n, r in results.items()}, f, indent=1, default=str)
    if not args.no_write and (args.write or not args.quick):
        write_results(results, args.quick)
    return 0 if all(not isinstance(r, str) for r in results.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
