"""Usage errors of the `physar` command (a missing argument, a value of the wrong type, an unknown option) are
one line naming the command, exit 2, like every other bad input (issue 21); help and --version still exit 0.
Mutant caught: typer's boxed multi-line usage message (the default), or a usage error exiting 0/1."""
import subprocess
import sys
from pathlib import Path

import pytest

PHYSAR = Path(sys.executable).with_name("physar")


@pytest.mark.parametrize("args, text", [
    (["fem", "solve"], "error: physar fem solve: Missing argument 'config'."),
    (["ar", "serve", "p.toml", "--port", "abc"], "error: physar ar serve: Invalid value for '--port'"),
    (["demo", "--bogus"], "error: physar demo: No such option: --bogus"),
])
def test_usage_error_is_one_line(args, text):
    r = subprocess.run([str(PHYSAR), *args], check=False, capture_output=True, text=True, timeout=120)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1 and lines[0].startswith(text), (r.returncode, r.stderr)
    assert r.stdout == ""


@pytest.mark.parametrize("args", [["--version"], ["fem", "solve", "--help"]])
def test_help_and_version_exit_zero(args):
    r = subprocess.run([str(PHYSAR), *args], check=False, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip(), r.stderr
