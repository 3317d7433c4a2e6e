"""The stale-model refusal of an AR project (`[model] file` not built from `[model] config` as it is now) tells
the user to run commands that exist. It named `physar ar build`, which `physar ar --help` does not list.

Reference: the command tree of the `physar` click application (what `physar ... --help` lists), not the message's
own text. Mutant caught: the message naming `physar ar build` (or any other command that does not exist).
"""
import re
import types

import pytest
import typer

from physar.ar.project import load_model
from physar.cli.main import app
from physar.errors import ConfigError


def _resolves(words: list[str]) -> bool:
    """Whether `physar WORDS...` names a leaf command of the CLI (every word a subcommand of the previous)."""
    cmd = typer.main.get_command(app)
    for w in words:
        sub = getattr(cmd, "commands", None)  # a group (typer's may not subclass click.Group)
        if sub is None or w not in sub:
            return False
        cmd = sub[w]
    return getattr(cmd, "commands", None) is None


def test_stale_model_message_names_existing_commands(tmp_path, monkeypatch):
    import physar.rom

    (tmp_path / "rom.toml").write_text("[mesh]\nbox = [1, 1, 1]\n")
    (tmp_path / "model.npz").write_bytes(b"stands for a model built from another rom.toml")
    monkeypatch.setattr(physar.rom.SeparatedModel, "load",
                        staticmethod(lambda path: types.SimpleNamespace(metadata={"config_sha256": "another"})))
    cfg = types.SimpleNamespace(_base_dir=tmp_path, model=types.SimpleNamespace(file="model.npz", config="rom.toml"))
    with pytest.raises(ConfigError, match="was not built from 'rom.toml'") as exc:
        load_model(cfg, "project.toml", build=False)
    commands = re.findall(r"`physar ([a-z -]+)`", str(exc.value))
    assert commands, str(exc.value)
    for c in commands:
        assert _resolves(c.split()), f"`physar {c}` is not a command: {exc.value}"
    assert not _resolves(["ar", "build"])  # the reference itself tells the old message apart
