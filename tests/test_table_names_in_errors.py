"""A table of an array of tables is named one way in every config error, as the file shows it: ``[[key]] 'name'``,
``[[key]] id N`` or ``[[key]] table K`` (1-based), never pydantic's ``parameter.0.radius`` / ``[parameter.0]``
(a review found both forms for the same table). Through the real loaders of three layers (fem/rom problem
files, MPM scenes, AR projects).

Mutants (tried, caught): positions 0-based ("table 0"), the name ignored (every table by position), the key left
in the line when the validator's message already starts with it ("points: points = ...")."""
import pytest

from physar.ar.project import TEMPLATE, parse_project
from physar.errors import ConfigError
from physar.fem.config import parse_config
from physar.mpm.scene import parse_scene
from physar.rom.config import RomConfig

BASE = {"mesh": {"box": [0.1, 0.02, 0.02], "cells": [4, 1, 1]}, "material": {"model": "linear", "E": 1e9, "nu": 0.3},
        "fix": [{"plane": {"point": [0, 0, 0], "normal": [1, 0, 0]}}]}
PARAM = {"name": "s", "kind": "load_position", "path": [[0.02, 0, 0.02], [0.1, 0, 0.02]], "points": 5,
         "load": [0, 0, -1.0]}


def _rom_error(**change):
    return str(pytest.raises(ConfigError, parse_config, {**BASE, "parameter": [{**PARAM, **change}], "rom": {}},
                             "r.toml", RomConfig).value)


@pytest.mark.parametrize("change, message", [
    ({"radius": -1.0}, "r.toml: [[parameter]] 's': radius: Input should be greater than 0 (got -1.0)"),
    ({"points": "x"}, ("r.toml: [[parameter]] 's': points = 'x' is not an integer from 3 to 2001 (the grid of "
                      "parameter 's')")),
    ({"colour": 1}, "r.toml: unknown key 'colour' in [[parameter]] 's'"),
    ({"kind": "speed"}, "r.toml: [[parameter]] 's': kind = 'speed' is not allowed;"),
])
def test_rom_parameter_named_by_its_name(change, message):
    assert _rom_error(**change).startswith(message)


def test_fem_tables_without_name_by_position():
    loads = [{"type": "point", "point": [0.1, 0.01, 0.01], "radius": 0.005, "total": [0, 0, -1.0]},
             {"type": "point", "point": [0.1, 0.01, 0.01], "radius": 0.005, "total": [0, 0, float("nan")]}]
    msg = str(pytest.raises(ConfigError, parse_config, {**BASE, "load": loads}, "c.toml").value)
    assert msg == "c.toml: [[load]] table 2: total.2: Input should be a finite number (got nan)"
    fixes = [BASE["fix"][0], {"components": ["x"]}]
    msg = str(pytest.raises(ConfigError, parse_config, {**BASE, "fix": fixes}, "c.toml").value)
    assert msg == "c.toml: [[fix]] table 2: a fix needs one of box, region, points, plane"
    probe = [{"point": [0.1, 0.01]}]
    msg = str(pytest.raises(ConfigError, parse_config, {**BASE, "probe": probe}, "c.toml").value)
    assert msg == "c.toml: [[probe]] table 1: point: expected 3 values, got [0.1, 0.01]"


def test_mpm_body_and_ar_marker():
    body = {"shape": "box", "min": [0.4, 0.4, 0.4], "max": [0.6, 0.6, 0.6]}
    msg = str(pytest.raises(ConfigError, parse_scene, {"body": [body, {**body, "E": -1.0}]}, "drop.toml").value)
    assert msg.startswith("drop.toml: [[body]] table 2: E: Input should be greater than 0")
    named = {**body, "name": "lid"}
    msg = str(pytest.raises(ConfigError, parse_scene, {"body": [body, {**named, "E": -1.0}]}, "drop.toml").value)
    assert msg.startswith("drop.toml: [[body]] 'lid': E: Input should be greater than 0"), msg
    import tomllib

    data = tomllib.loads(TEMPLATE)
    data["marker"][0]["size"] = -0.04
    msg = str(pytest.raises(ConfigError, parse_project, data, "p.toml").value)
    assert msg.startswith(f"p.toml: [[marker]] id {data['marker'][0]['id']}: size: "), msg
