"""Run every benchmark: ``python -m benchmarks.run_all [--quick] [--out DIR]``.

Each benchmark runs in turn in this process; a failure is reported and the others still run. The exit status is
the number of benchmarks that failed.
"""

from __future__ import annotations

import importlib
import sys
import time
import traceback

from benchmarks import BENCHMARKS
from benchmarks._harness import parse_args


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parse_args(argv, "Run all jaxsss benchmarks.")  # validate the shared options early
    failed = []
    for name in BENCHMARKS:
        t0 = time.perf_counter()
        print(f"== {name} ==", flush=True)
        try:
            importlib.import_module(f"benchmarks.{name}").main(argv)
        except Exception:  # noqa: BLE001 - report and carry on with the next benchmark
            traceback.print_exc()
            failed.append(name)
        print(f"== {name}: {time.perf_counter() - t0:.1f} s ==", flush=True)
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return len(failed)


if __name__ == "__main__":
    sys.exit(main())
