"""The registry of benchmark cases: ``name -> module with main(argv)``, found without importing them.

Every ``benchmarks/NAME.py`` whose name does not start with ``_`` is a case. Its module docstring's
first paragraph is its description (``python -m benchmarks --list``); a module-level literal
``THREADS = n`` asks the runner to pin the process to ``n`` threads (``--threads`` overrides) before
the module, and with it NumPy, is imported. Discovery reads the source with :mod:`ast`, so listing
imports no facewarp, warp or NumPy.
"""

from __future__ import annotations

import ast
import importlib
import runpy
import sys
from dataclasses import dataclass
from pathlib import Path

from benchmarks import _common

FOLDER = Path(__file__).resolve().parent


class UnknownCase(LookupError):
    """A case name that is not a ``benchmarks/NAME.py``."""


@dataclass(frozen=True)
class Case:
    """One benchmark case.

    Attributes:
        name: The module name (``physics_steps``).
        path: Its source file.
        description: The first paragraph of its module docstring, on one line.
        has_main: Whether it defines ``main`` (else the runner runs it as ``__main__``).
        threads: ``THREADS`` of the module (threads to pin to before import), or None.
    """

    name: str
    path: Path
    description: str
    has_main: bool
    threads: int | None


def _read(path: Path) -> Case:
    tree = ast.parse(path.read_text(), filename=str(path))
    doc = (ast.get_docstring(tree) or "").strip()
    threads = None
    has_main = False
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name == "main":
            has_main = True
        if (isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name)
                and node.targets[0].id == "THREADS" and isinstance(node.value, ast.Constant)):
            threads = int(node.value.value)
    first = " ".join(doc.split("\n\n")[0].split()).replace("``", "")
    description = first or "(no description: add a module docstring)"
    return Case(path.stem, path, description, has_main, threads)


def cases() -> dict[str, Case]:
    """Every case, by name, sorted."""
    return {p.stem: _read(p) for p in sorted(FOLDER.glob("*.py")) if not p.name.startswith("_")}


def run(name: str, argv: list[str]) -> int:
    """Run case ``name`` with ``argv`` (its own options); returns its exit status."""
    found = cases()
    if name not in found:
        raise UnknownCase(f"no benchmark named {name!r} (python -m benchmarks --list shows them)")
    case = found[name]
    if case.threads is not None:
        _common.limit_threads(_common.threads_from_argv(argv, case.threads))
    _common.command_line = " ".join(["python -m benchmarks", name, *argv])
    if not case.has_main:  # a script with only a __main__ block
        saved = sys.argv
        sys.argv = [str(case.path), *argv]
        try:
            runpy.run_module(f"benchmarks.{name}", run_name="__main__", alter_sys=True)
        except SystemExit as e:
            if isinstance(e.code, str):
                print(e.code, file=sys.stderr)
            return e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
        finally:
            sys.argv = saved
        return 0
    module = importlib.import_module(f"benchmarks.{name}")
    saved = sys.argv
    sys.argv = [f"python -m benchmarks {name}", *argv]  # argparse's prog and cases reading sys.argv
    try:
        code = module.main(argv)
    except SystemExit as e:
        code = e.code
    finally:
        sys.argv = saved
    if code is None:
        return 0
    if isinstance(code, str):  # raise SystemExit("message")
        print(code, file=sys.stderr)
        return 1
    return code if isinstance(code, int) else 1
