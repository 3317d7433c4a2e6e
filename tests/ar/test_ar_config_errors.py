"""One-line errors of the AR scene files (cantilever, foam, seal): an error of a model-level validator
names its table, or the top level for a check across tables, instead of an empty field."""

import pytest

from physar.ar.foam import load_foam_scene
from physar.ar.scene import load_scene
from physar.ar.seal import load_seal_scene
from physar.errors import ConfigError


def _error(load, path, text) -> str:
    path.write_text(text)
    with pytest.raises(ConfigError) as e:
        load(path)
    msg = str(e.value)
    assert "\n" not in msg and "field ''" not in msg and not msg.startswith(f"{path}: :")
    return msg


def test_model_level_error_of_a_table_names_it(tmp_path):
    p = tmp_path / "scene.toml"
    assert _error(load_scene, p, "[markers]\nids = [0, 1]\ncentres = [[0.1, 0.1]]\n") == \
        f"{p}: [markers] ids (2) and centres (1) differ in length"


def test_model_level_errors_across_tables_name_the_top_level(tmp_path):
    p = tmp_path / "scene.toml"
    assert _error(load_scene, p, "[beam]\nlength = 0.5\n[load]\npositions = [0.2, 0.7]\n") == \
        f"{p}: [top level] load positions [0.7] lie outside the beam [0, 0.5] m"
    assert _error(load_foam_scene, p, "[load]\npositions = [0.01]\n").startswith(
        f"{p}: [top level] load positions [0.01] lie outside the load range")
    assert _error(load_seal_scene, p, "keyframes = [[0.0, 0.0], [1.0, 500.0]]\n").startswith(
        f"{p}: [top level] keyframe angles [0.0, 500.0] must lie in [0, ")


def test_key_errors_name_the_key(tmp_path):
    p = tmp_path / "scene.toml"
    assert _error(load_scene, p, "[beam]\nlength = -1\n").startswith(f"{p}: beam.length: Input should be greater")
    assert _error(load_scene, p, "[video]\nfsp = 30\n").startswith(f"{p}: unknown key 'fsp' in [video] (allowed: ")
