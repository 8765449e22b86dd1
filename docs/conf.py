"""Sphinx configuration of the gearbox-rig documentation (``scripts/build_docs`` builds it)."""

from __future__ import annotations

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))  # the packages, documented from this source tree
sys.path.insert(0, str(DOCS / "_ext"))

from identify import __version__  # noqa: E402

project = "gearbox-rig"
author = "gearbox-rig authors"
copyright = "gearbox-rig authors"
release = __version__
version = __version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "mathml_math",  # docs/_ext: equations as MathML at build time, so the site needs no script and no network
    "rig_docs",
]
html_math_renderer = "mathml"

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
highlight_language = "none"  # literal blocks without a language (config formats, help texts) stay plain
smartquotes = False  # keep -- and quotes as typed: option names and JSON must read as the shell takes them
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]

# Markdown (MyST): `#anchor` links to headings down to level 4, $...$ maths, ::: fences, definition lists.
myst_heading_anchors = 4
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]

# API reference from the docstrings (numpy style), in source order, without importing heavy backends twice.
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"members": True, "show-inheritance": False}
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False

html_theme = "alabaster"
html_title = f"gearbox-rig {release}"
html_theme_options = {"description": "Hardware-in-the-loop gearbox test rig", "fixed_sidebar": True,
                      "page_width": "1200px", "sidebar_width": "230px"}
html_sidebars = {"**": ["about.html", "navigation.html", "relations.html", "searchbox.html"]}
html_static_path = ["_static"]
html_css_files = ["rig.css"]
