"""Sphinx configuration of the czmpc documentation site (``make docs``)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
# The gallery scripts run headless and with the CLI's one-BLAS-thread default.
os.environ.setdefault("MPLBACKEND", "Agg")
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import czmpc  # noqa: E402

project = "czmpc"
author = "the czmpc developers"
copyright = "2026, the czmpc developers"
release = czmpc.__version__          # the one version, from the package metadata
version = ".".join(release.split(".")[:2])

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
    "czmpc_contracts",
    "czmpc_cli",
    "czmpc_fields",
]

templates_path = ["_templates"]
exclude_patterns = ["_build", "examples/README.rst", "**/sg_execution_times.rst"]
default_role = "py:obj"
autosummary_generate = True
autosummary_imported_members = False
autodoc_typehints = "none"            # numpydoc sections carry the types and units
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False

html_theme = "pydata_sphinx_theme"
html_title = f"czmpc {release}"
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
}
html_static_path: list[str] = []
html_last_updated_fmt = None

sphinx_gallery_conf = {
    "examples_dirs": "examples",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "write_computation_times": False,
    "show_signature": False,
    "plot_gallery": "True",
    "abort_on_example_error": True,
}
