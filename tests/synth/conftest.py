"""Small AR project folders for the synth tests: a lever on a textured plate (a rotation parameter, a [[bar]],
a [registration.plane] with an image holding an ArUco marker, two markers on the plate), optionally with the
model visible; a 640x360 camera."""
from pathlib import Path

import cv2
import numpy as np
import pytest

from physar.ar.project import load_project
from physar.vision.calibration import aruco_dictionary

CAMERA = """[camera]
width = 640
height = 360
matrix = [[520.0, 0.0, 319.5], [0.0, 520.0, 179.5], [0.0, 0.0, 1.0]]
distortion = [0.0, 0.0, 0.0, 0.0, 0.0]
"""

ROM = """[mesh]
box = [0.04, 0.04, 0.06]
cells = [1, 1, 2]
[material]
model = "linear"
E = 3e5
nu = 0.3
[[fix]]
plane = { point = [0, 0, 0], normal = [0, 0, 1] }
[fem]
element = "P2"
[[parameter]]
name = "theta"
kind = "rotation"
range = [-30, 60]
points = 7
axis = [0, 1, 0]
point = [0.02, 0.02, 0.12]
plane = { point = [0, 0, 0.06], normal = [0, 0, 1] }
[rom]
max_modes = 6
"""

# the plate: 150 x 150 px at 500 px/m (0.3 m square) in the plane y = 0.03, its top-left corner at
# (-0.13, 0.03, 0.25); image rows along +x, columns down (-z). An ArUco marker (id 7) fills image pixels
# [MARKER_PX, MARKER_PX + MARKER_SIDE) in both directions (lower left of the plate, away from the lever).
PLATE_PPM = 500.0
PLATE_ORIGIN = np.array([-0.13, 0.03, 0.25])
MARKER_X, MARKER_Y, MARKER_SIDE = 12, 84, 54


def plate_image(seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = np.empty((150, 150, 3), np.float32)
    img[...] = (150, 95, 60)  # saturated blue-grey (BGR): nothing white
    img *= 1 + 0.15 * cv2.GaussianBlur(rng.standard_normal((150, 150)).astype(np.float32), (0, 0), 2)[..., None]
    cell = MARKER_SIDE // 6
    q = MARKER_SIDE + 2 * cell
    img[MARKER_Y - cell:MARKER_Y - cell + q, MARKER_X - cell:MARKER_X - cell + q] = 255
    m = cv2.aruco.generateImageMarker(aruco_dictionary("DICT_4X4_50"), 7, MARKER_SIDE, borderBits=1)
    img[MARKER_Y:MARKER_Y + MARKER_SIDE, MARKER_X:MARKER_X + MARKER_SIDE] = m[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)


def write_lever_project(d: Path, visible: bool = False, markers: bool = True, image: bool = True) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    (d / "camera.toml").write_text(CAMERA)
    (d / "rom.toml").write_text(ROM)
    cv2.imwrite(str(d / "plate.png"), plate_image())
    mk = "".join(f"""
[[marker]]
id = {i}
size = 0.04
center = [{x}, 0.0295, 0.2]
normal = [0, -1, 0]
up = [0, 0, 1]
""" for i, x in ((0, 0.12), (1, -0.08))) if markers else ""
    (d / "project.toml").write_text(f"""name = "lever"
[model]
config = "rom.toml"
file = "model.npz"
visible = {str(visible).lower()}
[camera]
file = "camera.toml"
[registration]
method = "plane"
[registration.plane]
origin = {PLATE_ORIGIN.tolist()}
u = [1, 0, 0]
v = [0, 0, -1]
{'image = "plate.png"' if image else ""}
{f"px_per_m = {PLATE_PPM}" if image else ""}
[[bar]]
parameter = "theta"
zero = [0, 0, 1]
length = 0.1
width = 0.012
face = -0.02
{mk}""")
    return d / "project.toml"


@pytest.fixture(scope="session")
def lever_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("lever")
    write_lever_project(d)
    load_project(d / "project.toml")  # builds model.npz once
    return d


@pytest.fixture(scope="session")
def lever(lever_dir):
    return load_project(lever_dir / "project.toml")


@pytest.fixture(scope="session")
def lever_visible(lever_dir, tmp_path_factory):
    d = tmp_path_factory.mktemp("lever_visible")
    write_lever_project(d, visible=True)
    (d / "model.npz").write_bytes((lever_dir / "model.npz").read_bytes())
    return load_project(d / "project.toml")
