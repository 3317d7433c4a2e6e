"""User-facing errors.

Every error that a user can cause (bad file, bad config value, bad mesh, ill-posed problem) is raised
as a :class:`PhysarError` with a one-line message naming the problem; the CLI prints that line and exits
with code 2. Anything else is a bug.
"""


import types
import typing


class PhysarError(Exception):
    """An error caused by the input (file, field, value), with a message a user can act on."""


class ConfigError(PhysarError, ValueError):
    """A configuration file or value is invalid."""


class MeshError(PhysarError, ValueError):
    """A mesh is invalid (NaN coordinates, degenerate or inverted elements, bad connectivity)."""


class SolverError(PhysarError, RuntimeError):
    """A solve failed for a reason the user can fix (singular system, divergence)."""


class PhysarWarning(UserWarning):
    """A result that ran to the end but should not be trusted as it is (e.g. a calibration with a large
    reprojection error); the CLI prints it as one ``warning:`` line on stderr."""


def format_validation_error(exc, source: str, model=None, section: str | None = None, data=None) -> str:
    """One line naming the file, the table/key and the problem of a pydantic ``ValidationError``.

    ``source`` is the file (or a name for the input); ``model`` the validated pydantic model class (for
    the keys allowed in a table); ``section`` the TOML table the validated data came from when only that
    table was validated (e.g. ``"train"``), so that locations are named inside it. An error raised by a
    model-level validator (``@model_validator``) names its table, e.g.
    ``run.toml: [train] nu_min (0.45) must be < nu_max (0.4)``; one of the file's top level names
    ``[top level]``. Shared by the config loaders of every layer (pydantic is duck-typed here).

    A table of an array of tables (``[[parameter]]``, ``[[load]]``, ``[[marker]]``...) is named as the file
    names it, by its ``name`` (``[[parameter]] 's'``), else its integer ``id`` (``[[marker]] id 7``), else its
    position (``[[load]] table 2``, 1-based; :func:`table_label`), read from ``data`` (the validated dict), e.g.
    ``rom.toml: [[parameter]] 's': radius: Input should be greater than 0 (got -1)``.
    """
    e = exc.errors()[0]
    inner = [str(p) for p in e["loc"]]
    aot = _array_table(e["loc"], data)
    if aot is not None:
        return _format_in_table(e, source, model, inner, aot, data, section)
    loc = ([section] if section else []) + inner
    where = ".".join(loc) if loc else "top level"
    table = ".".join(p for p in loc[:-1] if not p.isdigit()) or "top level"
    kind = e["type"]
    if kind == "extra_forbidden":
        return f"{source}: unknown key {loc[-1]!r} in [{table}]{_allowed_hint(model, inner[:-1])}"
    if kind == "missing" and e["loc"] and isinstance(e["loc"][-1], int):  # a tuple given too few values
        return (f"{source}: [{'.'.join(loc[:-1])}] expected {_values_wanted(model, e, inner)} values, "
                f"got {e.get('input')!r}")
    if kind == "missing":
        return f"{source}: missing key {loc[-1]!r} in [{table}]"
    if kind == "literal_error":
        return f"{source}: {where} = {e.get('input')!r} is not allowed; {e['msg'][:1].lower() + e['msg'][1:]}"
    msg = e["msg"].removeprefix("Value error, ").removeprefix("Assertion failed, ")
    if kind in ("value_error", "assertion_error"):
        return f"{source}: [{where}] {msg}"
    return f"{source}: {where}: {msg} (got {e.get('input')!r})"


def table_label(data, path) -> str:
    """How messages name the table at ``path`` (keys and list indices, ending with the index) of an array of
    tables in ``data``: ``[[key]] 'name'``, ``[[key]] id N`` or ``[[key]] table K`` (1-based)."""
    item = data
    for p in path:
        try:
            item = item[p]
        except (KeyError, IndexError, TypeError):
            item = None
            break
    key = ".".join(str(p) for p in path[:-1] if not isinstance(p, int))
    if isinstance(item, dict):
        name, ident = item.get("name"), item.get("id")
        if isinstance(name, str) and name:
            return f"[[{key}]] {name!r}"
        if isinstance(ident, int) and not isinstance(ident, bool):
            return f"[[{key}]] id {ident}"
    return f"[[{key}]] table {int(path[-1]) + 1}"


def _array_table(loc, data) -> int | None:
    """Index in ``loc`` of the last list index that selects a table (a dict in ``data``), None if none."""
    if data is None:
        return None
    item, found = data, None
    for j, p in enumerate(loc):
        try:
            item = item[p]
        except (KeyError, IndexError, TypeError):
            break
        if isinstance(p, int) and isinstance(item, dict):
            found = j
    return found


def _format_in_table(e, source: str, model, inner: list[str], j: int, data, section: str | None = None) -> str:
    """The message of :func:`format_validation_error` for an error inside the array-of-tables item ``loc[:j+1]``
    (``section``: the table ``data`` came from)."""
    label = table_label(data, list(e["loc"][:j + 1]))
    if section:
        label = label.replace("[[", f"[[{section}.", 1)
    tail = inner[j + 1:]
    kind = e["type"]
    within = label + "".join(f".{t}" for t in tail[:-1])          # the (sub)table holding the key
    if kind == "extra_forbidden":
        return f"{source}: unknown key {tail[-1]!r} in {within}{_allowed_hint(model, inner[:-1])}"
    if kind == "missing" and e["loc"] and isinstance(e["loc"][-1], int):
        return (f"{source}: {label}: {'.'.join(tail[:-1])}: expected {_values_wanted(model, e, inner)} values, "
                f"got {e.get('input')!r}")
    if kind == "missing":
        return f"{source}: missing key {tail[-1]!r} in {within}"
    key = ".".join(tail)
    if kind == "literal_error":
        return f"{source}: {label}: {key} = {e.get('input')!r} is not allowed; {e['msg'][:1].lower() + e['msg'][1:]}"
    msg = e["msg"].removeprefix("Value error, ").removeprefix("Assertion failed, ")
    named = key and msg.startswith((f"{tail[-1]} ", f"{tail[-1]}:"))   # the message names its key itself
    head = f"{source}: {label}: " + (f"{key}: " if key and not named else "")
    if kind in ("value_error", "assertion_error"):
        return head + msg
    return head + f"{msg} (got {e.get('input')!r})"


