"""A fem point load whose point is off the object: the message gives the point's distance to the surface and
says to check the point, not to increase the radius (issue 16: a load over a plate's hole was told "increase
the radius"). Reference: a box, whose surface distance is known in closed form."""
import pytest

from physar.errors import ConfigError
from physar.fem import FESpace, point_load
from physar.geometry import box_mesh


@pytest.mark.parametrize("point, dist", [([0.05, 0.01, 0.03], "0.02 m"), ([0.13, 0.01, 0.005], "0.03 m")])
def test_point_load_off_the_surface_names_its_distance(point, dist):
    """A point 20 mm above the top of a 100 x 20 x 10 mm box and one 30 mm past its end, radius 5 mm: one line
    with the distance (exact, from the box) and "check the point". Mutant (tried): the former message (no
    distance; "increase the radius" when surface faces were near but no quadrature point within the radius)."""
    space = FESpace(box_mesh((0.1, 0.02, 0.01), (10, 2, 1)), "P1")
    with pytest.raises(ConfigError) as e:
        point_load(space, point, [0, 0, -1.0], radius=0.005)
    msg = str(e.value)
    assert f"the point is {dist} from the object's surface" in msg and "check the point" in msg, msg
    assert "increase the radius" not in msg and "\n" not in msg
