"""The public API (issue 22, docs/api_policy.md): what each package's ``__all__`` names (and, for the
submodules ``physar.ar`` and ``physar.recon`` list there, the submodule's own ``__all__``) exists, has a
docstring, reaches the API reference's autodoc input, and is all that the examples and the README import.

Each check is a function returning the problems it finds; a test asserts that the code has none, and a
second test plants the mutant it is there for and asserts that the check reports it:

* a name dropped from ``__all__`` while an example still imports it (or an example importing from a private
  module, e.g. ``physar.geometry.denoise``): :func:`private_imports`;
* a public name added without a docstring, including a dataclass whose only "docstring" is the signature
  ``@dataclass`` writes: :func:`undocumented`;
* an API page that leaves a public name out: :func:`missing_from_reference`;
* a duplicate or an unsorted ``__all__``, a private (``_``) name in it, a listed submodule without its own
  ``__all__`` (every helper of it would be public): :func:`order_problems`, :func:`all_problems`.
* a package of physar without ``__all__``, or one with public names that the reference leaves out:
  :func:`package_problems` (``physar.cli`` declares an empty one: its Python functions are private);
* an API page that documents something private (a name not in ``__all__``, a private module, private or
  undocumented members): :func:`private_in_reference`.

Needs only the package (the API-page check also needs Sphinx, the ``docs`` extra, and is skipped without it).
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import re
import sys
import types
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "docs" / "_ext"))

import physar_public

# --- what the code claims ---------------------------------------------------------------------------------

def public_api() -> dict[str, list[str]]:
    """{public module: its ``__all__``}, found by walking the ``__all__`` lists from the packages of the API
    reference (not through ``physar_public.public_api``, which the docs build uses: a second walk)."""
    api = {}
    for package in physar_public.PACKAGES:
        module = importlib.import_module(package)
        api[package] = list(module.__all__)
        for name in module.__all__:
            try:
                sub = importlib.import_module(f"{package}.{name}")
            except ImportError:
                continue
            if getattr(module, name, sub) is sub:  # a submodule listed by name (not a function of that name)
                api[sub.__name__] = list(getattr(sub, "__all__", ()))
    return api


def _object(module: str, name: str):
    mod = importlib.import_module(module)
    if hasattr(mod, name):
        return getattr(mod, name)
    return importlib.import_module(f"{module}.{name}")  # a submodule not imported by the package


def _docstring(obj) -> str:
    """The docstring written for ``obj``: a class's own (inherited ones do not count), and not the signature
    that ``@dataclass`` (or a named tuple) writes when none was given."""
    if inspect.isclass(obj):
        doc = obj.__dict__.get("__doc__") or ""
        if dataclasses.is_dataclass(obj) and doc.strip() == f"{obj.__name__}{inspect.signature(obj)}".replace(
                " -> None", ""):
            return ""
        if issubclass(obj, tuple) and re.fullmatch(rf"{obj.__name__}\(.*\)", doc.strip()):
            return ""
        return doc.strip()
    return (getattr(obj, "__doc__", None) or "").strip()


def _comment_doc(module: str, name: str) -> str:
    """The ``#:`` comment above the assignment of a constant, in the module that defines it."""
    mod = importlib.import_module(module)
    value = getattr(mod, name)
    candidates = [mod] + [m for m in list(sys.modules.values())
                          if isinstance(m, types.ModuleType) and m.__name__.startswith(module + ".")]
    for m in candidates:
        if m.__dict__.get(name, object()) is not value:
            continue
        try:
            lines = inspect.getsource(m).splitlines()
        except (OSError, TypeError):
            continue
        for i, line in enumerate(lines):
            if re.match(rf"{re.escape(name)}\s*(:[^=]+)?=", line):
                doc = []
                while i > 0 and lines[i - 1].startswith("#:"):
                    i -= 1
                    doc.append(lines[i])
                if doc:
                    return " ".join(doc)
    return ""


