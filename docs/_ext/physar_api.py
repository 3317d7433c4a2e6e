"""API reference pages from each package's ``__all__``, and the check that every public name has a docstring.

The public API of physar is what each package lists in ``__all__`` (ARCHITECTURE.md: the rest is private).
:func:`api_page` writes one page per package: its docstring, a summary table and an autodoc entry per name.
Where ``__all__`` lists submodules (``physar.ar``, ``physar.recon``: their names are not imported by the
package itself), the page documents each submodule's public members. The public names without a docstring
(:func:`physar_public.missing_docstrings`) are reported as warnings, so ``-W`` fails on them.
"""

from __future__ import annotations

import importlib
import inspect
import re
import sys
import types
from pathlib import Path

from physar_formats import write_if_changed
from physar_public import PACKAGES, _is_data, data_doc, missing_docstrings, public_names, resolve
from sphinx.util import logging

logger = logging.getLogger(__name__)


def _entry(package: str, name: str, obj) -> list[str]:
    full = f"{package}.{name}"
    if inspect.isclass(obj):
        return [f".. autoclass:: {full}", "   :members:", ""]
    if inspect.isroutine(obj) or callable(obj):
        return [f".. autofunction:: {full}", ""]
    # a constant by its own name in its package (a dotted name here would be read as relative to the
    # automodule's package: physar.fem.physar.fem.MATERIALS)
    if name == "__version__":
        return [f".. py:data:: {name}", f"   :module: {package}", "", "   The installed version of physar.", ""]
    return [f".. py:data:: {name}", f"   :module: {package}", f"   :value: {obj!r}"[:200], "",
            f"   {data_doc(package, name) or ''}", ""]


def api_page(package: str) -> str:
    """The page of one package (MyST Markdown around an ``eval-rst`` block of autodoc directives)."""
    names = public_names(package)
    rst = [f".. automodule:: {package}", "   :no-members:", ""]
    modules = [n for n in names if isinstance(resolve(package, n), types.ModuleType)]
    objects = [n for n in names if n not in modules]
    if objects:
        listed = [n for n in objects if not _is_data(resolve(package, n))]  # a constant's docstring is its type's
        rst += [".. autosummary::", "   :nosignatures:", "", *(f"   {n}" for n in listed), ""]
        for name in objects:
            rst += _entry(package, name, resolve(package, name))
    for name in modules:
        module = resolve(package, name)
        title = f"``{module.__name__}``"
        rst += [title, "-" * len(title), "", f".. automodule:: {module.__name__}", "   :members:", ""]
    return "\n".join([f"# `{package}`", "", "```{eval-rst}", *rst, "```", ""])


def index_page(packages=PACKAGES) -> str:
    """The API index: one line per package, its docstring's first line."""
    lines = ["# API reference", "",
             ("The public API of each package is its `__all__`, documented here from the docstrings; anything "
             "else is private and may change ([Public API and stability](../../api_policy.md)). Equations cite "
             "the seed papers' sections."), "",
             "| package | |", "|---|---|"]
    for package in packages:
        doc = (importlib.import_module(package).__doc__ or "").strip().split("\n\n")[0]
        lines.append(f"| [`{package}`]({package}.md) | {' '.join(doc.split()).replace('|', chr(92) + '|')} |")
    lines += ["", "```{toctree}", ":hidden:", "", *packages, "```", ""]
    return "\n".join(lines)


def write_api_pages(out_dir: Path, packages=PACKAGES) -> None:
    """Write ``index.md`` and one page per package into ``out_dir``."""
    for package in packages:
        write_if_changed(out_dir / f"{package}.md", api_page(package))
    write_if_changed(out_dir / "index.md", index_page(packages))


_LITERAL = re.compile(r"(``.+?``|:[a-z:]+:`[^`]*`|`[^`]*`_?)")


