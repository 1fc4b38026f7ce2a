"""Sphinx configuration of rmpfusion's documentation site (``make docs``).

Sphinx reads the Markdown pages of docs/ through MyST, so every page also reads as is on a code host and in an
editor; the registry reference (docs/reference/) is written by the local extension ``registry_reference`` from the
registries when the build starts. ``make docs`` builds with ``-W --keep-going -n``: any warning (a broken link or
cross-reference, a page missing from the table of contents) fails the build.
"""

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))

project = "rmpfusion"
author = "the rmpfusion developers"
copyright = "2026, the rmpfusion developers"

extensions = ["myst_parser", "registry_reference"]
source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "_ext", "figures/README.md"]

# MyST: $...$ and $$...$$ math, heading anchors for links such as page.md#a-section, fenced directives
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 4

html_theme = "furo"
html_title = "rmpfusion"
html_static_path: list[str] = []
