"""Sphinx configuration of the facewarp documentation (``sphinx-build -W -b html docs docs/_build``).

The CLI reference, the API reference and the benchmark tables are generated from the source of
truth (the argument parser, the public names and their docstrings, the committed benchmark
results) by ``_ext/fw_generated.py`` each time the site is built, so they cannot drift.
"""

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent / "_ext"))
os.environ.setdefault("FACEWARP_QUIET", "1")

import facewarp  # noqa: E402

project = "facewarp"
author = "the facewarp developers"
copyright = "2026, the facewarp developers (MIT)"
release = facewarp.__version__
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "fw_generated",
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
myst_enable_extensions = ["colon_fence", "dollarmath", "deflist"]
myst_heading_anchors = 3
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store", "_generated/cli.md", "_generated/benchmarks.md"]
templates_path = []

autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": False}
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False
napoleon_attr_annotations = True
napoleon_use_ivar = True
# docstrings point at private modules (facewarp._src...) for the reader of the source; the site
# documents the public names, so unresolved cross-references are not errors
nitpicky = False
suppress_warnings = ["myst.xref_missing", "ref.python"]

html_theme = "furo" if __import__("importlib").util.find_spec("furo") else "alabaster"
html_title = f"facewarp {release}"
html_static_path = ["_static"]
