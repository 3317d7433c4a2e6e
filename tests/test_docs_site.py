"""The documentation site as ``make docs`` builds it (issue 22), in ``make test``: the whole site in quick mode
with warnings as errors, in a bounded time; the equations of the docstrings rendered as math in the API
reference; screenshots of the landing page, gallery pages and math pages in headless Chromium (Debian's
``chromium`` + ``chromium-driver``, driven by selenium) under ``docs/_build/screenshots`` (build artefacts,
not in git), with what the browser saw checked: math typeset by the site's own MathJax, figures loaded,
nothing fetched from elsewhere, no blank page.

The build needs the ``docs`` extra (``pip install -e '.[docs]'``; ``make docs`` installs it); without it the
build tests are skipped. The screenshots need Chromium and chromedriver (``make env`` installs them as root).
"""

from __future__ import annotations

import fcntl
import importlib
import inspect
import json
import os
import pickle
import re
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
BUILD = DOCS / "_build"
HTML = BUILD / "html"
sys.path.insert(0, str(DOCS / "_ext"))
sys.path.insert(0, str(DOCS))

import physar_formats as F
import physar_public
import screenshot as shot

# the build of `make docs` (Makefile): every page read afresh (-E), warnings are errors, examples in quick mode
SPHINX_ARGS = ["-b", "html", "-W", "--keep-going", "-q", "-E", "docs", "docs/_build/html"]
BUILD_BUDGET_S = 300  # about 55 s on 2 shared cores (2026-11-26); a build past this fails the test
BUILD_TIMEOUT_S = 600

# public objects whose docstrings state a seed equation, and must show it as math (`:math:` / `.. math::`)
MATH_DOCSTRINGS = {
    "physar.geometry": ["tet_quality"],
    "physar.fem": ["LinearElastic", "StVK", "NeoHookean", "NeoHookeanIncompressible", "Corotated", "point_load",
                   "gravity_load", "von_mises", "timoshenko_cantilever_tip"],
    "physar.integrators": ["SymplecticEuler", "BackwardEuler", "ImplicitMidpoint", "GeneralizedAlpha",
                           "ThetaMethod", "TRBDF2", "genalpha_coefficients", "rho_backward_euler",
                           "d_backward_euler", "damping_curve", "LinearDynamics", "SolidModel",
                           "CorotatedP1Kernel"],
    "physar.rom": ["SeparatedModel", "pgd_linear", "pgd_linear_tensor"],
    "physar.assimilation": ["observation_matrix"],
    "physar.vision": ["Pose", "surface_observation_matrix"],
    "physar.synth": ["rasterize"],
    "physar.gaussians": ["covariance", "eval_sh", "render"],
    "physar.skinning": ["lbs", "blend_transforms", "winding_number", "axis_angle_to_matrix"],
    "physar.mpm": ["Control", "MPMModel", "diagnostics"],
}
MATH_MODULES = ["physar.assimilation", "physar.recon.flow", "physar.recon.canonical", "physar.recon.metrics",
                "physar.recon.train", "physar.ar.project_pipeline", "physar.ar.surface"]  # shown in the reference


def _noise_free(stderr: str) -> str:
    """The build's stderr without the kernels' chatter (the warnings and errors of the build remain)."""
    noise = ("IPKernelApp", "traitlets", "Warp CUDA warning", "Kernel is running over TCP")
    return "\n".join(line for line in stderr.splitlines() if line.strip() and not any(n in line for n in noise))


# --- fast checks (no Sphinx) --------------------------------------------------------------------------------

def test_makefile_docs_is_the_tested_build():
    """``make docs`` and this test build the same way. Mutant caught: -W or -E dropped from one of them."""
    recipe = re.search(r"^docs:.*\n((?:\t.*\n)+)", (ROOT / "Makefile").read_text(), re.MULTILINE)
    assert recipe, "no docs target in the Makefile"
    assert "sphinx-build " + " ".join(SPHINX_ARGS) in recipe.group(1)


@pytest.mark.parametrize("name", [f"{p}.{n}" for p, names in MATH_DOCSTRINGS.items() for n in names]
                         + MATH_MODULES)
def test_seed_equations_are_marked_as_math(name):
    """The docstrings that state a seed equation mark it up as math (reStructuredText ``:math:`` or
    ``.. math::``, pyMOR's convention), so the API reference renders it; a rewrite back to plain text fails."""
    module, _, attr = name.rpartition(".")
    obj = importlib.import_module(name) if name in MATH_MODULES else getattr(importlib.import_module(module), attr)
    doc = inspect.getdoc(obj) or ""
    assert ":math:`" in doc or ".. math::" in doc, f"{name}: no math markup in its docstring"


# --- the site ------------------------------------------------------------------------------------------------

