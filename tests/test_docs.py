"""The documentation site (issue 22): format pages generated from the schemas, the public-API docstring check,
the docstring markup, the gallery pipeline on tiny examples. The full build of ``make docs`` and its screenshots
are in tests/test_docs_site.py.

Fast tests need only pydantic, except those marked as needing Sphinx (the ``docs`` extra: skipped where it is
not installed, as in ``make test``'s environment; ``make docs`` installs it).
"""

from __future__ import annotations

import importlib
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS / "_ext"))

import physar_formats as F
import physar_public

# --- format pages --------------------------------------------------------------------------------------

def _schema_keys(model, root: str) -> set[str]:
    """Every key of a schema as ``table.key`` (``fix.plane.normal``), from its JSON schema: a walk that shares
    no code with the page generator (which reads ``model_fields``)."""
    schema = model.model_json_schema()
    defs = schema.get("$defs", {})

    def sub_models(node) -> list[dict]:
        if "$ref" in node:
            return [defs[node["$ref"].split("/")[-1]]]
        found = []
        for key in ("anyOf", "oneOf", "allOf"):
            for option in node.get(key, []):
                found += sub_models(option)
        if node.get("type") == "array" and isinstance(node.get("items"), dict):
            found += sub_models(node["items"])
        return found

    keys = set()

    def walk(node, path):
        for name, prop in node.get("properties", {}).items():
            keys.add(f"{path}.{name}" if path else name)
            for sub in sub_models(prop):
                if "properties" in sub:
                    walk(sub, f"{path}.{name}" if path else name)
        if isinstance(node.get("additionalProperties"), dict):  # tables under names of the user's choice
            for sub in sub_models(node["additionalProperties"]):
                if "properties" in sub:
                    walk(sub, f"{path}.NAME" if path else "NAME")

    walk(schema, root)
    return keys


def _page_keys(page: str) -> set[str]:
    """Every key the page's tables list, as ``table.key``: headings ``## `[[fix]].plane``` name the table."""
    keys, table = set(), None
    for line in page.splitlines():
        if line.startswith("## "):
            head = line[3:].strip().strip("`")
            table = "" if head == "Top level" else (re.sub(r"[\[\]]", "", head) if head.startswith("[") else None)
        elif table is not None and (m := re.match(r"\| `([^`]+)` \|", line)):
            keys.add(f"{table}.{m.group(1)}" if table else m.group(1))
    return keys


@pytest.mark.parametrize("fmt", F.FORMATS, ids=[f.name for f in F.FORMATS])
def test_format_page_lists_exactly_the_schema_keys(fmt):
    """Mutant caught: a hand-written (or stale) page, a table or key the generator skips (nested tables,
    arrays of tables, optional sub-tables), a key invented by the page."""
    page = F.format_page(fmt, ROOT)
    expected = set().union(*(_schema_keys(F.load_class(path), root) for root, path in fmt.roots))
    assert _page_keys(page) == expected


def test_changed_schema_reaches_the_page(monkeypatch):
    """A description, a default and a bound changed in the schema show on the page, and nothing else moves.
    Mutant caught: a hard-coded page (or one cached from an earlier schema)."""
    from physar.fem.config import SolverSection

    fem = next(f for f in F.FORMATS if f.name == "fem")
    before = F.format_page(fem, ROOT)
    field = SolverSection.model_fields["tol"]
    monkeypatch.setattr(field, "description", "relative residual of Newton's method (changed in a test)")
    monkeypatch.setattr(field, "default", 2.5e-7)
    after = F.format_page(fem, ROOT)
    row = next(line for line in after.splitlines() if line.startswith("| `tol` | `float` | `2.5e-07`"))
    assert "relative residual of Newton's method \\(changed in a test\\)" in row
    assert "| > 0 |" in row
    changed = [(a, b) for a, b in zip(before.splitlines(), after.splitlines(), strict=True) if a != b]
    assert len(changed) == 1


def test_units_and_markup_of_a_row():
    """Units are read from the description ([Pa], ', m', a bare unit) or the key's suffix, never guessed;
    markup characters in a description are escaped (a '|' would split the table row)."""
    assert F.unit_text("E", "Young's modulus [Pa]") == "Pa"
    assert F.unit_text("size", "side of the cubic domain [0, size]^3, m") == "m"
    assert F.unit_text("density", "kg/m^3") == "kg/m^3"
    assert F.unit_text("shake_mm", "") == "mm"
    assert F.unit_text("nu", "Poisson ratio") == ""
    assert F.unit_text("nu", "Poisson ratio [-]") == "-"  # stated dimensionless
    assert F.unit_text("path", "keyframes [t, x, y, z]: t [s], x, y, z [m]") == "s, m"
    assert F.unit_text("fix", "a [[fix]] table of [registration.plane]") == ""
    assert F.escape("|u| * 2 [m]") == "\\|u\\| \\* 2 \\[m\\]"
    assert F.escape("see :mod:`physar.mpm.colliders` and ``x``") == "see `physar.mpm.colliders` and `x`"


def test_every_format_page_is_in_the_index():
    index = F.index_page()
    assert all(f"({f.name}.md)" in index for f in F.FORMATS)


