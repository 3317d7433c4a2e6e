"""An error or a warning printed while a progress bar is open starts a line of its own (physar.cli._common).

A tqdm bar draws on stderr with carriage returns and no newline; printed as is, `error: ...` ended up after the
bar's last count on the same line, where a user (or a script reading stderr line by line) misses it.
"""
import sys
import warnings

import typer
from tqdm import tqdm
from typer.testing import CliRunner

from physar.cli._common import user_errors
from physar.errors import ConfigError, PhysarWarning


def _app(fail: bool, leave: bool):
    app = typer.Typer()

    @app.command()
    @user_errors
    def run() -> None:
        bar = tqdm(total=10, desc="frames", file=sys.stderr, leave=leave, disable=False)
        bar.update(3)
        warnings.warn(PhysarWarning("frame 3 is dark"), stacklevel=1)
        bar.update(2)
        if fail:
            raise ConfigError("video.mp4: frame 5 is 640x480 but frames 0-4 are 1280x720")
        bar.close()

    @app.command()
    def other() -> None:  # a second command, so that typer keeps `run` as a subcommand
        pass

    return app


def _lines(err: str) -> list[str]:
    """stderr as a terminal shows it: each line's text after its last carriage return."""
    return [ln.rsplit("\r", 1)[-1] for ln in err.split("\n")]


def test_error_while_a_bar_is_open_is_on_its_own_line():
    # mutants caught: the bars not closed before the error (the error follows "5/10" on the bar's line);
    # the warning printed with a plain echo (it follows "3/10" on the bar's line)
    for leave in (False, True):
        r = CliRunner().invoke(_app(True, leave), ["run"])
        assert r.exit_code == 2
        lines = _lines(r.stderr)
        assert "error: video.mp4: frame 5 is 640x480 but frames 0-4 are 1280x720" in lines, r.stderr
        assert "warning: frame 3 is dark" in lines, r.stderr
        assert "Traceback" not in r.stderr


def test_warning_with_a_bar_keeps_the_bar():
    # a warning does not end the bar: it still reaches 5/10 after the warning line
    r = CliRunner().invoke(_app(False, True), ["run"])
    assert r.exit_code == 0
    lines = _lines(r.stderr)
    i = lines.index("warning: frame 3 is dark")
    assert any("5/10" in ln for ln in lines[i:]), r.stderr
