"""Sphinx configuration of the physar documentation (``make docs`` -> docs/_build/html).

Why these tools (see also docs/README.md):

* Sphinx: the generator of scikit-fem, pyMOR, NumPy and SciPy, the anchors of STYLE.md; autodoc reads the
  docstrings (contract, equation, SI units, shapes), autosummary makes the tables and napoleon reads the
  Google sections some docstrings have (``Attributes:``). The docstrings are reStructuredText written as
  plain text: ``|u|`` and ``x**2`` are escaped before parsing (physar_api.plain_text_markup), so they show
  as written; equations marked up as math (``:math:``, ``.. math::``, pyMOR's convention) are rendered by
  MathJax.
* myst-nb (with myst-parser and jupytext): the README and benchmarks/RESULTS.md are Markdown, and the
  examples are jupytext percent scripts whose text cells are Markdown. myst-nb executes them as notebooks
  and renders that Markdown as written; sphinx-gallery would read the text cells as reStructuredText
  (its open issue #710), turning ``## The beam`` into a paragraph and ``|p - c(p)|`` into a substitution.
* furo: a maintained theme with no web fonts or scripts from elsewhere; MathJax 3 is served from
  ``_static/mathjax`` (vendored from the mathjax npm package, Apache-2.0), so the site works offline.

The pages of the API reference, the file formats, the gallery, the landing page (README.md) and the
benchmark results are generated into ``_generated/`` by the extensions in ``_ext/`` at every build, from the
code, the schemas and the Markdown files themselves, so they cannot drift. Build with ``-W --keep-going``:
any warning (a public name without a docstring, a broken cross-reference, a failing example) fails it.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
(HERE / "_build" / "gallery_extra").mkdir(parents=True, exist_ok=True)  # videos of the gallery (html_extra_path)
os.environ.setdefault("MPLBACKEND", "Agg")

import physar

project = "physar"
author = "the physar developers"
copyright = "physar developers, MIT licence"
release = version = physar.__version__

extensions = [
    "myst_nb",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "physar_pages",
    "physar_formats",
    "physar_api",
    "physar_gallery",
]

root_doc = "index"
exclude_patterns = ["_build", "README.md", "_ext", "_generated/readme.md", "Thumbs.db", ".DS_Store", "**.ipynb_checkpoints"]
templates_path: list[str] = []

# --- Markdown and notebooks ---------------------------------------------------------------------------
myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence", "deflist"]
myst_heading_anchors = 3
myst_dmath_double_inline = True
# every build runs the examples (quick mode unless PHYSAR_DOCS_FULL=1); PHYSAR_DOCS_EXECUTE=0 skips them
# (pages without outputs: for work on the other pages only, never for a published build)
nb_execution_mode = "force" if os.environ.get("PHYSAR_DOCS_EXECUTE", "1") != "0" else "off"
nb_execution_timeout = 900
nb_execution_raise_on_error = True  # a failing example fails the build
nb_execution_show_tb = True
nb_merge_streams = True
nb_output_stderr = "remove"  # progress logs are not part of a page; an exception still fails the build

# --- API reference ------------------------------------------------------------------------------------
autosummary_generate = False  # the pages list every name themselves (physar_api)
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
napoleon_google_docstring = True
napoleon_numpy_docstring = False  # no docstring has NumPy sections; its parser would read "----" rules
add_module_names = False

# Cross-references: broken ones are errors (nitpicky), except names of other libraries' types, which an
# offline build cannot link (no intersphinx inventories are fetched).
nitpicky = True
nitpick_ignore_regex = [
    (r"py:.*", (r"(np|numpy|scipy|sp|torch|wp|warp|cv2|av|meshio|h5py|matplotlib|plt|pydantic|dask|distributed"
               r"|typing|collections|pathlib|os|io|dataclasses|concurrent|threading|enum|skfem|trimesh|PIL|annotated_types"
               r"|types)(\..*)?")),
    (r"py:class", r"[-+]?[0-9.]+(e[-+]?[0-9]+)?"),  # values inside Literal[...] and Annotated[...] hints
    (r"py:class", r"(FieldInfo|NoneType|Gt|Ge|Lt|Le)"),  # pydantic / annotated_types constraints inside Annotated
    (r"py:class", (r"(Path|Callable|Iterator|Iterable|Sequence|Mapping|Any|Literal|Self|ndarray|NDArray|ArrayLike"
                  r"|Tensor|array|optional|callable|float|int|str|bool|dict|list|tuple|None|object|type"
                  r"|function|np\.ndarray)")),
]

# --- HTML ---------------------------------------------------------------------------------------------
html_theme = "furo"
html_title = f"physar {release}"
html_static_path = ["_static"]
html_extra_path = ["_build/gallery_extra"]
mathjax_path = "mathjax/tex-chtml.js"  # local copy: no CDN
# MathJax's context menu can switch on speech output, which loads the speech-rule engine from a CDN: off.
mathjax3_config = {"options": {"enableMenu": False}}
html_show_sourcelink = False
suppress_warnings = ["myst.header"]  # README's heading levels are its own (e.g. ### under ##)