def undocumented(api: dict[str, list[str]]) -> list[str]:
    """Public names that do not exist, or exist without a docstring (a constant: without a ``#:`` comment)."""
    problems = []
    for module, names in api.items():
        for name in names:
            try:
                obj = _object(module, name)
            except (AttributeError, ImportError):
                problems.append(f"{module}.{name}: listed in __all__ but not defined")
                continue
            if name == "__version__":
                continue
            if inspect.isclass(obj) or inspect.isroutine(obj) or isinstance(obj, types.ModuleType) or callable(obj):
                if not _docstring(obj):
                    problems.append(f"{module}.{name}: no docstring")
            elif not _comment_doc(module, name):
                problems.append(f"{module}.{name}: a constant without a #: comment")
    return problems


def missing_from_reference(api: dict[str, list[str]], page_of) -> list[str]:
    """Public names that the autodoc input of their package's API page (``page_of(package)``) does not
    document: a class, function or constant needs its own directive; a listed submodule an ``automodule``
    with ``:members:`` (autodoc then documents what the submodule's ``__all__`` names)."""
    problems = []
    for package in physar_public.PACKAGES:
        page = page_of(package)
        for name in api[package]:
            sub = f"{package}.{name}"
            if sub in api:
                if not re.search(rf"^\.\. automodule:: {re.escape(sub)}\n   :members:$", page, re.MULTILINE):
                    problems.append(f"{sub}: no automodule with :members: on the {package} page")
            elif not (re.search(rf"^\.\. (autoclass|autofunction):: {re.escape(sub)}$", page, re.MULTILINE) or re.search(
                    rf"^\.\. py:data:: {re.escape(name)}\n   :module: {re.escape(package)}$", page, re.MULTILINE)):
                problems.append(f"{sub}: not on the {package} page")
    return problems


# --- what the examples and the README use -----------------------------------------------------------------

def code_sources() -> dict[str, str]:
    """The examples (``examples/**/*.py``) and the Python code blocks of README.md and the docs pages."""
    sources = {str(p.relative_to(ROOT)): p.read_text() for p in sorted((ROOT / "examples").rglob("*.py"))}
    for md in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        blocks = re.findall(r"^```(?:python|py|\{code-cell\}[^\n]*)\n(.*?)^```", md.read_text(), re.DOTALL | re.MULTILINE)
        for i, block in enumerate(blocks):
            sources[f"{md.relative_to(ROOT)} python block {i + 1}"] = block
    return sources


def private_imports(sources: dict[str, str], api: dict[str, list[str]]) -> list[str]:
    """Every ``from physar.X import Y`` / ``import physar.X`` whose name is not public."""
    public_modules = set(api) | {"physar"}
    problems = []
    for where, text in sources.items():
        try:
            tree = ast.parse(text)
        except SyntaxError:  # a README block of another language marked as Python would be a README bug
            problems.append(f"{where}: not Python")
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "physar":
                for alias in node.names:
                    if node.module not in public_modules:
                        problems.append(f"{where}:{node.lineno}: from {node.module} import {alias.name} "
                                        f"(a private module)")
                    elif alias.name not in api.get(node.module, ()) and f"{node.module}.{alias.name}" not in api:
                        problems.append(f"{where}:{node.lineno}: from {node.module} import {alias.name} "
                                        f"({alias.name} is not in {node.module}.__all__)")
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name.split(".")[0] == "physar" and alias.name not in public_modules:
                        problems.append(f"{where}:{node.lineno}: import {alias.name} (a private module)")
    return problems


# --- the shape of __all__ ---------------------------------------------------------------------------------

def _group(name: str) -> int:
    """ruff's isort-style order of ``__all__`` (RUF022), the project's: CONSTANTS, then Classes, then the rest."""
    if name.isupper():
        return 0
    if name[:1].isupper():
        return 1
    return 2