@dataclass
class Site:
    html: Path
    seconds: float
    pages: list[Path]
    examples_s: dict[str, float]  # execution time of each gallery example


def _example_times(html: Path) -> dict[str, float]:
    """Seconds each example took to execute in the build, from myst-nb's record in the environment (best
    effort: empty if myst-nb keeps it elsewhere)."""
    try:
        with open(html / ".doctrees" / "environment.pickle", "rb") as f:
            env = pickle.load(f)
        return {doc.rsplit("/", 1)[-1]: round(md["exec_data"]["runtime"], 1)
                for doc, md in sorted(env.nb_metadata.items()) if md.get("exec_data")}
    except (OSError, EOFError, pickle.UnpicklingError, AttributeError, KeyError, TypeError):  # a diagnostic
        return {}


@pytest.fixture(scope="module")
def site():
    """The site, built once for this module as ``make docs`` builds it, into docs/_build/html. A lock keeps
    two test runs from building into the same folder at once."""
    pytest.importorskip("sphinx", reason="the docs extra is not installed (pip install -e '.[docs]')")
    pytest.importorskip("myst_nb", reason="the docs extra is not installed (pip install -e '.[docs]')")
    BUILD.mkdir(parents=True, exist_ok=True)
    with open(BUILD / ".test-site.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        env = {k: v for k, v in os.environ.items() if k not in ("PHYSAR_DOCS_EXECUTE", "PHYSAR_DOCS_FULL")}
        t0 = time.perf_counter()
        run = subprocess.run([sys.executable, "-m", "sphinx", *SPHINX_ARGS], cwd=ROOT, env=env, check=False,
                             capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
        seconds = time.perf_counter() - t0
        assert run.returncode == 0, f"the docs build failed:\n{_noise_free(run.stderr)[-6000:]}"
        assert not _noise_free(run.stderr), _noise_free(run.stderr)[-6000:]
        built = Site(HTML, seconds, sorted(HTML.rglob("*.html")), _example_times(HTML))
        (BUILD / "test-site.json").write_text(json.dumps({"build_s": round(seconds, 1), "html_pages": len(built.pages),
                                                          "examples_s": built.examples_s}, indent=1) + "\n")
        yield built


def test_site_builds_in_bounded_time(site):
    """The quick build CI runs stays bounded (examples in quick mode): a slow example or a full-size run
    crossing the budget fails here, before CI's own limit."""
    print(f"docs build: {site.seconds:.0f} s, {len(site.pages)} pages, examples {site.examples_s}")
    assert site.seconds < BUILD_BUDGET_S, (f"docs build took {site.seconds:.0f} s (budget {BUILD_BUDGET_S} s); "
                                           f"examples (s): {site.examples_s}")


def test_site_has_every_generated_page(site):
    """A page per package of the public API, per file format, per example; the landing page is the README's
    tour and the benchmark results are in. Mutant caught: a generator that skips a source."""
    html = site.html
    expected = ["index", "equations", "_generated/benchmarks", "_generated/api/index", "_generated/formats/index",
                "_generated/gallery/index"]
    expected += [f"_generated/api/{p}" for p in physar_public.PACKAGES]
    expected += [f"_generated/formats/{f.name}" for f in F.FORMATS]
    examples = sorted((ROOT / "examples").glob("*.py"))
    expected += [f"_generated/gallery/{e.stem}" for e in examples]
    missing = [name for name in expected if not (html / f"{name}.html").exists()]
    assert not missing
    assert "A short tour" in (html / "index.html").read_text()
    results_title = (ROOT / "benchmarks" / "RESULTS.md").read_text().splitlines()[0].lstrip("# ").strip()
    assert results_title in (html / "_generated" / "benchmarks.html").read_text()
    for example in examples:
        page = (html / "_generated" / "gallery" / f"{example.stem}.html").read_text()
        assert re.search(r'<img[^>]+src="[^"]+\.png"', page), f"{example.name}: no figure on its gallery page"
        assert (html / "gallery_files" / example.stem / "thumbnail.png").stat().st_size > 0, example.name
    recon = (html / "_generated" / "gallery" / "recon_tiny.html").read_text()
    assert 'href="../../gallery_files/recon_tiny/recon_novel.mp4"' in recon
    assert (html / "gallery_files" / "recon_tiny" / "recon_novel.mp4").stat().st_size > 0


def test_site_fetches_nothing_from_elsewhere(site):
    """Offline: no script, stylesheet or font from another host, MathJax served from the site itself."""
    for page in site.pages:
        text = page.read_text()
        assert not re.search(r'<(script|link|img)[^>]+(src|href)="(https?:)?//', text), page
    assert (site.html / "_static" / "mathjax" / "tex-chtml.js").exists()
    assert list((site.html / "_static" / "mathjax" / "output" / "chtml" / "fonts" / "woff-v2").glob("*.woff"))


def _entry(page: str, ident: str) -> str:
    """The HTML of one documented object (its signature to the next object that is not one of its members)."""
    start = page.index(f'id="{ident}"')
    for m in re.finditer(r'<dt class="sig sig-object py" id="([^"]+)"', page[start + 1:]):
        if not m.group(1).startswith(ident + "."):
            return page[start:start + 1 + m.start()]
    return page[start:]


def test_api_reference_renders_the_equations_as_math(site):
    """Each docstring's equation reaches its entry in the API reference as a math element, and the page loads
    the site's MathJax. Mutant caught: math markup escaped as plain text (physar_api), MathJax not loaded."""
    for package, names in MATH_DOCSTRINGS.items():
        page = (site.html / "_generated" / "api" / f"{package}.html").read_text()
        assert 'src="../../_static/mathjax/tex-chtml.js' in page, package
        for name in names:
            assert 'class="math' in _entry(page, f"{package}.{name}"), f"{package}.{name}: no math in its entry"
            assert "\\\\(" not in _entry(page, f"{package}.{name}"), f"{package}.{name}: escaped math"
    table = re.search(r'<table class="autosummary.*?</table>',
                      (site.html / "_generated" / "api" / "physar.integrators.html").read_text(), re.DOTALL)
    assert "(seed Eq. 2.11-2.12); state" in re.sub(r"<[^>]+>", "", table.group(0))  # "Eq." ends no sentence
    assimilation = (site.html / "_generated" / "api" / "physar.assimilation.html").read_text()
    assert 'class="math' in assimilation.split('<dt class="sig')[0]  # the package docstring, before the entries
    recon = (site.html / "_generated" / "api" / "physar.recon.html").read_text()
    flow = recon[recon.index('id="module-physar.recon.flow"'):]
    assert 'class="math' in flow[:flow.find('id="module-', 20)]


# --- what a browser shows ----------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def browser():
    found = shot.find_browser()
    if found is None:
        pytest.skip("needs Debian's chromium and chromium-driver (`make env` installs them when run as root)")
    pytest.importorskip("selenium")
    return found


def test_screenshots_show_rendered_math_and_figures(site, browser):
    """Screenshots of the landing page, two gallery pages (their figures), two API pages and the equations page
    (typeset math), taken in headless Chromium from ``file://`` URLs as a reader opens the site. On each: the
    screenshot is not blank, every formula is typeset by MathJax without error, every image is loaded, nothing
    is fetched from another host; the math pages show math, the gallery pages a figure, within the screenshot."""
    shots = BUILD / "screenshots"
    pages = dict(shot.PAGES)
    for name, (page, expects) in shot.PAGES.items():  # an example whose Markdown has $math$ shows it typeset
        example = ROOT / "examples" / f"{name.removeprefix('gallery_')}.py"
        if name.startswith("gallery_") and re.search(r"^# .*\$[^$\n]+\$", example.read_text(), re.MULTILINE):
            pages[name] = (page, (*expects, "math"))
    reports = shot.take_all(site.html, shots, pages)
    (BUILD / "test-site-screenshots.json").write_text(json.dumps(
        {n: {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(r).items() if k != "external"}
         for n, r in reports.items()}, indent=1, default=str) + "\n")
    problems = {name: r.problems() for name, r in reports.items() if r.problems()}
    assert not problems
    assert set(reports) == set(shot.PAGES)
    for name, (_, expects) in pages.items():
        assert (shots / f"{name}.png").read_bytes().startswith(b"\x89PNG")
        if "math" in expects:
            assert reports[name].typeset >= 5, name
    assert reports["api_integrators"].typeset >= 30  # the steppers' and damping docstrings


def test_page_check_flags_a_broken_page(tmp_path, browser):
    """The browser check itself: a formula MathJax never typeset, an image that does not load, a script from
    another host and a blank page are each reported. Mutant caught: a check that passes whatever it sees."""
    broken = tmp_path / "broken.html"
    text = "Some words of text. " * 20
    broken.write_text(f'<html><body><article><p>{text}</p><span class="math">\\(x^2\\)</span>'
                      '<img src="missing.png"><script src="http://127.0.0.1:9/x.js"></script></article></body></html>')
    (tmp_path / "blank.html").write_text("<html><body></body></html>")
    pages = {"broken": ("broken.html", ("math", "figure")), "blank": ("blank.html", ())}
    reports = shot.take_all(tmp_path, tmp_path / "shots", pages=pages)
    problems = " | ".join(reports["broken"].problems())
    for phrase in ("1 of 1 formulas not typeset", "no typeset math", "1 of 1 images not loaded", "no figure",
                   "fetched from outside the site"):
        assert phrase in problems
    assert any("blank screenshot" in p for p in reports["blank"].problems())
