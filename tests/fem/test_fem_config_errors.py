"""One-line config errors of the FEM problem file: an error of a model-level validator names its table
(not an empty field), errors of a key name the dotted key, unknown keys the table and what is allowed."""

import pytest
from pydantic import model_validator

from physar.errors import ConfigError
from physar.fem.config import FemConfig, parse_config

BASE = {"mesh": {"box": [1.0, 0.1, 0.1], "cells": [4, 1, 1]}, "material": {"model": "linear", "E": 1e6, "nu": 0.3}}


def _error(data, model=FemConfig) -> str:
    with pytest.raises(ConfigError) as e:
        parse_config(data, "beam.toml", model)
    msg = str(e.value)
    assert "\n" not in msg and "field ''" not in msg
    return msg


def test_model_level_error_names_its_table():
    assert _error({**BASE, "mesh": {"box": [1.0, 0.1, 0.1]}}) == "beam.toml: [mesh] box needs cells = [nx, ny, nz]"


def test_model_level_error_in_an_array_of_tables_names_the_entry():
    load = [{"type": "point", "total": [0, 0, -1.0], "point": [1.0, 0.05, 0.1], "radius": 0.01},
            {"type": "traction", "total": [0, 0, -1.0]}]
    assert _error({**BASE, "load": load}) == "beam.toml: [[load]] table 2: a traction load needs one of box, region, points, plane"


def test_model_level_error_of_the_whole_file_names_the_top_level():
    class Checked(FemConfig):
        @model_validator(mode="after")
        def _one_load(self):
            if len(self.load) != 1:
                raise ValueError(f"exactly one [[load]] table, got {len(self.load)}")
            return self

    assert _error(BASE, Checked) == "beam.toml: [top level] exactly one [[load]] table, got 0"


def test_key_errors_name_the_key():
    msg = _error({**BASE, "solver": {"steps": 0}})
    assert msg.startswith("beam.toml: solver.steps: ") and msg.endswith("(got 0)")
    assert _error({**BASE, "solver": {"stpes": 2}}) == ("beam.toml: unknown key 'stpes' in [solver] "
                                                        "(allowed: steps, tol, max_iter, linear)")
    assert _error({"mesh": BASE["mesh"]}) == "beam.toml: missing key 'material' in [top level]"


def test_read_toml_folder_binary_and_unreadable(tmp_path):
    """Every TOML a file points to (a project's [model] config, a scenario...) is read by read_toml: a folder,
    a binary file or an unreadable file is one ConfigError line naming it, not a traceback (issue 21).
    Mutant caught: read_text without the checks (IsADirectoryError / UnicodeDecodeError escape)."""
    import os

    from physar.errors import ConfigError
    from physar.fem.config import read_toml

    d = tmp_path / "rom.toml"
    d.mkdir()
    b = tmp_path / "bin.toml"
    b.write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff\xfe")
    u = tmp_path / "locked.toml"
    u.write_text("a = 1\n")
    os.chmod(u, 0)
    cases = [(d, "is a folder"), (b, "not a TOML file (byte")]
    if os.geteuid() != 0:      # root reads anything
        cases.append((u, "cannot read"))
    for path, text in cases:
        with pytest.raises(ConfigError) as e:
            read_toml(path)
        msg = str(e.value)
        assert str(path) in msg and text in msg and "\n" not in msg
