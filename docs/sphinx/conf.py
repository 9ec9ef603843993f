"""Sphinx configuration of penumbra's documentation site (``make docs``).

The source folder is ``docs/`` itself, so the Markdown pages there (read by
myst-parser) are the site's pages as they are; this folder holds only the
site's own pages: the start page, the Python API reference (autodoc, from the
docstrings) and the examples gallery. Build with warnings as errors:
``sphinx-build -W -c docs/sphinx docs build/docs/html``.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
try:
    # The installed package first (`make docs` runs after `pip install .`): the
    # source folder has no built library beside it.
    import penumbra
except ImportError:
    # A checkout without `pip install .`, the library named by PENUMBRA_LIBRARY.
    sys.path.insert(0, str(ROOT / "python"))
    import penumbra

project = "penumbra"
author = "the penumbra authors"
release = version = penumbra.__version__

root_doc = "sphinx/index"
extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.napoleon", "sphinx.ext.viewcode"]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["**/.*", "sphinx/gallery/**"]   # gallery/gallery.md is included by gallery.md

# Markdown: headings get anchors (the pages link to each other's sections, e.g. api.md#renderer),
# dollar maths and tables as GitHub renders them.
myst_heading_anchors = 4
myst_enable_extensions = ["dollarmath", "colon_fence"]
# Links from the pages to files of the repository (sources, README, scene files) are not
# documents of the site; they stay plain links instead of failing as cross-references.
myst_url_schemes = ["http", "https", "mailto"]
# The pages keep "#### <method> parameters" headings under "##" sections: the tests find the
# parameter tables by them (tests/test_method_docs.py), so skipped heading levels are intended.
suppress_warnings = ["myst.header"]

autodoc_member_order = "bysource"
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_typehints = "description"
autodoc_preserve_defaults = True
napoleon_google_docstring = False
napoleon_numpy_docstring = True

html_theme = "alabaster"
html_title = f"penumbra {release}"
html_theme_options = {"description": "environment lighting with soft shadows for dynamic scenes (OpenCL)",
                      "fixed_sidebar": True}
