"""File-format pages generated from the pydantic schemas that validate the files.

Every table of a format page (key, type, default, unit, constraints, description) is read from the
``model_fields`` of the schema classes at build time, so the pages cannot drift from the validators:
change a field in ``physar/fem/config.py`` and the next ``make docs`` shows it. ``FORMATS`` lists the
pages; :func:`format_page` renders one (MyST Markdown) and :func:`write_format_pages` writes them all,
on Sphinx's ``builder-inited`` event. ``tests/test_docs.py`` compares a page's keys with the schema's
JSON schema (an independent walk) and checks that a changed description reaches the page.
"""

from __future__ import annotations

import importlib
import json
import re
import types
import typing
from dataclasses import dataclass
from pathlib import Path

import annotated_types as at
from pydantic import BaseModel


@dataclass(frozen=True)
class Format:
    """One file format: its page name, title, the command that reads it and its schema roots.

    ``roots`` maps a TOML table prefix to a schema class path: ``""`` for a schema that is the whole file,
    ``"synth"`` for one validating the table ``[synth]`` only.
    """

    name: str
    title: str
    command: str
    roots: tuple[tuple[str, str], ...]
    example: str | None = None  # a file of examples/ shown at the end of the page
    intro: str = ""


FORMATS: tuple[Format, ...] = (
    Format("fem", "FEM problem file", "physar fem solve CONFIG.toml --out result.vtu",
           (("", "physar.fem.config.FemConfig"),), "examples/cantilever.toml"),
    Format("rom", "Reduced-model (ROM) build file", "physar rom build CONFIG.toml --out model.npz",
           (("", "physar.rom.config.RomConfig"),), "examples/rom_cantilever.toml",
           "A FEM problem file (its `[[load]]` tables are constant loads) plus `[[parameter]]` tables and `[rom]`."),
    Format("dynamics", "Elastodynamics file", "physar simulate CONFIG.toml --out beam.xdmf",
           (("", "physar.integrators.config.DynamicsConfig"),), "examples/dynamics_cantilever.toml",
           "A FEM problem file plus `[dynamics]`."),
    Format("ar_project", "AR project file", "physar ar run project.toml video.mp4",
           (("", "physar.ar.project.ProjectConfig"),), "examples/ar/bracket/project.toml"),
    Format("synth_scenario", "Synthetic-clip scenario", "physar synth render project.toml --scenario S.toml",
           (("", "physar.synth.scenario.Scenario"),)),
    Format("mpm_scene", "MPM scene", "physar mpm run SCENE.toml --out mpm_out/",
           (("", "physar.mpm.scene.Scene"),), "examples/mpm_two_blocks.toml"),
    Format("recon", "Reconstruction configuration", "physar recon synth|fit --config CONFIG.toml",
           (("synth", "physar.recon.synth.SynthConfig"), ("train", "physar.recon.train.TrainConfig")),
           "examples/recon_tiny.toml",
           "Two tables, `[synth]` (the synthetic scene) and `[train]` (the fit); a file with neither table "
           "is read as one of them at the top level."),
    Format("recon_anny", "Anny two-hand benchmark scene", "python benchmarks/bench_recon_pillow.py --config FILE",
           (("synth", "physar.recon.synth_anny.AnnySceneConfig"),), "examples/recon_anny_cpillow.toml",
           "The `[synth]` table of the anny benchmark scenes (the body squeezing a C-shaped pillow or lifting a "
           "bag, truth with fibres and plasticity), exported as a user's files and read back by "
           "`physar recon import`; `[train]` as in the reconstruction configuration."),
)

# units as they are written in the schemas' descriptions; "-" marks a dimensionless quantity ("[-]")
_UNITS = {"m", "mm", "cm", "m^2", "m^3", "kg/m^3", "Pa", "N", "N/m", "s", "1/s", "1/s^2", "1/m", "1/m^2",
          "m/s", "m/s^2", "px", "px^2", "1/px", "px/m", "deg", "degrees", "rad", "Hz", "fps", "ms", "kg", "J",
          "DN", "sqrt(DN)", "-"}
_SUFFIX_UNITS = {"_mm": "mm", "_deg": "deg", "_px": "px", "_ms": "ms", "_s": "s", "_hz": "Hz"}
_SPECIAL = re.compile(r"([\\`*_\[\]{}<>()#+!|$~])")


def load_class(path: str) -> type[BaseModel]:
    """The class at a dotted path ``package.module.Class``."""
    module, _, name = path.rpartition(".")
    return getattr(importlib.import_module(module), name)


def escape(text: str) -> str:
    """Plain text made literal in MyST Markdown (a backslash before every markup character); `code` spans,
    which the schemas' descriptions use for commands and keys, stay code, and so do reST roles
    (``:mod:`x```) and literals of the docstrings."""
    text = re.sub(r"(?::[a-z]+)+:`~?([^`]+)`", r"`\1`", " ".join(text.split()))  # reST roles and ``x`` -> `x`
    text = re.sub(r"``([^`]+)``", r"`\1`", text)
    parts = re.split(r"(`[^`|]+`)", text)
    return "".join(p if i % 2 else _SPECIAL.sub(r"\\\1", p) for i, p in enumerate(parts))


