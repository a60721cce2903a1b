"""Sphinx configuration of the scene-estimator documentation.

Build: ``sphinx-build -W --keep-going -b html docs docs/_build/html`` (warnings are errors; the test
suite runs the same build in ``tests/test_docs.py``).

Why Sphinx + MyST-Parser + furo: Sphinx is the Python ecosystem's standard documentation tool, and
the only one whose ``autodoc`` reads the API reference from the docstrings of the imported modules
(the same objects the tests import) and whose extension API lets the command reference be generated
from the real ``argparse`` parser at build time. MyST-Parser lets the pages be written in Markdown,
as the README is, with Sphinx's cross-references and math. furo is a maintained, accessible theme
with a working client-side search and no JavaScript framework to build.
"""
from __future__ import annotations

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)                      # the project itself, also when not installed
sys.path.insert(0, os.path.join(HERE, "_ext"))  # the documentation's own extensions

project = "scene-estimator"
author = "scene-estimator contributors"
copyright = "the scene-estimator contributors (MIT licence)"
try:
    from importlib.metadata import version as _version

    release = _version("scene-estimator")
except Exception:  # pragma: no cover - building from a tree that is not installed
    release = "0.1.0"
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "cli_reference",  # docs/_ext/cli_reference.py: the command reference, walked from the argparse parser
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]

myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence", "deflist", "attrs_inline"]
myst_heading_anchors = 3

autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"members": True, "show-inheritance": False}
autosummary_generate = False
napoleon_google_docstring = True
napoleon_numpy_docstring = True
# the docstrings are prose written in reStructuredText loosely (``code`` and *emphasis*); references
# to names that the API reference does not document are not errors
nitpicky = False
# the format examples elide arrays as [..], which is not JSON: highlighted leniently, not an error
suppress_warnings = ["misc.highlighting_failure"]

html_theme = "furo"
html_title = f"scene-estimator {release}"
html_static_path: list[str] = []
smartquotes = False  # `--option` stays two hyphens in the command reference