def _allowed_hint(model, path: list[str]) -> str:
    """`` (allowed: a, b, ...)`` for the table at ``path`` of ``model``, or ""."""
    allowed = _allowed_keys(model, path) if model is not None else []
    return f" (allowed: {', '.join(allowed)})" if allowed else ""


def _values_wanted(model, e, inner: list[str]) -> str:
    """How many values the tuple of a ``missing`` error at a tuple index wants: "3", else "at least k"."""
    n = _tuple_length(model, inner[:-1]) if model is not None else None
    return f"{n}" if n else f"at least {e['loc'][-1] + 1}"


def _allowed_keys(model, path: list[str]) -> list[str]:
    """Field names of the (nested) pydantic model at table ``path`` of ``model``; [] if not a table."""
    cur = model
    for p in path:
        if p.isdigit():
            continue
        field_ = cur.model_fields.get(p)
        if field_ is None:
            return []
        ann = field_.annotation
        cand = [a for a in (ann, *_type_args(ann)) if isinstance(a, type) and hasattr(a, "model_fields")]
        if not cand:
            return []
        cur = cand[0]
    return list(cur.model_fields)


def _tuple_length(model, path: list[str]) -> int | None:
    """The length of the fixed-size tuple at ``path`` of ``model`` (a field ``Vec3``, or an item of a
    ``list[Vec3]`` field: 3), None if it is not one."""
    ann = model
    for p in path:
        if p.isdigit():  # an item of a list (or of a tuple of tuples)
            args = [a for a in getattr(ann, "__args__", ()) if a is not Ellipsis]
            if getattr(ann, "__origin__", None) in (list, tuple) and args:
                ann = args[min(int(p), len(args) - 1)] if getattr(ann, "__origin__", None) is tuple else args[0]
                continue
            cand = [a for a in _type_args(ann) if getattr(a, "__origin__", None) in (list, tuple)]
            if not cand:
                return None
            ann = next(a for a in cand[0].__args__ if a is not Ellipsis)
            continue
        models = [a for a in (ann, *_type_args(ann)) if isinstance(a, type) and hasattr(a, "model_fields")]
        if not models or p not in models[0].model_fields:
            return None
        ann = models[0].model_fields[p].annotation
    for a in (ann, *getattr(ann, "__args__", ())):
        args = getattr(a, "__args__", ())
        if getattr(a, "__origin__", None) is tuple and args and Ellipsis not in args:
            return len(args)
    return None


def _type_args(ann) -> tuple:
    """Type arguments of ``ann``, one level of nesting included (``list[Model] | None`` -> Model)."""
    args = getattr(ann, "__args__", ())
    return (*args, *(b for a in args for b in getattr(a, "__args__", ())))


def refuse_coercion(value, annotation):
    """``value`` unchanged, or ValueError when pydantic would silently coerce it into ``annotation``.

    Config files are TOML, whose numbers, booleans and strings are distinct types; pydantic's lax mode reads
    ``E = true`` as 1.0 and ``E = "69e9"`` or ``cells = ["40", 2, 2]`` as numbers. A number field (int or
    float, also inside tuples, lists, dicts and unions) refuses a boolean or a string, and a bool field
    refuses anything but true/false. Used as a ``field_validator("*", mode="before")`` of the config models
    (their ``_Strict`` base); the message becomes ``file: [table.key] ...`` (:func:`format_validation_error`).
    """
    msg = _coercion(value, annotation)
    if msg is not None:
        raise ValueError(msg)
    return value


def _coercion(value, ann) -> str | None:
    origin, args = typing.get_origin(ann), typing.get_args(ann)
    if origin is typing.Annotated:
        return _coercion(value, args[0])
    if origin in (typing.Union, types.UnionType):
        found = [_coercion(value, a) for a in args if a is not type(None) or value is None]
        return None if not found or any(f is None for f in found) else found[0]
    if origin in (list, tuple, set, frozenset) and isinstance(value, (list, tuple)):
        if origin is tuple and args and args[-1] is not Ellipsis:
            pairs = zip(value, args)
        else:
            pairs = ((v, args[0] if args else typing.Any) for v in value)
        return next((m for v, a in pairs if (m := _coercion(v, a)) is not None), None)
    if origin is dict and isinstance(value, dict) and len(args) == 2:
        return next((m for v in value.values() if (m := _coercion(v, args[1])) is not None), None)
    if ann in (int, float):
        kind = "an integer" if ann is int else "a number"
        if isinstance(value, bool):
            return f"expected {kind}, got {str(value).lower()} (a boolean)"
        if isinstance(value, str):
            return f"expected {kind}, got the string {value!r} (write it without quotes)"
    if ann is bool and not isinstance(value, bool):
        return f"expected true or false, got {value!r}"
    return None


__all__ = ["ConfigError", "MeshError", "PhysarError", "PhysarWarning", "SolverError"]
