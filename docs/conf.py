"""Sphinx configuration of the cdcr-ctl manual (MyST Markdown pages, autodoc for the library API).

Built by scripts/docs (warnings are errors); scripts/test runs it.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

project = "cdcr-ctl"
author = "cdcr-ctl contributors"
copyright = "cdcr-ctl contributors"

extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.napoleon"]
source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build"]

# Markdown: headings get anchors (links like page.md#a-heading), ``{eval-rst}`` hosts autodoc.
myst_heading_anchors = 3
myst_enable_extensions = ["colon_fence"]

# The API pages document what a lab would script; docstrings are the source.
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"members": True, "show-inheritance": False}

html_theme = "alabaster"
html_title = "cdcr-ctl manual"
