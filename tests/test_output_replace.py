"""A destination that cannot be replaced (an immutable or another user's file in a sticky folder: os.replace
fails) is one ConfigError line naming it, the temporary removed and the old file kept; before, a
PermissionError traceback (exit 1). The failure is simulated by os.replace raising what Linux raises (EPERM).

mutant caught: os.replace called bare in atomic_path (PermissionError escapes)."""

from __future__ import annotations

import errno
import os

import pytest

from physar.errors import ConfigError
from physar.output import atomic_write_text


def test_unreplaceable_destination_is_one_line(tmp_path, monkeypatch):
    dst = tmp_path / "t.csv"
    dst.write_text("keep\n")

    def deny(src, d):
        raise PermissionError(errno.EPERM, os.strerror(errno.EPERM), str(src), None, str(d))

    monkeypatch.setattr(os, "replace", deny)
    with pytest.raises(ConfigError) as e:
        atomic_write_text(dst, "new\n")
    assert str(e.value).startswith(f"{dst}: cannot be replaced (Operation not permitted)"), str(e.value)
    assert dst.read_text() == "keep\n" and sorted(p.name for p in tmp_path.iterdir()) == ["t.csv"]


# The default side outputs (not named on the command line) never replace a user's file: denoise's OUT.png and
# simulate's OUT.csv. An earlier output of the same command is replaced. mutants caught: replaces not passed
# (model_clean.png / notes.csv overwritten), the PNG mark not written by save_figure (the second run refused)
def test_default_side_outputs_keep_users_files(tmp_path):
    import trimesh
    from PIL import Image
    from typer.testing import CliRunner

    from physar.cli.main import app

    run = CliRunner().invoke
    ico = trimesh.creation.icosphere(subdivisions=2)
    ico.export(tmp_path / "in.ply")
    Image.new("RGB", (4, 4), "red").save(tmp_path / "clean.png")
    before = (tmp_path / "clean.png").read_bytes()
    r = run(app, ["denoise", str(tmp_path / "in.ply"), "--out", str(tmp_path / "clean.ply"), "--iterations", "1"])
    assert r.exit_code == 2 and "clean.png: exists and does not look like an earlier picture" in r.output, r.output
    assert (tmp_path / "clean.png").read_bytes() == before and not (tmp_path / "clean.ply").exists()
    (tmp_path / "clean.png").unlink()
    for _ in range(2):  # the second run replaces the first one's picture
        r = run(app, ["denoise", str(tmp_path / "in.ply"), "--out", str(tmp_path / "clean.ply"), "--iterations", "1"])
        assert r.exit_code == 0, r.output
    cfg = tmp_path / "s.toml"
    cfg.write_text('[mesh]\nbox = [0.1, 0.1, 0.1]\ncells = [1, 1, 1]\n[material]\nmodel = "corotated"\nE = 5e6\n'
                   'nu = 0.3\ndensity = 500\n[fem]\nelement = "P1"\n[dynamics]\nmethod = "be"\nh = 0.01\nsteps = 2\n')
    (tmp_path / "notes.csv").write_text("my notes\n")
    r = run(app, ["simulate", str(cfg), "--out", str(tmp_path / "notes.xdmf")])
    assert r.exit_code == 2 and "notes.csv: exists and does not look like an earlier energy CSV" in r.output, r.output
    assert (tmp_path / "notes.csv").read_text() == "my notes\n"
    (tmp_path / "notes.csv").unlink()
    for _ in range(2):
        r = run(app, ["simulate", str(cfg), "--out", str(tmp_path / "notes.xdmf")])
        assert r.exit_code == 0, r.output


# What native code writes to descriptor 2 inside native_stderr_without passes except the dropped lines (Warp's
# CUDA-driver line on every CPU-only run; review). mutant caught: nothing filtered (both lines out)
def test_native_stderr_filter(capfd):
    from physar.output import native_stderr_without

    with native_stderr_without("Could not find or load the NVIDIA CUDA driver"):
        os.write(2, b"Warp CUDA warning: Could not find or load the NVIDIA CUDA driver. GPU off.\n")
        os.write(2, b"a real problem\n")
    err = capfd.readouterr().err
    assert "a real problem" in err and "NVIDIA CUDA driver" not in err, err


def test_native_filter_without_stderr(monkeypatch):
    # sys.stderr None (pythonw, a service): the block runs unfiltered (review: AttributeError on import)
    import sys

    from physar.output import native_stderr_without

    monkeypatch.setattr(sys, "stderr", None)
    ran = []
    with native_stderr_without("x"):
        ran.append(1)
    assert ran == [1]
