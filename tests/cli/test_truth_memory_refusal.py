"""``physar synth render`` refuses a ``[truth] refine`` whose truth would not fit in memory, before meshing
(issue 21: ``refine = 8`` on the cantilever example peaked at about 18 GB while building the truth).

Reference: the truth's tetrahedron count in closed form, 6 n_x n_y n_z refine^3 for a box of n_x n_y n_z cells
(each hexahedron into 6 Kuhn tetrahedra) and the model's count times 8^log2(refine) for a mesh file (each
tetrahedron into 8), and the estimate 43 B per element-matrix entry, 900 entries per P2 tetrahedron
(measured 38.5 kB per P2 tetrahedron, see physar/synth/truth.py).

Mutants caught: no check (the box is meshed and its stiffness assembled: the patched ``build_problem`` /
``refine_tets`` raise "built", and the 19 TB box is refused by ``box_mesh`` with another message); the check
after the refined mesh is made (``refine_tets`` called); the count without the refine^3 factor (the 17.7 GiB
estimate would read 35.4 MiB and pass the 4 GiB limit).
"""
import shutil
from pathlib import Path

import pytest
from test_bad_inputs import assert_refused, snapshot
from typer.testing import CliRunner

import physar.fem.config
import physar.output
import physar.synth.truth
from physar.ar.project import load_project
from physar.cli.main import app
from physar.errors import ConfigError
from physar.synth import FineTruth

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _built(*a, **k):
    raise AssertionError("built")


def test_refine_8_refused_with_its_estimate_before_meshing(tmp_path, monkeypatch):
    d = tmp_path / "project"
    d.mkdir()
    for f in ("project.toml", "rom.toml", "scenario.toml"):
        shutil.copy(EXAMPLES / "ar" / "cantilever" / f, d / f)
    shutil.copy(EXAMPLES / "camera_720p.toml", d / "camera.toml")
    (d / "project.toml").write_text((d / "project.toml").read_text().replace("../../camera_720p.toml",
                                                                               "camera.toml"))
    load_project(d / "project.toml")          # the model built here, before build_problem is patched
    (d / "s.toml").write_text("[truth]\nrefine = 8\n")
    monkeypatch.setattr(physar.output, "available_memory", lambda: 4 * 2**30)
    monkeypatch.setattr(physar.fem.config, "build_problem", _built)
    before = snapshot(tmp_path)
    r = CliRunner().invoke(app, ["synth", "render", str(d / "project.toml"), "-s", str(d / "s.toml"),
                                 "--out", str(tmp_path / "clip")])
    # 6 * (40*8) * (2*8) * (2*8) = 491,520 P2 tets; 43 * 900 * 491520 B = 17.7 GiB
    assert_refused(r, "the truth mesh at [truth] refine = 8 (491,520 P2 tetrahedra) needs about 17.7 GiB of "
                      "memory, more than the 4 GiB available", before, tmp_path)


def test_box_truth_beyond_any_memory_refused(tmp_path, monkeypatch):
    rom = (EXAMPLES / "ar" / "cantilever" / "rom.toml").read_text()
    assert "cells = [40, 2, 2]" in rom
    (tmp_path / "rom.toml").write_text(rom.replace("cells = [40, 2, 2]", "cells = [400, 20, 20]"))
    monkeypatch.setattr(physar.fem.config, "build_problem", _built)
    # 6 * 160,000 * 512 = 491,520,000 tets: 43 * 900 * 4.9e8 B = 17.3 TiB
    with pytest.raises(ConfigError, match=r"rom.toml: the truth mesh at \[truth\] refine = 8 \(491,520,000 P2 "
                                          r"tetrahedra\) needs about 17.3 TiB of memory"):
        FineTruth(tmp_path / "rom.toml", refine=8)


def test_mesh_file_truth_refused_before_refining(monkeypatch):
    monkeypatch.setattr(physar.output, "available_memory", lambda: 2**30)
    monkeypatch.setattr(physar.synth.truth, "refine_tets", _built)
    # the foam example's 1,728 tets * 8^3 = 884,736 P2 tets: 43 * 900 * 884736 B = 31.9 GiB
    with pytest.raises(ConfigError, match=r"\(884,736 P2 tetrahedra\) needs about 31.9 GiB of memory, more than "
                                          r"the 1 GiB available"):
        FineTruth(EXAMPLES / "ar" / "foam" / "rom.toml", refine=8)
