"""physar.output.atomic_folder replaces its target whole: it refuses the current folder and the folders above
it (issue 21), before anything is created. Mutant caught: a target "." whose temporary would be made inside
itself (the run does all its work, then fails to rename) or a target above the working folder (replacing it
would delete the user's files)."""
import pytest

from physar.errors import ConfigError
from physar.output import atomic_folder


@pytest.mark.parametrize("target", [".", "..", "SUB/..", "ABOVE"])
def test_atomic_folder_refuses_the_working_folder_and_above(tmp_path, monkeypatch, target):
    work = tmp_path / "work"
    work.mkdir()
    (work / "mine.txt").write_text("keep")
    monkeypatch.chdir(work)
    path = {"SUB/..": "sub/..", "ABOVE": str(tmp_path)}.get(target, target)
    before = sorted(p.name for p in tmp_path.rglob("*"))
    with pytest.raises(ConfigError, match="not the current folder or one above it"), atomic_folder(path):
        pytest.fail("no folder to fill must be given")
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


def test_atomic_folder_still_replaces_a_subfolder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with atomic_folder("out") as d:
        (d / "a.txt").write_text("1")
    assert (tmp_path / "out" / "a.txt").read_text() == "1"
