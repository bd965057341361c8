"""The public surface (issues 9, 35): every public name resolves, a small top level (at most 60 names),
each name public in exactly one place and on a docs page, the README, docs, scenes and benchmarks use
public names only (unit tests may import ``facewarp._src``), and ``import facewarp`` stays light (no
Warp, MuJoCo or USD until they are used)."""

from __future__ import annotations

import ast
import importlib
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

import facewarp

ROOT = Path(__file__).resolve().parents[1]
PUBLIC_MODULES = sorted(p.stem for p in (ROOT / "facewarp").glob("*.py")
                        if not p.stem.startswith("_") and p.stem != "cli")
PRIVATE = "facewarp." + "_src"  # spelled so that this file does not match itself
PRIVATE_USE = re.compile(re.escape(PRIVATE) + r"|from\s+facewarp\s+import\s+[^\n]*\b_src\b|import\s+facewarp\s*\._src")


def test_top_level_names_resolve():
    assert "FaceSimulator" in facewarp.__all__ and "__version__" in facewarp.__all__
    missing = [name for name in facewarp.__all__ if getattr(facewarp, name, None) is None]
    assert not missing, f"facewarp.__all__ names that do not resolve: {missing}"
    assert not [n for n in facewarp.__all__ if n.startswith("_") and n != "__version__"]
    with pytest.raises(AttributeError, match="no attribute"):
        facewarp.no_such_name  # noqa: B018


def test_type_checking_block_lists_every_lazy_name():
    # static analysers see the names through the TYPE_CHECKING imports; they must match the lazy map
    tree = ast.parse((ROOT / "facewarp" / "__init__.py").read_text(encoding="utf-8"))
    block = next(n for n in tree.body if isinstance(n, ast.If) and getattr(n.test, "id", "") == "TYPE_CHECKING")
    imported = {a.asname or a.name for n in ast.walk(block) if isinstance(n, ast.ImportFrom) for a in n.names}
    lazy = set(facewarp.__all__) - {"__version__"}
    assert imported == lazy, f"only lazy: {sorted(lazy - imported)}; only TYPE_CHECKING: {sorted(imported - lazy)}"


@pytest.mark.parametrize("name", PUBLIC_MODULES)
def test_public_submodule_names_resolve(name):
    mod = importlib.import_module(f"facewarp.{name}")
    assert getattr(facewarp, name) is mod
    assert mod.__all__ and len(set(mod.__all__)) == len(mod.__all__)
    missing = [n for n in mod.__all__ if not hasattr(mod, n)]
    assert not missing, f"facewarp.{name}.__all__ names that do not resolve: {missing}"
    assert not [n for n in mod.__all__ if n.startswith("_")]


def test_top_level_is_small():
    assert len(dir(facewarp)) <= 60, f"{len(dir(facewarp))} names at the top level: {dir(facewarp)}"
    assert set(facewarp._SUBMODULES) == set(PUBLIC_MODULES), "public submodule files and _SUBMODULES differ"


def test_each_public_name_in_one_place():
    places: dict = {}
    for n in facewarp.__all__:
        places.setdefault(n, []).append("facewarp")
    for sub in facewarp._SUBMODULES:
        for n in importlib.import_module(f"facewarp.{sub}").__all__:
            places.setdefault(n, []).append(f"facewarp.{sub}")
    twice = {n: p for n, p in places.items() if len(p) > 1}
    assert not twice, f"names public in more than one place: {twice}"


def test_each_public_name_on_a_docs_page():
    # the top level on the Python API page, every submodule's names in the generated API reference
    page = (ROOT / "docs" / "python-api.md").read_text(encoding="utf-8")
    missing = [n for n in facewarp.__all__ if n != "__version__" and f"`{n}`" not in page]
    assert not missing, f"top-level names not on docs/python-api.md: {missing}"
    assert not [s for s in facewarp._SUBMODULES if f"`facewarp.{s}`" not in page]
    spec = importlib.util.spec_from_file_location("fw_generated", ROOT / "docs" / "_ext" / "fw_generated.py")
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    assert gen.PUBLIC_MODULES == ["facewarp", *(f"facewarp.{s}" for s in facewarp._SUBMODULES), "usd_export"]


def test_no_old_aliases():
    assert not hasattr(facewarp, "play_timeline")


def test_user_facing_files_use_public_names_only():
    # scenes and benchmarks: no private module at all; README and docs: no code that imports one (the
    # prose may say that facewarp._src is private; the docs' own build extension reads it)
    code_use = re.compile(r"(from|import)\s+facewarp\s*\._src|from\s+facewarp\s+import[^\n]*\b_src\b|\bfw\._src\b")
    paths = [(p, PRIVATE_USE) for folder in ("scenes", "benchmarks") for p in (ROOT / folder).rglob("*")]
    paths += [(ROOT / "README.md", code_use)] + [(p, code_use) for p in (ROOT / "docs").rglob("*")
                                                  if not {"_generated", "_build", "_ext"} & set(p.parts)
                                                  and p.name != "conf.py"]
    offenders = []
    for path, pattern in sorted(paths):
        if not path.is_file() or "__pycache__" in path.parts or path.suffix not in (".py", ".md", ".json", ".txt"):
            continue
        for k, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            if pattern.search(line):
                offenders.append(f"{path.relative_to(ROOT)}:{k}: {line.strip()}")
    assert not offenders, "private facewarp modules used in README, docs, scenes or benchmarks:\n" + "\n".join(offenders)


def test_import_facewarp_is_light():
    code = ("import sys, facewarp; "
            "print(sorted(m for m in ('warp', 'mujoco', 'pxr') if m in sys.modules))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert run.stdout.strip() == "[]", f"import facewarp loaded {run.stdout.strip()}"


def _imports_of(path: Path) -> list[str]:
    """Modules a source file imports (absolute names, relative ones resolved against the file)."""
    pkg = path.relative_to(ROOT).with_suffix("").parts[:-1]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = list(pkg[: len(pkg) - node.level + 1]) if node.level else []
            mod = ".".join(base + ([node.module] if node.module else []))
            out += [mod] + [f"{mod}.{a.name}" for a in node.names]
    return out


def test_layers_physics_and_sim_import_nothing_from_anatomy():
    # the house (issue 22): the anatomy builds the face rig (contact geometry included) once; the
    # physics and the simulator only read it. And the model and its materials do not import each other.
    engine = ROOT / "facewarp" / ("_" + "src")
    anatomy = ".".join(("facewarp", "_" + "src", "anatomy"))
    offenders = [f"{p.relative_to(ROOT)}: {m}" for folder in ("physics", "sim") for p in sorted((engine / folder).rglob("*.py"))
                 for m in _imports_of(p) if m == anatomy or m.startswith(anatomy + ".")]
    assert not offenders, "physics/sim import the anatomy:\n" + "\n".join(offenders)
    physics = ".".join(("facewarp", "_" + "src", "physics"))
    model = [m for m in _imports_of(engine / "physics" / "model.py") if m.startswith(physics + ".materials")]
    materials = [m for m in _imports_of(engine / "physics" / "materials.py") if m.startswith(physics + ".model")]
    assert not (model and materials), f"model.py and materials.py import each other: {model}, {materials}"