def _model_in(annotation) -> tuple[type[BaseModel] | None, bool]:
    """(schema class, is an array of tables) of a field holding a sub-table, else (None, False)."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation, False
    if origin is typing.Annotated:
        return _model_in(args[0])
    if origin in (typing.Union, types.UnionType):
        for a in args:
            model, many = _model_in(a)
            if model is not None:
                return model, many
    if origin in (list, tuple) and args:
        model, _ = _model_in(args[0])
        if model is not None:
            return model, True
    return None, False


def type_name(annotation) -> str:
    """A field type in TOML words: ``float``, ``[float, float, float]``, ``"P1" | "P2"``, ``table``."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Annotated:
        return type_name(args[0])
    if origin in (typing.Union, types.UnionType):
        return " | ".join(type_name(a) for a in args if a is not type(None))
    if origin is typing.Literal:
        return " | ".join(json.dumps(a) for a in args)
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"[{type_name(args[0])}, ...]"
        return "[" + ", ".join(type_name(a) for a in args) + "]"
    if origin is list:
        return f"[{type_name(args[0])}, ...]" if args else "array"
    if origin is dict:
        return "table"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "table"
    return {bool: "boolean", int: "integer", float: "float", str: "string", Path: "string"}.get(
        annotation, getattr(annotation, "__name__", str(annotation)))