# --- API reference and docstrings (need Sphinx) -------------------------------------------------------

@pytest.fixture(scope="module")
def api():
    pytest.importorskip("sphinx", reason="the docs extra is not installed (make docs installs it)")
    return importlib.import_module("physar_api")


def test_every_public_name_has_a_docstring():
    """What ``make docs`` checks on every build (each miss is a warning, so an error under -W); here it runs
    in ``make test`` too, so a public name added without a docstring fails CI, not only the docs build."""
    assert physar_public.missing_docstrings() == []


def test_docstring_check_catches_a_missing_docstring(monkeypatch):
    """Mutant caught: a check that looks at inherited docstrings, skips constants, or does not look."""
    import physar.rom
    import physar.rom.separated

    monkeypatch.setattr(physar.rom.pgd_linear, "__doc__", None)
    monkeypatch.setattr(physar.rom.SeparatedModel, "__doc__", None)  # a class: its own docstring only
    source = physar.rom.separated.__loader__.get_source("physar.rom.separated")
    monkeypatch.setattr(physar_public.inspect, "getsource", lambda module: source.replace("#: Version", "# Version"))
    assert set(physar_public.missing_docstrings(["physar.rom"])) == {
        "physar.rom.pgd_linear", "physar.rom.SeparatedModel", "physar.rom.FORMAT_VERSION"}


def test_api_page_lists_the_package_all(api):
    import physar.fem

    page = api.api_page("physar.fem")
    for name in physar.fem.__all__:
        assert re.search(rf"^\.\. (autoclass|autofunction):: physar\.fem\.{name}$|"
                         rf"^\.\. py:data:: {name}\n   :module: physar\.fem$", page, re.MULTILINE), name


def test_plain_text_docstrings_are_escaped_outside_literals(api):
    lines = ["|u| = sqrt(u**2), ``|a|`` and :func:`x`", "", "* a bullet with a*b", "", "Block::", "",
             "    |u| stays", "after |v|"]
    assert api.plain_text_markup(lines) == [
        "\\|u\\| = sqrt(u\\*\\*2), ``|a|`` and :func:`x`", "", "* a bullet with a\\*b", "", "Block::", "",
        "    |u| stays", "after \\|v\\|"]


def test_math_markup_is_not_escaped(api):
    """Equations marked up as math in a docstring reach Sphinx unchanged: a ``:math:`` role, a ``.. math::``
    block (its content) and a one-line ``.. math::``; the plain text around them is still escaped.
    Mutant caught: ``\\`` doubled or ``*`` escaped inside the TeX (MathJax would show a broken formula)."""
    lines = ["Energy :math:`W = \\frac{\\mu}{2} |F|^2` of x**2", "", ".. math::", "",
             "    \\lVert u \\rVert^2 = a * b", "", ".. math:: |a| \\cdot b^*", "after |v|"]
    assert api.plain_text_markup(lines) == [
        "Energy :math:`W = \\frac{\\mu}{2} |F|^2` of x\\*\\*2", "", ".. math::", "",
        "    \\lVert u \\rVert^2 = a * b", "", ".. math:: |a| \\cdot b^*", "after \\|v\\|"]


def test_summary_line_of_an_equation_docstring(api):
    """The API tables' summary: "(seed Eq. 2.9)" does not end the first sentence (an abbreviation for
    autosummary), and a first paragraph that leads into an equation (``...:``) ends in a full stop."""
    from sphinx.ext import autosummary

    api.setup(type("App", (), {"connect": lambda *a, **k: None})())
    api.setup(type("App", (), {"connect": lambda *a, **k: None})())  # twice (a second build): wrapped once
    assert "Eq." in autosummary.WELL_KNOWN_ABBREVIATIONS and "Alg." in autosummary.WELL_KNOWN_ABBREVIATIONS
    assert autosummary.extract_summary.physar
    summary = api.summary_line(lambda doc, document: " ".join(doc))
    assert summary(["The law, with the strain E:"], None) == "The law, with the strain E."
    assert summary(["Generalized-α; state (q, v):."], None) == "Generalized-α; state (q, v)."
    assert summary(["Damping d (seed Eq. 2.9)."], None) == "Damping d (seed Eq. 2.9)."


def test_cross_reference_to_nothing_stays_broken(api):
    """Existing private physar objects render as code; a name that exists nowhere is not resolved (so the
    build warns, and -W fails). Mutant caught: a resolver that silences every reference."""
    from docutils import nodes
    from sphinx.addnodes import pending_xref

    def ref(target, module="physar.fem"):
        node = pending_xref("", refdomain="py", reftype="func", reftarget=target)
        node["py:module"] = module
        node.source = "docstring of physar.fem.loads.fixed_dofs"
        return api._existing_private_target(None, None, node, nodes.literal(text=target))

    assert ref("select_nodes_mask") is not None  # in physar.fem.loads, the docstring's module
    assert ref("physar.output.atomic_path") is not None
    assert ref("no_such_function") is None
    assert ref("physar.fem.no_such_function") is None


