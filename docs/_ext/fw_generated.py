"""Pages generated from the source of truth each time the site is built.

* ``_generated/cli.md``: every command and option of ``facewarp`` from the argument parser
  (usage, help, default, required), so the CLI reference cannot drift from ``--help``.
* ``_generated/api/*.rst``: one page per public module (``facewarp``, its public submodules and
  ``usd_export``), one autodoc entry per public name, in the order of the module's ``__all__``.
* ``_generated/benchmarks.md``: the committed benchmark results (``benchmarks/results/*.json``)
  with their machine, device and date.

:func:`public_names` is also what ``tests/test_docs.py`` checks for missing docstrings.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import inspect
import json
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent
ROOT = HERE.parent
OUT = HERE / "_generated"

def _public_modules() -> list[str]:
    import facewarp

    return ["facewarp", *(f"facewarp.{m}" for m in facewarp._SUBMODULES), "usd_export"]


PUBLIC_MODULES = _public_modules()


# ------------------------------------------------------------------------------ public names
def _import_origins(modname: str) -> dict:
    """name -> module it is imported from, read from the public module's ``from X import``
    statements (and ``facewarp._NAMES`` for the top level)."""
    mod = importlib.import_module(modname)
    if modname == "facewarp":
        return {n: (f"facewarp._src.{m}", n) for n, m in mod._NAMES.items()}
    tree = ast.parse(Path(inspect.getsourcefile(mod)).read_text())
    out = {}
    pkg = modname.rsplit(".", 1)[0] if "." in modname else modname
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module is not None:
            base = importlib.util.resolve_name("." * node.level + node.module, pkg if node.level else "") \
                if node.level else node.module
            for a in node.names:
                out[a.asname or a.name] = (base, a.name)
    return out


def attribute_doc(origin: str, name: str) -> str:
    """The attribute docstring under a module-level assignment (constants), or ''."""
    from sphinx.pycode import ModuleAnalyzer

    try:
        docs = ModuleAnalyzer.for_module(origin).find_attr_docs()
    except Exception:  # noqa: BLE001 - a module without source
        return ""
    return "\n".join(docs.get(("", name), [])).strip()


def _defining_doc(name: str, obj) -> str:
    """The attribute docstring of ``name`` in whichever loaded facewarp / usd_export module defines
    it (a constant re-exported through several modules)."""
    import sys

    for modname, mod in sorted(sys.modules.items()):
        if mod is None or not modname.startswith(("facewarp", "usd_export")):
            continue
        if getattr(mod, name, None) is obj:
            doc = attribute_doc(modname, name)
            if doc:
                return doc
    return ""


def public_names() -> list[tuple[str, str, object, str, str]]:
    """Every public name: ``(module, name, object, kind, docstring)``; kind is ``class``,
    ``function`` or ``data``; the docstring is the object's own (classes, functions) or the
    attribute docstring where the constant is defined."""
    rows = []
    for modname in PUBLIC_MODULES:
        mod = importlib.import_module(modname)
        names = [n for n in getattr(mod, "__all__", []) if not n.startswith("__")]
        origins = _import_origins(modname)
        for n in names:
            obj = getattr(mod, n)
            if inspect.isclass(obj):
                kind, doc = "class", inspect.getdoc(obj) or ""
            elif callable(obj):
                kind, doc = "function", inspect.getdoc(obj) or ""
            else:
                kind = "data"
                origin, orig = origins.get(n, (modname, n))
                doc = attribute_doc(origin, orig) or _defining_doc(orig, obj)
            rows.append((modname, n, obj, kind, doc))
    return rows


def _api_pages() -> None:
    api = OUT / "api"
    api.mkdir(parents=True, exist_ok=True)
    rows = public_names()
    seen: dict = {}
    index = ["# API reference", "",
             "Generated from the docstrings of the public names (each module's `__all__`); "
             "everything under `facewarp._src` is private and may change.", "",
             "```{toctree}", ":maxdepth: 1", ""]
    for modname in PUBLIC_MODULES:
        mod = importlib.import_module(modname)
        index.append(modname)
        first = (inspect.getdoc(mod) or "").split("\n\n")[0].replace("\n", " ")
        lines = [modname, "=" * len(modname), "", f".. module:: {modname}", ""]
        lines += [first, ""]
        for m, n, obj, kind, doc in rows:
            if m != modname:
                continue
            full = f"{modname}.{n}"
            key = id(obj) if kind != "data" else _import_origins(modname).get(n, (modname, n))
            if key in seen:  # documented once, where it is first public (the top level first)
                lines += [f"- ``{n}``: the same object as :py:obj:`{seen[key]}`.", ""]
                continue
            seen[key] = full
            if kind == "class":
                lines += [f".. autoclass:: {full}", "   :members:", ""]
            elif kind == "function":
                lines += [f".. autofunction:: {full}", ""]
            else:
                lines += [f".. py:data:: {full}", ""]
                for dl in (doc or "").splitlines():
                    lines.append(f"   {dl}" if dl else "")
                r = repr(obj)
                if len(r) < 200 and "\n" not in r:
                    lines += ["", f"   Value: ``{r}``"]
                lines.append("")
        (api / f"{modname}.rst").write_text("\n".join(lines) + "\n")
    index += ["```", ""]
    (api / "index.md").write_text("\n".join(index))


# ------------------------------------------------------------------------------ CLI
def _walk(parser: argparse.ArgumentParser, path: list[str]):
    yield path, parser
    for act in parser._actions:
        if isinstance(act, argparse._SubParsersAction):
            for name, sub in act.choices.items():
                yield from _walk(sub, path + [name])


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def cli_markdown() -> str:
    from facewarp.cli import build_parser

    parser = build_parser()
    out = ["# Command reference", "",
           "Generated from `facewarp`'s argument parser (`facewarp COMMAND --help` prints the same). "
           "Every error a user can cause is one line, `facewarp: error: ...`, with exit code 2.", ""]
    helps = {}
    for act in parser._actions:
        if isinstance(act, argparse._SubParsersAction):
            for ca in act._choices_actions:
                helps[ca.dest] = ca.help
    for path, p in _walk(parser, ["facewarp"]):
        subs = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
        title = " ".join(path)
        out += [f"## `{title}`" if len(path) > 1 else "## `facewarp` (global options)", ""]
        if p.description:
            out += [p.description.strip(), ""]
        out += ["```text", p.format_usage().strip(), "```", ""]
        rows = []
        for a in p._actions:
            if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)) or a.default is argparse.SUPPRESS:
                continue  # (SUPPRESS: the global options a command accepts too, listed once under `facewarp`)
            name = ", ".join(a.option_strings) if a.option_strings else (a.metavar or a.dest)
            if a.option_strings and a.nargs != 0 and a.metavar:
                name += f" {a.metavar}" if isinstance(a.metavar, str) else ""
            elif a.option_strings and a.nargs != 0 and a.choices:
                name += " {" + ",".join(map(str, a.choices)) + "}"
            if not a.option_strings:
                req = "yes" if a.nargs not in ("?", "*") else "no"
                default = ""
            else:
                req = "yes" if a.required else "no"
                default = "" if a.default in (None, False, argparse.SUPPRESS) or a.nargs == 0 else f"`{a.default}`"
            rows.append(f"| `{_cell(name)}` | {req} | {default} | {_cell(a.help or '')} |")
        if rows:
            out += ["| argument | required | default | meaning |", "|---|---|---|---|", *rows, ""]
        for s in subs:
            names = ", ".join(f"`{title} {c}`" for c in s.choices)
            out += [f"Commands: {names}.", ""]
    return "\n".join(out) + "\n"


# ------------------------------------------------------------------------------ benchmarks
def _scalars(d, prefix="", out=None, depth=0):
    out = {} if out is None else out
    if isinstance(d, dict) and depth < 2:
        for k, v in d.items():
            _scalars(v, f"{prefix}{k}." if depth < 1 else f"{prefix}{k}", out, depth + 1) if isinstance(v, dict) \
                else _scalars(v, f"{prefix}{k}", out, depth + 1)
    elif isinstance(d, (int, float, str, bool)) and prefix:
        out[prefix.rstrip(".")] = d
    return out


def benchmarks_markdown() -> str:
    res = ROOT / "benchmarks" / "results"
    out = ["## Every committed result", "",
           "Generated from the committed results in `benchmarks/results/` (each JSON file as written by its "
           "benchmark; `python -m benchmarks --list` lists them, `python -m benchmarks NAME` re-runs one). "
           "Timings are from the machine and date named with each.", ""]
    for f in sorted(res.glob("*.json")):
        try:
            data = json.loads(f.read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(data, dict):
            continue
        meta = {k: data.get(k) for k in ("benchmark", "date", "machine", "device") if data.get(k) is not None}
        out += [f"### `{f.name}`", ""]
        for k, v in meta.items():
            out.append(f"- {k}: {_cell(json.dumps(v) if isinstance(v, (dict, list)) else v)}")
        figs = _scalars(data.get("figures", {k: v for k, v in data.items() if k not in meta}))
        figs = {k: v for k, v in figs.items() if not isinstance(v, str) or len(v) < 80}
        if figs:
            out += ["", "| figure | value |", "|---|---|"]
            for k, v in list(figs.items())[:40]:
                val = f"{v:.4g}" if isinstance(v, float) else str(v)
                out.append(f"| {_cell(k)} | {_cell(val)} |")
            if len(figs) > 40:
                out.append(f"| ... | {len(figs) - 40} more in the file |")
        out.append("")
    return "\n".join(out) + "\n"


def generate(app=None) -> None:
    OUT.mkdir(exist_ok=True)
    (OUT / "cli.md").write_text(cli_markdown())
    (OUT / "benchmarks.md").write_text(benchmarks_markdown())
    _api_pages()


def setup(app):
    app.connect("builder-inited", generate)
    return {"version": "1", "parallel_read_safe": True}
