"""`--help` shows TOML table names such as ``[[parameter]]``, ``[rom]`` and units ``[m]`` literally.

Typer renders help through rich markup, where ``[rom]`` or ``[m]`` is a (silently dropped) style tag unless
escaped as ``\\[rom]``. The reference is the raw help string of each parameter: every bracketed word in it,
with rich's escapes removed, must appear in the rendered help.
"""

import re

import pytest
import typer
from typer.testing import CliRunner

from physar.cli.main import app

runner = CliRunner()


def _leaves(cmd, path=()):
    subs = getattr(cmd, "commands", None)
    if subs is None:
        return [path]
    return [p for name, c in sorted(subs.items()) for p in _leaves(c, (*path, name))]


COMMANDS = _leaves(typer.main.get_command(app))    # every command of `physar`


def _help(*args: str) -> str:
    r = runner.invoke(app, [*args, "--help"], terminal_width=200)
    assert r.exit_code == 0, r.output
    return r.stdout


def test_rom_build_and_simulate_show_table_names():
    # mutants: the unescaped help "… with [[parameter]] tables and [rom]" (rendered "[] tables and") and
    # "… fem tables plus [dynamics]" (rendered "plus")
    out = _help("rom", "build")
    assert "[[parameter]]" in out and "[rom]" in out
    assert "[dynamics]" in _help("simulate")


def _command(path: tuple[str, ...]):
    """The click command of `physar PATH` (typer's own click: groups have `.commands`), or None."""
    cmd = typer.main.get_command(app)
    for name in path:
        cmd = getattr(cmd, "commands", {}).get(name)
        if cmd is None:
            return None
    return cmd


@pytest.mark.parametrize("path", COMMANDS, ids=" ".join)
def test_every_bracketed_word_of_a_parameter_help_is_shown(path):
    # mutant: --noise's "std of the observation noise [m]" unescaped (the unit disappears)
    cmd = _command(path)
    if cmd is None:
        pytest.skip(f"no command {' '.join(path)}")
    out = " ".join(_help(*path).replace("\u2502", " ").split())   # rich's box edges and line wraps removed
    words = set()
    for text in [cmd.help or ""] + [getattr(p, "help", None) or "" for p in cmd.params]:
        words |= {" ".join(w.split()) for w in re.findall(r"\[+[a-z_][^\[\]]*\]+", text.replace("\\[", "["))}
    missing = [w for w in sorted(words) if w not in out]
    assert not missing, f"{missing} missing from `physar {' '.join(path)} --help`"


def test_command_help_paragraphs_are_not_broken_mid_sentence():
    # typer prints the line breaks of a docstring's later paragraphs as they are: `physar simulate --help` showed
    # "A run" alone on a line (review). Every command's help keeps no break before a lower-case word inside a
    # paragraph. mutant caught: the reflow of main.py removed (simulate, synth render, ... fail)
    import inspect
    import re

    from physar.cli.main import app

    def walk(t, path=()):
        for c in t.registered_commands:
            yield (*path, c.name or c.callback.__name__), c.help or inspect.cleandoc(c.callback.__doc__ or "")
        for g in t.registered_groups:
            yield from walk(g.typer_instance, (*path, g.name))

    broken = [(" ".join(p), m.group(0)) for p, h in walk(app) if h
              for m in [re.search(r"[^\n]\n[a-z(]", h)] if m]
    assert not broken, broken
