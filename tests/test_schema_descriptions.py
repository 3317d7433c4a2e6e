"""Every key of every TOML file physar reads is described, with its unit where it is a physical quantity
(issue 22).

The format pages of the documentation (``docs/_ext/physar_formats.py``) show each key's description and a
unit column read from it; a key without a description is a blank row there and in ``--help``-less TOML
editing. This walk is the check: from the schema classes of every format page it reaches every table
(nested tables, arrays of tables, optional tables and the free-named tables of a model that allows extra
keys, such as ``[schedule.NAME]``) and asserts, naming each key that fails:

* a description that says what the key is (a few words, not a unit alone);
* for a key holding real numbers (a float, a vector, a range), a unit the format page can show: in the
  convention the docs extension parses (``[Pa]``, ``[m/s]``, ``[-]`` for a dimensionless number, or the forms
  ``(m)``, ``, m`` and a key suffix such as ``_mm``, see :func:`physar_formats.unit_text`), or, for a key whose
  unit follows another key (a parameter's range), a description that says which unit.

Integers, strings, booleans and choices need a description only.
"""

from __future__ import annotations

import re
import sys
import typing
from pathlib import Path

import pytest
from pydantic import BaseModel

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "docs" / "_ext"))

import physar_formats as F

# every kind of TOML file physar reads (the camera file of `physar calibrate` is a dataclass, not a schema)
KINDS = {"fem", "rom", "dynamics", "ar_project", "synth_scenario", "mpm_scene", "recon"}


def _models_in(annotation) -> list[type[BaseModel]]:
    """The schema classes a field's type holds: a table, an optional table, an array of tables, a mapping."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for a in typing.get_args(annotation) if a is not Ellipsis for m in _models_in(a)]


def _extra_models(model: type[BaseModel]) -> list[type[BaseModel]]:
    """Tables under free names (``[schedule.NAME]``) of a model with ``extra = "allow"``, from the annotation
    of its ``__pydantic_extra__``."""
    if model.model_config.get("extra") != "allow":
        return []
    return _models_in(typing.get_type_hints(model).get("__pydantic_extra__"))


def _holds_float(annotation) -> bool:
    if annotation is float:
        return True
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return False
    return any(_holds_float(a) for a in typing.get_args(annotation) if a is not Ellipsis)


def schema_models(formats=F.FORMATS) -> dict[type[BaseModel], str]:
    """Every schema class reachable from the format pages' roots -> the TOML path it is first met at."""
    found: dict[type[BaseModel], str] = {}

    def walk(model, kind, path):
        if model in found:
            return
        found[model] = f"{kind}: {path or 'top level'}"
        for key, field in model.model_fields.items():
            for sub in _models_in(field.annotation):
                walk(sub, kind, f"{path}.{key}" if path else key)
        for sub in _extra_models(model):
            walk(sub, kind, f"{path}.NAME" if path else "NAME")

    for fmt in formats:
        for root, class_path in fmt.roots:
            walk(F.load_class(class_path), fmt.name, root)
    return found


_UNIT_ONLY = re.compile(r"\[[^\[\]]*\]|\([^()]*\)")


def problems(model: type[BaseModel], where: str) -> list[str]:
    """What is missing from the descriptions of the keys of one table, one line per key."""
    out = []
    for key, field in model.model_fields.items():
        name = f"{model.__module__}.{model.__qualname__}.{key} ({where})"
        desc = " ".join((field.description or "").split())
        if not desc:
            out.append(f"{name}: no description")
            continue
        words = re.findall(r"[A-Za-z][A-Za-z'-]+", _UNIT_ONLY.sub(" ", desc))
        if len([w for w in words if w not in F._UNITS]) < 2:
            out.append(f"{name}: {desc!r} gives a unit, not what the key is")
        if _holds_float(field.annotation) and not F.unit_text(key, desc) and not re.search(r"\bunits?\b", desc):
            out.append(f"{name}: {desc!r} states no unit (write it as [m], [Pa], [s], ..., or [-] for a "
                       "dimensionless number)")
    return out


def test_every_file_kind_is_walked():
    """Mutant caught: a format page (so its schema) dropped from the walk."""
    assert KINDS <= {f.name for f in F.FORMATS}


def test_every_schema_class_of_physar_is_on_a_format_page():
    """Every pydantic model physar defines (once its schema modules are imported) is reached from a format
    page's root, so the walk below sees it. Mutant caught: a table class that the schemas no longer link
    (or a new kind of file) left out of the documentation and of this check."""
    reached = schema_models()

    def subclasses(cls):
        for sub in cls.__subclasses__():
            yield sub
            yield from subclasses(sub)

    ours = {c for c in subclasses(BaseModel) if c.__module__.startswith("physar.")}
    orphans = sorted(f"{c.__module__}.{c.__qualname__}" for c in ours - set(reached)
                     if not c.__name__.startswith("_") and c.model_fields)
    assert orphans == [], f"pydantic models not reached from docs/_ext/physar_formats.py FORMATS: {orphans}"


def test_every_key_is_described_with_its_unit():
    """Mutant caught: a key added to a schema without a description, with a unit alone as its description,
    or (a real-valued key) without a unit."""
    missing = [line for model, where in schema_models().items() for line in problems(model, where)]
    assert missing == [], f"{len(missing)} keys of the TOML schemas are not described:\n" + "\n".join(missing)


def _probe_model(**fields):
    from pydantic import create_model

    return create_model("Probe", **fields)


@pytest.mark.parametrize("annotation", [float, str, tuple[float, float], float | None, list[int]])
def test_a_field_without_description_is_named(annotation):
    """The check itself: a new key without a description is reported by its class and name."""
    lines = problems(_probe_model(new_key=(annotation, None)), "test")
    assert len(lines) == 1 and "Probe.new_key (test): no description" in lines[0]


def test_unit_rules_of_the_check():
    """A real-valued key needs a unit; [-] says dimensionless; an integer or string key needs none; a unit
    alone is not a description; a unit that follows another key is named in words."""
    from pydantic import Field

    model = _probe_model(
        a=(float, Field(1.0, description="stiffness of the ground")),
        b=(float, Field(1.0, description="Poisson ratio [-]")),
        c=(tuple[float, float], Field((0.0, 1.0), description="range in the parameter's unit")),
        d=(int, Field(1, description="number of frames")),
        e=(float, Field(1.0, description="[m]")),
        f_mm=(float, Field(1.0, description="amplitude of the shake")),
    )
    lines = problems(model, "test")
    assert [line.split(" (")[0] for line in lines] == [
        f"{model.__module__}.Probe.a", f"{model.__module__}.Probe.e"]
    assert "states no unit" in lines[0] and "gives a unit" in lines[1]


def test_walk_reaches_nested_optional_arrays_and_free_named_tables():
    """Mutant caught: a walk that stops at the top level, skips optional tables or arrays of tables, or the
    [schedule.NAME] tables of a model with extra keys."""
    from physar.fem.config import PlaneSelector
    from physar.mpm.scene import ColliderSpec
    from physar.synth.scenario import Pan, Schedule

    reached = schema_models()
    for cls in (PlaneSelector, ColliderSpec, Pan, Schedule):
        assert cls in reached, cls
    assert reached[Schedule] == "synth_scenario: schedule.NAME"
