"""Sphinx configuration of the documentation site (Sphinx, as ROS 2's rosdoc2 uses, with MyST for
the Markdown pages and autodoc for the API from the docstrings).

    python -m sphinx -W -b html docs out/site

``-W`` turns every warning into an error: a broken link to a heading or a file, a docstring autodoc
cannot read, a page left out of the table of contents.  ``test/test_docs.py`` builds it so.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # (the package, for autodoc, where it is not installed)

project = "piezofin_ros"
author = "piezofin_ros developers"
copyright = "2026, " + author
extensions = ["myst_parser", "sphinx.ext.autodoc"]
source_suffix = {".md": "markdown"}
root_doc = "index"
myst_heading_anchors = 4  # GitHub's heading anchors, so that the same links work on GitHub and here
myst_enable_extensions = ["colon_fence"]
autodoc_member_order = "bysource"
autodoc_typehints = "description"
html_theme = "alabaster"
html_title = "piezofin_ros"
