"""``[mesh] size`` larger than the object (a length in mm given as m) is refused (issue 16: size = 3 on a
0.16 m plate built 242 cells silently)."""

import pytest

from physar.errors import ConfigError
from physar.fem.config import run_config
from physar.geometry import box_mesh, write_mesh

TOML = """
[mesh]
file = "plate.stl"
size = {size}
[material]
model = "linear"
E = 7e10
nu = 0.3
[[fix]]
plane = {{point = [0, 0, 0], normal = [1, 0, 0]}}
"""


def _plate(tmp_path, size):
    write_mesh(tmp_path / "plate.stl", box_mesh((0.16, 0.04, 0.012), (4, 1, 1)).boundary().mesh)
    p = tmp_path / "plate.toml"
    p.write_text(TOML.format(size=size))
    return p


def test_mesh_size_in_mm_is_refused_with_file_table_value_and_extent(tmp_path):
    """size = 3 on the 0.16 m plate: one line naming plate.toml, [mesh] size, 3, the 0.16 m extent.
    Catches: no check (a 1-element-across mesh is built), a message without the extent or file."""
    with pytest.raises(ConfigError) as e:
        run_config(_plate(tmp_path, 3))
    msg = str(e.value)
    assert "\n" not in msg
    assert "plate.toml" in msg and "[mesh] size = 3 m" in msg and "largest extent 0.16 m" in msg
    assert "plate.stl" in msg


def test_coarse_mesh_size_up_to_the_extent_is_accepted(tmp_path):
    """A legitimate coarse mesh is not refused: size = 0.16 (the largest extent: one element along the
    plate) builds. Catches: a stricter rule (e.g. half the extent) refusing a coarse mesh."""
    res = run_config(_plate(tmp_path, 0.16))
    assert res.problem.space.mesh.n_cells > 0
