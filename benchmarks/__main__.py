"""Run every benchmark and write the results table into benchmarks/README.md.

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
note (its section in the README then says so), so the runner works while modules are
being changed. ``--quick`` asks each module for a short smoke run (small batches, few
repeats): its numbers are noisy and it does not rewrite the README unless ``--write``.
Each module's section of the README, between the markers ``<!-- results:NAME:begin -->``
and ``<!-- results:NAME:end -->``, is replaced (appended when absent); the rest of the
file is kept, so ``--only NAME --write`` refreshes one section.
"""

from __future__ import annotations

import argparse
import datetime
import importlib
import json
import math
import os
import pkgutil
import sys
import time
import traceback

from benchmarks._common import machine

KEYS = ("benchmark", "case", "cstorm_us", "peer", "peer_us", "ratio", "compile_s", "notes")
HERE = os.path.dirname(os.path.abspath(__file__))
README = os.path.join(HERE, "README.md")
BEGIN, END = "<!-- results:{}:begin -->", "<!-- results:{}:end -->"
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


def section(name, rows, quick) -> str:
    """One module's README section, between its own markers (so `--only` updates just it)."""
    date = datetime.date.today().isoformat()
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    body = rows if isinstance(rows, str) else markdown(rows)
    return "\n".join([BEGIN.format(name), f"### {name} ({date}{', quick smoke run' if quick else ''})", "",
                      f"Machine: {machine()}; load average after the run: {load}.", "", body, END.format(name)])


def report(results, quick) -> str:
    return "\n\n".join(section(n, r, quick) for n, r in results.items())


def write_readme(results, quick, path=README):
    """Replace each module's section in the README (appended when new)."""
    text = open(path).read() if os.path.exists(path) else "# Benchmarks\n"
    for name, rows in results.items():
        new = section(name, rows, quick)
        b, e = BEGIN.format(name), END.format(name)
        if b in text and e in text:
            head, rest = text.split(b, 1)
            text = head + new + rest.split(e, 1)[1]
        else:
            text = text.rstrip("\n") + "\n\n" + new + "\n"
    with open(path, "w") as f:
        f.write(text)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short smoke run (noisy numbers; README untouched)")
    ap.add_argument("--only", default=None, help="comma-separated module names, e.g. derivatives,dynamics")
    ap.add_argument("--write", action="store_true", help="write the README even with --quick")
    ap.add_argument("--no-write", action="store_true", help="print the table only")
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
    text = report(results, args.quick)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"machine": machine(), "quick": args.quick, "results": results}, f, indent=1, default=str)
    if not args.no_write and (args.write or not args.quick):
        write_readme(results, args.quick)
        print(f"wrote {README}")
    return 0 if all(not isinstance(r, str) for r in results.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
