"""The benchmark runner.

    python -m benchmarks --list                      # every case, one line each
    python -m benchmarks NAME [--device cpu|cuda] [case options ...]
    python -m benchmarks NAME --help                 # the case's own options
    python -m benchmarks --results DIR NAME ...      # write the results to DIR, not benchmarks/results
    python -m benchmarks --tables [--check]          # rewrite (or check) the README's tables from the results

A case is any ``benchmarks/NAME.py`` (not starting with ``_``) with a module docstring, whose first
line is its description, and ``main(argv=None)``; see benchmarks/README.md.
"""

from __future__ import annotations

import sys

from benchmarks import _registry


def _usage() -> str:
    return ("usage: python -m benchmarks --list | --tables [--check] | [--results DIR] NAME [options]\n"
            "       python -m benchmarks NAME --help")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv:
        print(_usage(), file=sys.stderr)
        return 2
    if argv[0] in ("-h", "--help"):
        print(__doc__.strip())
        return 0
    if argv[0] == "--results":
        if len(argv) < 3:
            print("python -m benchmarks: error: --results needs a folder and a case name", file=sys.stderr)
            return 2
        import os
        from pathlib import Path

        from benchmarks import _common

        _common.RESULTS = Path(argv[1]).resolve()
        os.environ["FACEWARP_BENCH_RESULTS"] = str(_common.RESULTS)  # for cases that run themselves again
        argv = argv[2:]
    if argv[0] == "--list":
        cases = _registry.cases()
        width = max(map(len, cases))
        for name, case in cases.items():
            print(f"{name:<{width}}  {case.description}")
        return 0
    if argv[0] == "--tables":
        from benchmarks import _tables

        return _tables.main(argv[1:])
    name, rest = argv[0], argv[1:]
    try:
        return _registry.run(name, rest)
    except _registry.UnknownCase as e:
        print(f"python -m benchmarks: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
