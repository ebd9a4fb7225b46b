"""Sphinx configuration of dynid's documentation (``make docs``: every warning is an error).

Generated at build time, never committed: the configuration reference (``_ext/dynid_config_reference.py``,
from the schema), the API stubs (autosummary, ``reference/api/generated/``) and the tutorials' pages
(sphinx-gallery runs ``tutorials/*.py`` into ``auto_tutorials/``). No inventory is fetched: the build
needs no network (no intersphinx).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(DOCS / "_ext"))
sys.path.insert(0, str(ROOT / "src"))  # the checkout's dynid, installed or not
os.environ.setdefault("MPLBACKEND", "Agg")

import dynid  # noqa: E402

project = "dynid"
author = "the dynid authors"
copyright = "the dynid authors"
version = release = dynid.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
    "dynid_config_reference",
    "dynid_bench_pages",  # bench/README.md cut into the studies pages (studies/generated/)
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "tutorials", "auto_tutorials/*.ipynb", "auto_tutorials/*.py", "**/*.zip",
                    "auto_tutorials/*.codeobj.json", "Thumbs.db", ".DS_Store"]
templates_path = ["_templates"]

# MyST: markdown pages (index, getting started, explanation; the guide)
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3

# API reference: autosummary writes the stubs at build time (reference/api/generated/, ignored by git)
autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {"members": True, "show-inheritance": False}
autodoc_typehints = "none"  # numpydoc documents the parameters; the signatures keep their annotations
autodoc_member_order = "bysource"
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
numpydoc_validation_checks: set[str] = set()

# tutorials: executed at build time (each writes only under a temporary folder)
sphinx_gallery_conf = {
    "examples_dirs": "tutorials",
    "gallery_dirs": "auto_tutorials",
    "filename_pattern": r"/tut_",  # every tutorial runs
    "within_subsection_order": "FileNameSortKey",
    "abort_on_example_error": True,
    "download_all_examples": False,
    "remove_config_comments": True,
    "image_scrapers": ("matplotlib",),
    "matplotlib_animations": False,
    "reference_url": {},
    "show_memory": False,
    "capture_repr": ("_repr_html_", "__repr__"),
    "line_numbers": False,
}

html_theme = "pydata_sphinx_theme"
html_title = f"dynid {release}"
html_static_path = ["_static"]
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "header_links_before_dropdown": 6,
    "secondary_sidebar_items": ["page-toc"],
}
html_sidebars = {"index": [], "getting-started": []}
html_show_sourcelink = False
