"""Print the Markdown tables quoted in ``docs/benchmarks.md`` from ``benchmarks/results/*.json``.

``python -m benchmarks.report [--out DIR]``: per results file, a header line (date, machine, load) and a table.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from benchmarks import BENCHMARKS
from benchmarks._harness import DEFAULT_OUT


def _g(x, fmt=".2e"):
    return "n/a" if x is None else format(x, fmt)


def header(doc: dict) -> str:
    m = doc["machine"]
    load = doc["summary"].get("loadavg_1min_at_start")
    return (f"{doc['date']}, {'quick' if doc['quick'] else 'full'} run; {m['cpu']}, {m['cpu_count']} cores, "
            f"backend {m['backend']}, jax {m['jax']}, numpy {m['numpy']}; 1-min load average "
            f"{_g(load, '.1f')} at start, {_g(m.get('loadavg_1min'), '.1f')} at end")


def profile_table(doc: dict) -> str:
    numpy_seconds = {r["setting"]: r["seconds"] for r in doc["rows"] if r["method"] == "numpy f64"}
    lines = ["| setting | method | evals/s | x NumPy | seconds (min of 9) | compile s | max rel err |",
             "|---|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        lines.append(f"| {r['setting']} | {r['method']} | {r['evals_per_second']:.3g} | "
                     f"{numpy_seconds[r['setting']] / r['seconds']:.2f} | {r['seconds']:.4f} | "
                     f"{_g(r['compile_seconds'], '.2f')} | {_g(r['error'])} |")
    return "\n".join(lines)


def inversion_table(doc: dict) -> str:
    lines = ["| method | setting | error | rel err alpha' | rel err 1-alpha' | err, Rd in [0.01, 0.99] | "
             "seconds (min of 9) | compile s | steps mean/max |", "|---|---|---|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        steps = f"{r['mean_steps']:.2f} / {r['max_steps_taken']}" if "mean_steps" in r else "-"
        lines.append(f"| {r['method']} | {r['setting']} | {_g(r['error'])} | {_g(r['err_alpha'])} | "
                     f"{_g(r['err_one_minus_alpha'])} | {_g(r['err_mid'])} | {r['seconds']:.4f} | "
                     f"{_g(r['compile_seconds'], '.2f')} | {steps} |")
    return "\n".join(lines)


def generic_table(doc: dict) -> str:
    """The common row keys, for benchmarks without a formatter of their own."""
    lines = ["| method | setting | error | error metric | seconds | compile s |", "|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        lines.append(f"| {r['method']} | {r['setting']} | {_g(r['error'])} | {r['error_metric']} | "
                     f"{_g(r['seconds'], '.4g')} | {_g(r['compile_seconds'], '.2f')} |")
    return "\n".join(lines)


TABLES = {"profile_throughput": profile_table, "rd_inversion": inversion_table}
"""Formatters by benchmark name; others use :func:`generic_table`."""


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    out = Path(argv[argv.index("--out") + 1]) if "--out" in argv else DEFAULT_OUT
    for name in BENCHMARKS:
        # <name>.json and any tagged runs, e.g. <name>_1core.json from `taskset -c 0 ... --tag _1core`.
        paths = sorted(out.glob(f"{name}*.json"))
        if not paths:
            print(f"## {name}: no results in {out}\n")
        for path in paths:
            doc = json.loads(path.read_text())
            cores = doc["machine"].get("usable_cores", "?")
            print(f"## {path.stem} ({cores} usable cores)\n\n{header(doc)}\n\n{TABLES.get(name, generic_table)(doc)}\n\n"
                  f"summary: {json.dumps(doc['summary'])}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
