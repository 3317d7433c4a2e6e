"""The public API of physar (each package's ``__all__``) and the check that every public name has a docstring.

The rule (docs/api_policy.md): a name in the ``__all__`` of a package of :data:`PACKAGES`, or of a submodule
such a package lists in its ``__all__``, is public and documented; everything else is private.

No Sphinx here: ``tests/test_docs.py`` runs :func:`missing_docstrings` in ``make test``'s environment, and
the docs build (``physar_api``) reports each miss as a warning, an error under ``-W``.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
import types

PACKAGES = ("physar", "physar.geometry", "physar.fem", "physar.integrators", "physar.rom", "physar.assimilation",
            "physar.vision", "physar.ar", "physar.synth", "physar.mpm", "physar.skinning", "physar.gaussians",
            "physar.recon")


def public_names(package: str) -> list[str]:
    """The ``__all__`` of a package (an error if it has none: every package states its public API)."""
    module = importlib.import_module(package)
    if not hasattr(module, "__all__"):
        raise AttributeError(f"{package} has no __all__")
    return list(module.__all__)


def resolve(package: str, name: str):
    """A public name of a package: its attribute, or the submodule of that name (imported on use)."""
    pkg = importlib.import_module(package)
    try:
        return getattr(pkg, name)
    except AttributeError:
        return importlib.import_module(f"{package}.{name}")


def submodules(package: str) -> list[str]:
    """The dotted names of the submodules a package lists in its ``__all__`` (``physar.ar``, ``physar.recon``):
    each documents, and keeps stable, what its own ``__all__`` names."""
    return [resolve(package, n).__name__ for n in public_names(package)
            if isinstance(resolve(package, n), types.ModuleType)]


def public_api() -> dict[str, list[str]]:
    """Every public module of physar (the packages of :data:`PACKAGES` and the submodules they list) and the
    names it exports: its ``__all__``. A module missing from this map is private, whole."""
    api = {}
    for package in PACKAGES:
        api[package] = public_names(package)
        for module in submodules(package):
            api[module] = public_names(module)
    return api


def _members(module: types.ModuleType) -> list[str]:
    """Public names defined in a module that has no ``__all__`` (what autodoc's ``:members:`` shows)."""
    names = getattr(module, "__all__", None)
    if names is not None:
        return list(names)
    return [n for n, obj in vars(module).items() if not n.startswith("_")
            and (inspect.isclass(obj) or inspect.isfunction(obj)) and obj.__module__ == module.__name__]


def data_doc(package: str, name: str) -> str | None:
    """The ``#:`` comment (or string after the assignment) documenting a constant of ``package``, looked up in
    the submodule that defines it."""
    pkg = importlib.import_module(package)
    value = getattr(pkg, name)
    candidates = [package] + [f"{package}.{m.name}" for m in pkgutil.iter_modules(getattr(pkg, "__path__", []))]
    for modname in candidates:
        try:
            module = importlib.import_module(modname)
        except ImportError:
            continue
        if getattr(module, name, object()) is not value:
            continue
        doc = _comment_above(inspect.getsource(module), name)
        if doc:
            return doc
    return None


def _comment_above(source: str, name: str) -> str | None:
    """The ``#:`` comment lines right above the module-level assignment of ``name`` (Sphinx's convention)."""
    lines = source.splitlines()
    for i, line in enumerate(lines):
        if re.match(rf"{re.escape(name)}\s*(:[^=]+)?=", line):
            doc = []
            while i > 0 and lines[i - 1].startswith("#:"):
                i -= 1
                doc.insert(0, lines[i][2:].strip())
            return " ".join(doc) or None
    return None


def _own_doc(obj) -> str | None:
    """The docstring written for ``obj``: a class's own (not inherited), and not the signature that
    ``@dataclass`` and ``namedtuple`` put there when none was written (``Name(field: type, ...)``)."""
    if inspect.isclass(obj):
        doc = obj.__dict__.get("__doc__")
        if doc and re.fullmatch(rf"{re.escape(obj.__name__)}\(.*\)", doc.strip(), re.DOTALL):
            return None
        return doc
    return getattr(obj, "__doc__", None)


def _is_data(obj) -> bool:
    return not (inspect.isclass(obj) or inspect.isroutine(obj) or isinstance(obj, types.ModuleType) or callable(obj))


def missing_docstrings(packages=PACKAGES) -> list[str]:
    """Dotted names of the public API with no docstring (a constant: no ``#:`` comment where it is defined)."""
    missing = []
    for package in packages:
        for name in public_names(package):
            obj = resolve(package, name)
            if isinstance(obj, types.ModuleType):
                if not (obj.__doc__ or "").strip():
                    missing.append(obj.__name__)
                for n in _members(obj):
                    member = getattr(obj, n)
                    documented = data_doc(obj.__name__, n) if _is_data(member) else (_own_doc(member) or "").strip()
                    if not documented:
                        missing.append(f"{obj.__name__}.{n}")
            elif _is_data(obj):
                if name != "__version__" and not data_doc(package, name):
                    missing.append(f"{package}.{name}")
            elif not (_own_doc(obj) or "").strip():
                missing.append(f"{package}.{name}")
    return missing


