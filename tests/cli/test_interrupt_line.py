"""A command that has no stop of its own (here `physar rom info --check`, interrupted during its full solves)
says that it was interrupted, in one line, exit 130; typer alone turned the KeyboardInterrupt into a silent exit
130 (the reviewer's Ctrl-C after 13 min of `rom info --check` printed nothing). SIGTERM arrives as
KeyboardInterrupt("SIGTERM") (physar.output.sigterm_as_interrupt) and is named as such.

mutant caught: the KeyboardInterrupt branch of user_errors removed (exit 130, no line)."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from physar.cli.main import app

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("exc, name", [(KeyboardInterrupt(), "SIGINT"), (KeyboardInterrupt("SIGTERM"), "SIGTERM")])
def test_interrupt_during_check_is_said(monkeypatch, exc, name):
    import physar.rom.quality as Q

    def stop(*a, **k):
        raise exc

    monkeypatch.setattr(Q, "discretisation_error", stop)
    d = ROOT / "examples" / "ar" / "cantilever"
    r = CliRunner().invoke(app, ["rom", "info", str(d / "model.npz"), "--check", str(d / "rom.toml")])
    assert r.exit_code == 130, r.output
    lines = [ln for ln in r.output.splitlines() if ln.startswith("interrupted")]
    assert len(lines) == 1 and lines[0].startswith(f"interrupted ({name}): outputs not yet complete were not "
                                                   "written"), r.output
