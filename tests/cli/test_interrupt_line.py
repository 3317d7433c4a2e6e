"""A command that has no stop of its own (`physar rom info --check` in the review; here `physar mesh box`)
says that it was interrupted, in one line, exit 130; typer alone turned the KeyboardInterrupt into a silent exit
130 (the reviewer's Ctrl-C after 13 min of `rom info --check` printed nothing). SIGTERM arrives as
KeyboardInterrupt("SIGTERM") (physar.output.sigterm_as_interrupt) and is named as such.

mutant caught: the KeyboardInterrupt branch of user_errors removed (exit 130, no line)."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from physar.cli.main import app


@pytest.mark.parametrize("exc, name", [(KeyboardInterrupt(), "SIGINT"), (KeyboardInterrupt("SIGTERM"), "SIGTERM")])
def test_interrupt_during_work_is_said(monkeypatch, tmp_path, exc, name):
    # `physar mesh box` (no stop of its own, like `rom info --check`), interrupted while it meshes
    import physar.cli.mesh as M

    def stop(*a, **k):
        raise exc

    monkeypatch.setattr(M, "box_mesh", stop)
    r = CliRunner().invoke(app, ["mesh", "box", "--size", "1", "1", "1", "--cells", "1", "1", "1",
                                 "--out", str(tmp_path / "b.vtu")])
    assert r.exit_code == 130, r.output
    lines = [ln for ln in r.output.splitlines() if ln.startswith("interrupted")]
    assert len(lines) == 1 and lines[0].startswith(f"interrupted ({name}): outputs not yet complete were not "
                                                   "written"), r.output
    assert not (tmp_path / "b.vtu").exists()