def order_problems(module: str, names: list[str]) -> list[str]:
    problems = []
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        problems.append(f"{module}.__all__: duplicates {duplicates}")
    expected = sorted(dict.fromkeys(names), key=lambda n: (_group(n), n))
    if list(dict.fromkeys(names)) != expected:
        problems.append(f"{module}.__all__ is not sorted (constants, classes, the rest): {expected}")
    private = [n for n in names if n.startswith("_") and not (n.startswith("__") and n.endswith("__"))]
    if private:
        problems.append(f"{module}.__all__ lists private names {private}")
    return problems


def all_problems(api: dict[str, list[str]]) -> list[str]:
    problems = []
    for module, names in api.items():
        if not hasattr(importlib.import_module(module), "__all__"):
            problems.append(f"{module} is listed as public but has no __all__ (all its helpers would be public)")
        problems += order_problems(module, names)
    return problems


def package_problems(root: Path, documented) -> list[str]:
    """Every package under ``root`` (a directory with ``__init__.py``, read as source: nothing imported) states
    its public API in a literal ``__all__``; one that the reference does not document (not in
    ``documented``) must declare it empty: wholly private (``physar.cli``: the command line is the interface).
    Catches a new subpackage that exports its helpers by default, or one public but missing from the docs."""
    problems = []
    for init in sorted(root.rglob("__init__.py")):
        name = ".".join(init.relative_to(root.parent).parent.parts)
        names = None
        for node in ast.parse(init.read_text()).body:
            target = node.targets[0] if isinstance(node, ast.Assign) else getattr(node, "target", None)
            if isinstance(target, ast.Name) and target.id == "__all__" and node.value is not None:
                names = ast.literal_eval(node.value)
        if names is None:
            problems.append(f"{name}: no __all__ in its __init__.py")
        elif name not in documented and names:
            problems.append(f"{name}: __all__ lists {sorted(names)} but the API reference does not document it")
    return problems


_DIRECTIVE = re.compile(r"^\.\. (automodule|autoclass|autofunction|py:data):: (\S+)\n((?:   :.*\n)*)", re.MULTILINE)
_NO_PRIVATE_OPTIONS = (":private-members:", ":undoc-members:", ":imported-members:", ":ignore-module-all:",
                       ":special-members:")


def private_in_reference(api: dict[str, list[str]], page_of) -> list[str]:
    """What the autodoc input of the API pages (``page_of(package)``) would document beyond the public API:
    a directive or an autosummary entry for a name not in its module's ``__all__``, a private module, a
    package page whose ``automodule`` has ``:members:`` (the page's own entries decide what is shown), or an
    option that adds private or undocumented members."""
    problems = []
    for package in physar_public.PACKAGES:
        page = page_of(package)
        for kind, target, options in _DIRECTIVE.findall(page):
            if kind == "py:data":  # a constant by its name, in the module its :module: option names
                target = re.search(r":module: (\S+)", options).group(1) + "." + target
            module, _, name = target.rpartition(".")
            if kind == "automodule":
                if target == package:
                    if ":no-members:" not in options:
                        problems.append(f"{package} page: automodule {target} without :no-members:")
                elif target not in api:
                    problems.append(f"{package} page: automodule {target}, a private module")
            elif module not in api or name not in api[module]:
                problems.append(f"{package} page: {kind} {target}, not in {module}.__all__")
            problems += [f"{package} page: {target} with {o}" for o in _NO_PRIVATE_OPTIONS if o in options]
        for block in re.findall(r"^\.\. autosummary::\n((?:   .*\n|\n)*)", page, re.MULTILINE):
            entries = [line.strip() for line in block.splitlines() if line.strip() and not line.strip().startswith(":")]
            problems += [f"{package} page: autosummary entry {e}, not in {package}.__all__"
                         for e in entries if e not in api[package]]
    return problems


# --- the tests ----------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def api():
    return public_api()


def test_the_docs_and_this_test_agree_on_the_public_api(api):
    """Two walks of the ``__all__`` lists (this test's, the docs build's) find the same public API."""
    assert api == physar_public.public_api()
    assert {"physar.recon.train", "physar.ar.video", "physar.geometry"} <= set(api)


