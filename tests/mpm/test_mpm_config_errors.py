"""One-line errors of the MPM scene file: an error of a model-level validator names its table
([[body]] / [[collider]] entry) instead of an empty field; key errors name the dotted key."""

import pytest

from physar.errors import ConfigError
from physar.mpm.scene import load_scene, parse_scene

BODY = {"shape": "box", "min": [0.4, 0.4, 0.4], "max": [0.6, 0.6, 0.6]}


def _error(data) -> str:
    with pytest.raises(ConfigError) as e:
        parse_scene(data, "drop.toml")
    msg = str(e.value)
    assert "\n" not in msg and "field ''" not in msg
    return msg


def test_model_level_body_error_names_the_table(tmp_path):
    assert _error({"body": [BODY, {"shape": "sphere", "center": [0.5, 0.5, 0.2]}]}) == \
        "drop.toml: [body.1] a sphere body needs 'center' and 'radius'"
    p = tmp_path / "scene.toml"
    p.write_text('[[body]]\nshape = "box"\nmin = [0.5, 0.4, 0.4]\nmax = [0.4, 0.6, 0.6]\n')
    with pytest.raises(ConfigError) as e:
        load_scene(p)
    assert str(e.value) == (f"{p}: [body.0] box min (0.5, 0.4, 0.4) must be below max (0.4, 0.6, 0.6) "
                            "in every coordinate")


def test_model_level_collider_error_names_the_table():
    col = {"shape": "capsule", "center": [0.5, 0.5, 0.1]}
    assert _error({"body": [BODY], "collider": [col]}) == "drop.toml: [collider.0] a capsule collider needs 'radius'"


def test_key_errors_name_the_key():
    assert _error({"body": [{**BODY, "E": -1.0}]}).startswith("drop.toml: body.0.E: Input should be greater than 0")
    assert _error({"grid": {"size": 1.0, "res": 8}, "body": [BODY]}) == \
        "drop.toml: unknown key 'res' in [grid] (allowed: size, resolution)"
