"""``[truth] mesh_size``: the test-data renderer's truth on a mesh independent of the model's (the model's surface
file tetrahedralised again at another size, then refined), so that a model is never checked against a
subdivision of its own mesh.

Catches: ``mesh_size`` ignored (the truth would be the model's mesh split into 8: every model vertex a truth
vertex), the truth not filling the same solid (volume of the STL's solid, computed by the divergence theorem on
the surface, not by physar's meshing), and a box or volume mesh silently accepted.
"""
from pathlib import Path

import numpy as np
import pytest

from physar.errors import ConfigError
from physar.fem.config import build_mesh
from physar.geometry import read_mesh, tet_signed_volumes
from physar.rom.config import load_rom_config
from physar.synth import FineTruth

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
BRACKET = EXAMPLES / "ar" / "bracket" / "rom.toml"


def _stl_volume(path):
    s = read_mesh(path, kind="auto")
    x = s.points[s.faces]
    return abs(np.einsum("ij,ij->", x[:, 0], np.cross(x[:, 1], x[:, 2])) / 6)


def test_truth_is_meshed_again_at_its_own_size(tmp_path):
    """The bracket example's rom.toml with a 10 mm model mesh; truth at mesh_size 8 mm, refined 2x."""
    text = BRACKET.read_text()
    assert "size = 0.0025" in text
    (tmp_path / "rom.toml").write_text(text.replace("size = 0.0025", "size = 0.01"))
    (tmp_path / "bracket.stl").write_bytes((BRACKET.parent / "bracket.stl").read_bytes())
    cfg = load_rom_config(tmp_path / "rom.toml")
    model_mesh = build_mesh(cfg.mesh, tmp_path)
    truth = FineTruth(tmp_path / "rom.toml", refine=2, mesh_size=0.008)
    tm = truth.space.mesh
    vol = _stl_volume(BRACKET.parent / cfg.mesh.file)
    assert tet_signed_volumes(tm.points, tm.cells).sum() == pytest.approx(vol, rel=1e-6)
    # not a subdivision of the model's mesh: most model vertices are not truth vertices
    key = {tuple(np.round(p, 9)) for p in tm.points}
    shared = np.mean([tuple(np.round(p, 9)) in key for p in model_mesh.points])
    assert shared < 0.5, shared


def test_mesh_size_needs_a_surface_file():
    with pytest.raises(ConfigError, match=r"\[mesh\].*surface file"):
        FineTruth(EXAMPLES / "ar" / "cantilever" / "rom.toml", mesh_size=0.005)
    with pytest.raises(ConfigError, match="positive length"):
        FineTruth(BRACKET, mesh_size=-1.0)
