"""Sphinx configuration of the API reference (``make docs``).

Built from the numpydoc docstrings of the package; warnings are errors
(``-W``), so a docstring that does not render breaks the build.
"""

import os
import sys

# the package of this checkout, whether or not it is installed
sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..")))

import ipc_taichi  # noqa: E402

project = "ipc_taichi"
author = "ipc_taichi maintainers"
release = version = ipc_taichi.__version__
copyright = "2026, ipc_taichi maintainers"

extensions = ["sphinx.ext.autodoc", "sphinx.ext.mathjax", "numpydoc"]

# numpydoc: one entry per documented member, no autosummary tables of
# undocumented members
numpydoc_show_class_members = False
numpydoc_xref_param_type = False
autodoc_default_options = {"members": True, "member-order": "bysource"}
autodoc_typehints = "none"
# the pages document the code, not the Taichi runtime: importing the package
# never starts Taichi, so nothing needs mocking
nitpicky = False

html_theme = "alabaster"
html_static_path = []
exclude_patterns = ["_build"]
