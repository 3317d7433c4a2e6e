import pytest

DROP = """
[mesh]
box = [0.2, 0.2, 0.2]
cells = [2, 2, 2]

[material]
model = "corotated"
E = 5e4
nu = 0.3
density = 500

[fem]
element = "P1"

[dynamics]
method = "{method}"
h = 0.01
steps = 12
gravity = [0, 0, -9.81]
{dynamics}

[dynamics.ground]
z = -0.02
stiffness = 2e4
"""


@pytest.fixture
def drop_config():
    """TOML text of a 2x2x2 corotated P1 block dropped on the penalty ground (12 steps of 0.01 s):
    ``make(method, dynamics="extra [dynamics] lines", tail="extra tables")``."""
    def make(method: str = "si", dynamics: str = "", tail: str = "") -> str:
        return DROP.format(method=method, dynamics=dynamics) + tail
    return make