def test_format_pages_build_into_html(tmp_path, monkeypatch):
    """A Sphinx build of the format pages alone (the extension as ``make docs`` loads it) shows a changed
    description in the HTML. Mutant caught: the extension not generating the pages at build time."""
    pytest.importorskip("myst_parser", reason="the docs extra is not installed (make docs installs it)")
    from sphinx.application import Sphinx

    from physar.mpm.scene import Grid

    monkeypatch.setattr(Grid.model_fields["resolution"], "description", "grid cells per side (test marker 41)")
    src = tmp_path / "src"
    src.mkdir()
    (src / "conf.py").write_text("extensions = ['myst_parser', 'physar_formats']\nexclude_patterns = ['_build']\n"
                                 "myst_heading_anchors = 3\n")
    (src / "index.md").write_text("# t\n\n```{toctree}\n_generated/formats/index\n```\n")
    t0 = time.perf_counter()
    app = Sphinx(str(src), str(src), str(tmp_path / "html"), str(tmp_path / "doctrees"), "html",
                 status=None, warning=None, warningiserror=True, keep_going=True, freshenv=True)
    app.build()
    assert app.statuscode == 0
    html = (tmp_path / "html" / "_generated" / "formats" / "mpm_scene.html").read_text()
    assert "grid cells per side (test marker 41)" in html
    assert time.perf_counter() - t0 < 30


# --- the gallery pipeline on tiny examples (needs myst-nb and a Jupyter kernel) ----------------------------

_EXAMPLE = '''"""A tiny example: one figure.

Writes ``tiny.png``.
"""

# %%
import os
from pathlib import Path

import matplotlib.pyplot as plt

OUT = Path(os.environ.get("PHYSAR_EXAMPLE_OUT", "example_out"))
QUICK = os.environ.get("PHYSAR_EXAMPLE_QUICK") == "1"

# %% [markdown]
# ## A figure
# Saved to a file and closed, as the examples do; |p - c(p)| stays text, $\\rho = 1/\\sqrt{{1 + (h\\omega)^2}}$ is math.

# %%
fig, ax = plt.subplots()
ax.plot([0, 1], [0, 1])
fig.savefig(OUT / "tiny.png")
plt.close(fig)
print("quick", QUICK)
{extra}
'''


def _gallery_build(tmp_path: Path, extra: str):
    """Build a site whose gallery is one tiny example, with docs/conf.py's settings (in a subprocess: Sphinx
    extensions keep state per process); (exit status, html dir)."""
    src = tmp_path / "src"
    (tmp_path / "examples").mkdir()
    (tmp_path / "examples" / "tiny.py").write_text(_EXAMPLE.format(extra=extra))
    src.mkdir()
    (src / "conf.py").write_text(f"exec(compile(open({str(DOCS / 'conf.py')!r}).read(), 'conf.py', 'exec'))\n"
                                 "extensions = ['myst_nb', 'physar_gallery']\nhtml_static_path = []\n")
    (src / "index.md").write_text("# t\n\n```{toctree}\n_generated/gallery/index\n```\n")
    html = src / "_build" / "html"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(DOCS / "_ext"), os.environ.get("PYTHONPATH", "")]))
    run = subprocess.run([sys.executable, "-m", "sphinx", "-b", "html", "-W", "--keep-going", "-q", "-E", str(src),
                          str(html)], check=False, capture_output=True, text=True, timeout=600, env=env)
    return run.returncode, html


def test_gallery_shows_the_figure_an_example_saves(tmp_path):
    """An example run as the site runs it (quick mode, its own output folder): its Markdown cells are pages
    text, the figure it saved and closed is on the page. Mutant caught: figures not collected after a cell,
    the quick flag not set, Markdown read as reStructuredText, ``$...$`` not read as math."""
    pytest.importorskip("myst_nb", reason="the docs extra is not installed (make docs installs it)")
    status, html = _gallery_build(tmp_path, "")
    assert status == 0
    page = (html / "_generated" / "gallery" / "tiny.html").read_text()
    assert "<h1>A tiny example: one figure" in page and "<h2>A figure" in page
    assert "|p - c(p)| stays text" in page
    assert re.search(r'class="math[^"]*">\\\(\\rho = 1/\\sqrt\{1 \+ \(h\\omega\)\^2\}\\\)', page)  # MyST dollarmath
    assert re.search(r'<img[^>]+src="[^"]+\.png"', page)
    assert "quick True" in page
    index = (html / "_generated" / "gallery" / "index.html").read_text()
    assert 'src="../../gallery_files/tiny/thumbnail.png"' in index
    assert (html / "gallery_files" / "tiny" / "thumbnail.png").read_bytes().startswith(b"\x89PNG")


@pytest.mark.slow  # a second kernel and build: keeps the fast tests under 30 s
def test_a_failing_example_fails_the_build(tmp_path):
    """Mutant caught: nb_execution_raise_on_error off (the page would show a traceback and the build pass)."""
    pytest.importorskip("myst_nb", reason="the docs extra is not installed (make docs installs it)")
    status, _ = _gallery_build(tmp_path, "raise RuntimeError('example broke')")
    assert status != 0