def _toml(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, tuple | list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def default_text(field) -> str:
    """The default as TOML (``required`` when there is none, ``—`` for an unset optional value)."""
    if field.is_required():
        return "required"
    value = field.get_default(call_default_factory=True)
    if value is None:
        return "—"
    if isinstance(value, BaseModel):
        return "its defaults"
    if isinstance(value, list) and not value:
        return "none"
    return f"`{_toml(value)}`"


def constraints_text(field) -> str:
    """Bounds of a field from its pydantic metadata: ``> 0``, ``≥ 3, ≤ 2001``, ``1 to 4 entries``."""
    out = []
    for m in field.metadata:
        for cls, attr, sym in ((at.Gt, "gt", ">"), (at.Ge, "ge", "≥"), (at.Lt, "lt", "<"), (at.Le, "le", "≤")):
            if isinstance(m, cls):
                out.append(f"{sym} {_toml(getattr(m, attr))}")
        if isinstance(m, at.MinLen):
            out.append(f"≥ {m.min_length} entries")
        if isinstance(m, at.MaxLen):
            out.append(f"≤ {m.max_length} entries")
    return ", ".join(out)


def unit_text(key: str, description: str) -> str:
    """The SI (or stated) unit of a field, as its description or name gives it; ``""`` if none is stated.

    Units in brackets come first, all of them in order (``t [s], x, y, z [m]`` -> ``s, m``; ``[-]``: a
    dimensionless quantity), then the other spellings the schemas use (``(m)``, a leading or a trailing ``, m``).
    """
    bracketed = []
    for m in re.finditer(r"\[([^\[\]]+)\]", description):
        unit = m.group(1).strip()
        if unit in _UNITS and unit not in bracketed:
            bracketed.append(unit)
    if bracketed:
        return ", ".join(bracketed)
    for pattern in (r"\(([^()]+)\)", r"^([^\s,;(]+)(?:$|[,;]|\s\()", r",\s*([^\s,;()]+)\s*$",
                    r"^([A-Za-z/^0-9]+)\s"):
        for m in re.finditer(pattern, description):
            unit = m.group(1).strip()
            if unit in _UNITS:
                return unit
    for suffix, unit in _SUFFIX_UNITS.items():
        if key.lower().endswith(suffix):
            return unit
    return ""


def _doc(model: type[BaseModel]) -> str:
    doc = model.__dict__.get("__doc__")
    return " ".join(doc.split()) if doc else ""


def extra_table(model: type[BaseModel]) -> type[BaseModel] | None:
    """The schema of the tables a model takes under names of the user's choice (``[schedule.NAME]``): the
    value type of its ``__pydantic_extra__`` when it allows extra keys, else None."""
    if model.model_config.get("extra") != "allow":
        return None
    args = typing.get_args(typing.get_type_hints(model).get("__pydantic_extra__"))
    return _model_in(args[-1])[0] if args else None


def tables(prefix: str, model: type[BaseModel], many: bool = False, required: bool = True):
    """Yield ``(heading, model, many, required)`` for the table of ``model`` and its sub-tables, depth first.

    The heading is the table's TOML name: ``[mesh]``, ``[[fix]]``, ``[[fix]].plane``; ``""`` is the top level.
    Tables under names of the user's choice come last, as ``NAME`` (``[schedule].NAME``).
    """
    yield prefix, model, many, required
    for key, field in model.model_fields.items():
        sub, sub_many = _model_in(field.annotation)
        if sub is not None:
            yield from tables(f"{prefix}.{key}" if prefix else key, sub, sub_many, field.is_required())
    extra = extra_table(model)
    if extra is not None:
        yield from tables(f"{prefix}.NAME" if prefix else "NAME", extra, False, False)


def heading(path: str, many: bool) -> str:
    """TOML spelling of a table path: ``mesh`` -> ``[mesh]``; ``fix``, an array, -> ``[[fix]]`` (and
    ``[[fix]].plane`` for its sub-table; ``many`` says whether the first part is an array of tables)."""
    if not path:
        return "top level"
    head, _, rest = path.partition(".")
    return (f"[[{head}]]" if many else f"[{head}]") + (f".{rest}" if rest else "")


def format_page(fmt: Format, repo: Path | None = None) -> str:
    """The MyST Markdown page of one format, every table read from the schema classes."""
    lines = [f"# {fmt.title}", "", f"Read by `{fmt.command}`.", ""]
    if fmt.intro:
        lines += [fmt.intro, ""]
    classes = ", ".join(f"`{path}`" for _, path in fmt.roots)
    lines += [(f"Generated from the schema {classes} at build time: the tables below are the validator's "
              "fields. A key that is not listed is an error, and so is a value of the wrong type. A string "
              "is never read as a number."), ""]
    many_of: dict[str, bool] = {}
    for root, path in fmt.roots:
        for table, model, many, required in tables(root, load_class(path)):
            head, _, _ = table.partition(".")
            if "." not in table:
                many_of[head] = many
            name = heading(table, many_of.get(head, False))
            kind = "array of tables, repeatable" if many else ("table" if table else "")
            state = ("required" if required else "optional") if table else ""
            label = ", ".join(x for x in (kind, state) if x)
            lines += [f"({_label(fmt, table)})=", f"## `{name}`" if table else "## Top level", ""]
            if label:
                lines += [f"*{label}*", ""]
            if _doc(model):
                lines += [escape(_doc(model)), ""]
            lines += _field_table(model, fmt, table)
    if fmt.example and repo is not None and (repo / fmt.example).exists():
        lines += ["## Example", "", f"`{fmt.example}`:", "", "```toml", (repo / fmt.example).read_text().rstrip(),
                  "```", ""]
    return "\n".join(lines)


def _label(fmt: Format, table: str) -> str:
    """The cross-reference target of a table's section: ``format-fem-fix.plane``."""
    return f"format-{fmt.name}-{table or 'top'}"


def _field_table(model: type[BaseModel], fmt: Format, table: str) -> list[str]:
    rows = ["| key | type | default | unit | constraints | description |", "|---|---|---|---|---|---|"]
    for key, field in model.model_fields.items():
        sub, many = _model_in(field.annotation)
        desc = field.description or ""
        if sub is None:
            kind = "`" + type_name(field.annotation).replace("|", "\\|") + "`"
        else:  # a link to the sub-table's section, described by its class docstring unless the field says more
            kind = f"{{ref}}`{'array of tables' if many else 'table'} <{_label(fmt, f'{table}.{key}' if table else key)}>`"
            desc = desc or _doc(sub).split(". ")[0].rstrip(".")
        cells = [f"`{key}`", kind, default_text(field), unit_text(key, desc), constraints_text(field), escape(desc)]
        rows.append("| " + " | ".join(cells) + " |")
    return rows + [""]


def write_if_changed(path: Path, text: str) -> None:
    """Write ``text`` unless the file already holds it (keeps Sphinx's incremental build incremental)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.exists() or path.read_text() != text:
        path.write_text(text)


def index_page(formats=FORMATS) -> str:
    """The index of the format pages."""
    lines = ["# File formats", "",
             ("Every file physar reads is TOML validated by a pydantic schema; these pages are generated from "
             "those schemas when the documentation is built. Units are SI unless a key's name or description "
             "says otherwise; `-` in the unit column marks a dimensionless number."),
             "", "| file | read by |", "|---|---|"]
    lines += [f"| [{f.title}]({f.name}.md) | `{f.command.replace('|', chr(92) + '|')}` |" for f in formats]
    lines += ["", "```{toctree}", ":hidden:", "", *(f.name for f in formats), "```", ""]
    return "\n".join(lines)


def write_format_pages(out_dir: Path, repo: Path, formats=FORMATS) -> list[Path]:
    """Write ``index.md`` and one page per format into ``out_dir``; return the page paths."""
    pages = []
    for fmt in formats:
        pages.append(out_dir / f"{fmt.name}.md")
        write_if_changed(pages[-1], format_page(fmt, repo))
    write_if_changed(out_dir / "index.md", index_page(formats))
    return pages


def _generate(app) -> None:
    src = Path(app.srcdir)
    write_format_pages(src / "_generated" / "formats", src.parent)


def setup(app):
    app.connect("builder-inited", _generate)
    return {"parallel_read_safe": True, "version": "1"}