def plain_text_markup(lines: list[str]) -> list[str]:
    """Escape the characters that physar's docstrings use as plain-text notation and reStructuredText reads
    as markup: ``|`` (norms, ``|u|``: a substitution reference) and ``*`` (``x**2``, ``a * b``: emphasis),
    outside literals, roles (``:math:`...```), literal blocks (after ``::``), directives and their content
    (``.. math::``), grid tables and bullets (a leading ``* ``)."""
    out, literal_indent, in_table = [], None, False
    for line in lines:
        indent = len(line) - len(line.lstrip())
        if literal_indent is not None and (not line.strip() or indent > literal_indent):
            out.append(line)
            continue
        literal_indent = None
        stripped = line.lstrip()
        in_table = stripped.startswith(("+-", "+=")) or (in_table and stripped.startswith("|"))
        if in_table or stripped.startswith(">>>"):
            out.append(line)
            continue
        if stripped.startswith(".. "):  # a directive (.. math::, .. note::): its own markup, content kept
            out.append(line)
            literal_indent = indent
            continue
        head = line[:indent]
        if stripped.startswith("* "):
            head, stripped = line[: indent + 2], stripped[2:]
        parts = _LITERAL.split(stripped)
        text = "".join(p if i % 2 else p.replace("\\", "\\\\").replace("|", "\\|").replace("*", "\\*")
                       for i, p in enumerate(parts))
        out.append(head + text)
        if line.rstrip().endswith("::"):
            literal_indent = indent
    return out


def _process_docstring(app, what, name, obj, options, lines) -> None:
    lines[:] = plain_text_markup(lines)
    if what in ("property", "attribute", "data") and lines:
        # napoleon reads the first line of an attribute's docstring as "type: description"; physar writes
        # "what it is, unit: formula" there. A first line with no colon (an escaped space, which renders as
        # nothing) makes it all description.
        lines.insert(0, "\\ ")


def _module_object(dotted: str):
    """The object at a dotted path (a module, or an attribute of one), or None."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        try:
            for attr in parts[i:]:
                obj = getattr(obj, attr)
        except AttributeError:
            return None
        return obj
    return None


def _existing_private_target(app, env, node, contnode):
    """A Python cross-reference to a physar object that exists but is not in the public API (a private
    helper, a section class of a schema, a submodule) is shown as code, without a link; a reference to
    something that does not exist stays a broken reference (a warning, so an error under ``-W``).

    A name is looked up as written, in the current class and module, in the module of the docstring that
    holds the reference, and in the submodules of the current package (autosummary's summary lines)."""
    if node.get("refdomain") != "py":
        return None
    target = re.sub(r"\s+", "", node.get("reftarget", "")).lstrip("~.")
    module, cls = node.get("py:module") or "", node.get("py:class")
    contexts = [module] if module else []
    if module and cls:
        contexts.insert(0, f"{module}.{cls}")
    holder = re.search(r"docstring of ([\w.]+)", node.source or "")
    if holder:
        parts = holder.group(1).split(".")
        contexts += [".".join(parts[:i]) for i in range(len(parts), 0, -1)]
    contexts += [name for name in sorted(sys.modules) if module and name.startswith(module + ".")]
    for dotted in [target, *(f"{c}.{target}" for c in contexts)]:
        if dotted.startswith("physar") and _module_object(dotted) is not None:
            return contnode
    if node.get("reftype") in ("meth", "attr") and "." not in target:  # a method named without its class
        for c in contexts:
            obj = _module_object(c)
            if isinstance(obj, types.ModuleType) and any(
                    inspect.isclass(v) and v.__module__ == obj.__name__ and hasattr(v, target) for v in vars(obj).values()):
                return contnode
    return None


def _generate(app) -> None:
    write_api_pages(Path(app.srcdir) / "_generated" / "api")
    for name in missing_docstrings():
        logger.warning(f"public name without a docstring: {name}", type="physar", subtype="docstring")


# A summary line of the API tables is a docstring's first sentence; "(seed Eq. 2.9)" is not a sentence's end.
SUMMARY_ABBREVIATIONS = ("Eq.", "Eqs.", "Fig.", "Alg.", "App.", "Sec.", "Ref.")


def summary_line(extract):
    """autosummary's ``extract_summary`` with a first paragraph that leads into an equation (``...:``) ending
    in a full stop, not ``:.``."""
    def summary(doc, document):
        return re.sub(r"\s*[:;,]\.?$", ".", extract(doc, document))
    summary.physar = True
    return summary


def setup(app):
    from sphinx.ext import autosummary

    known = autosummary.WELL_KNOWN_ABBREVIATIONS
    autosummary.WELL_KNOWN_ABBREVIATIONS = (*known, *(a for a in SUMMARY_ABBREVIATIONS if a not in known))
    if not getattr(autosummary.extract_summary, "physar", False):
        autosummary.extract_summary = summary_line(autosummary.extract_summary)
    app.connect("builder-inited", _generate)
    app.connect("autodoc-process-docstring", _process_docstring, priority=400)  # before napoleon
    app.connect("missing-reference", _existing_private_target)
    return {"parallel_read_safe": True, "version": "1"}