def test_every_public_name_exists_and_has_a_docstring(api):
    assert undocumented(api) == []


def test_undocumented_catches_a_name_without_docstring(api, monkeypatch):
    """Mutants caught: a public function added without a docstring; a public dataclass whose only docstring
    is the signature @dataclass generates (what ``PoseEstimate`` had); a name in __all__ that is not defined."""
    import physar.geometry
    import physar.vision

    @dataclasses.dataclass
    class PoseEstimate:  # the mutant: no docstring
        pose: object
        status: str

    monkeypatch.setattr(physar.geometry.msal, "__doc__", None)
    monkeypatch.setattr(physar.vision, "PoseEstimate", PoseEstimate)
    mutant = {**api, "physar.fem": [*api["physar.fem"], "no_such_solver"]}
    assert set(undocumented(mutant)) == {"physar.geometry.msal: no docstring",
                                         "physar.vision.PoseEstimate: no docstring",
                                         "physar.fem.no_such_solver: listed in __all__ but not defined"}


def test_examples_and_readme_import_only_public_names(api):
    """Every ``from physar.X import Y`` of examples/*.py, README.md's code blocks and the docs pages names
    something in ``physar.X.__all__``, so what the gallery shows uses no private name."""
    sources = code_sources()
    assert any(k.startswith("examples/") for k in sources) and any(k.startswith("README.md") for k in sources)
    assert private_imports(sources, api) == []


def test_private_imports_catches_a_name_dropped_from_all(api):
    """Mutants caught: a public name dropped from ``__all__`` while an example imports it; an example that
    imports from a private module (examples/denoise_mesh.py did: ``physar.geometry.denoise``)."""
    sources = code_sources()
    mutant = {**api, "physar.geometry": [n for n in api["physar.geometry"] if n != "msal"]}
    assert any("from physar.geometry import msal (msal is not in physar.geometry.__all__)" in p
               for p in private_imports(sources, mutant))
    old_example = {"examples/denoise_mesh.py": "from physar.geometry.denoise import msal\nimport physar.output\n"}
    assert private_imports(old_example, api) == [
        "examples/denoise_mesh.py:1: from physar.geometry.denoise import msal (a private module)",
        "examples/denoise_mesh.py:2: import physar.output (a private module)"]


def test_all_lists_are_sorted_without_duplicates_or_private_names(api):
    assert all_problems(api) == []


def test_all_problems_catches_duplicates_disorder_and_helpers(api, monkeypatch):
    """Mutants caught: a name listed twice, appended out of order, a ``_helper`` made public, a listed
    submodule without its own ``__all__``."""
    import physar.recon.io

    assert order_problems("m", ["B", "a", "a"]) == ["m.__all__: duplicates ['a']"]
    assert order_problems("m", ["a", "B"]) == ["m.__all__ is not sorted (constants, classes, the rest): ['B', 'a']"]
    assert order_problems("m", ["TET_FACES", "TetMesh", "box_mesh"]) == []
    assert order_problems("m", ["_npz"]) == ["m.__all__ lists private names ['_npz']"]
    monkeypatch.delattr(physar.recon.io, "__all__")
    assert all_problems({"physar.recon.io": []}) == [
        "physar.recon.io is listed as public but has no __all__ (all its helpers would be public)"]


@pytest.fixture(scope="module")
def physar_api():
    pytest.importorskip("sphinx", reason="the docs extra is not installed (make docs installs it)")
    return importlib.import_module("physar_api")


def test_every_public_name_is_in_the_api_reference(api, physar_api):
    """The autodoc input the docs build writes (one page per package) documents every public name."""
    assert missing_from_reference(api, physar_api.api_page) == []


def test_missing_from_reference_catches_a_skipped_name(api, physar_api, monkeypatch):
    """Mutant caught: a page generator that skips a name (here: the functions) or a listed submodule."""
    entry = physar_api._entry
    monkeypatch.setattr(physar_api, "_entry",
                        lambda package, name, obj: [] if name == "msal" else entry(package, name, obj))
    problems = missing_from_reference(api, physar_api.api_page)
    assert problems == ["physar.geometry.msal: not on the physar.geometry page"]
    monkeypatch.undo()
    page = physar_api.api_page("physar.recon").replace(".. automodule:: physar.recon.train\n", "")
    problems = missing_from_reference({**api}, lambda p: page if p == "physar.recon" else physar_api.api_page(p))
    assert problems == ["physar.recon.train: no automodule with :members: on the physar.recon page"]


def test_every_package_states_its_public_api():
    """Each package of physar has an ``__all__``; those the reference leaves out export nothing."""
    assert package_problems(ROOT / "physar", physar_public.PACKAGES) == []
    assert {"physar.fem", "physar.cli"} <= {".".join(p.relative_to(ROOT).parent.parts)
                                           for p in (ROOT / "physar").rglob("__init__.py")}


def test_package_problems_catches_a_package_without_all(tmp_path):
    """Mutants caught: a new subpackage without ``__all__`` (every helper public by default); a package
    that lists names in ``__all__`` but is not in the reference (public and undocumented)."""
    root = tmp_path / "physar"
    for name, text in {"": "__all__ = ['PhysarError']", "fem": "__all__ = ['solve_static']",
                       "cli": "__all__: list[str] = []", "newpkg": '"""A new package."""\nx = 1',
                       "extra": "__all__ = ['helper']"}.items():
        (root / name).mkdir(parents=True, exist_ok=True)
        (root / name / "__init__.py").write_text(text + "\n")
    assert package_problems(root, ("physar", "physar.fem")) == [
        "physar.extra: __all__ lists ['helper'] but the API reference does not document it",
        "physar.newpkg: no __all__ in its __init__.py"]


def test_nothing_private_is_in_the_api_reference(api, physar_api):
    """The autodoc input of the API pages names only public names and public modules, with no option that
    would pull in private or undocumented members."""
    assert private_in_reference(api, physar_api.api_page) == []


def test_private_in_reference_catches_a_private_name(api, physar_api, monkeypatch):
    """Mutants caught: a page generator that documents a name not in ``__all__`` (here the package's
    attribute ``denoise``, a private module) or a private function; a package automodule with
    ``:members:``; an ``:undoc-members:`` option."""
    public_names = physar_api.public_names
    monkeypatch.setattr(physar_api, "public_names", lambda p: [*public_names(p), "denoise", "al_iterate"]
                        if p == "physar.geometry" else public_names(p))
    import physar.geometry
    from physar.geometry.denoise import al_iterate

    monkeypatch.setattr(physar.geometry, "al_iterate", al_iterate, raising=False)
    assert private_in_reference(api, physar_api.api_page) == [
        "physar.geometry page: autofunction physar.geometry.al_iterate, not in physar.geometry.__all__",
        "physar.geometry page: automodule physar.geometry.denoise, a private module",
        "physar.geometry page: autosummary entry al_iterate, not in physar.geometry.__all__"]
    monkeypatch.undo()
    page = physar_api.api_page("physar.fem").replace(":no-members:", ":members:\n   :undoc-members:")
    assert private_in_reference(api, lambda p: page if p == "physar.fem" else physar_api.api_page(p)) == [
        "physar.fem page: automodule physar.fem without :no-members:",
        "physar.fem page: physar.fem with :undoc-members:"]


def test_the_stability_page_names_every_public_package():
    """docs/api_policy.md (in the site's table of contents) states the rule and names each package of the
    reference: a package added to the reference and not to the page fails here."""
    page = (ROOT / "docs" / "api_policy.md").read_text()
    assert "api_policy" in (ROOT / "docs" / "index.md").read_text()
    assert "## Deprecation" in page and "__all__" in page
    missing = [p for p in physar_public.PACKAGES if p != "physar" and f"`{p}`" not in page]
    assert missing == []
