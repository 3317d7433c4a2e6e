r"""Camera calibration from ChArUco images (seed 000 §2.1: "after calibration and lens distortion correction").

Zhang's method as implemented by OpenCV: ChArUco corners (chessboard corners identified by the ArUco
markers in the white squares) give 2-D/3-D correspondences; ``cv2.calibrateCamera`` minimises the
reprojection error :math:`\sum_i \sum_k \|p_{ik} - \Pi(K, d, R_i, t_i; X_k)\|^2` over :math:`K`, distortion
:math:`d` and the view poses :math:`(R_i, t_i)`.
"""
from __future__ import annotations

import struct
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from physar.errors import ConfigError, PhysarError, PhysarWarning
from physar.vision.camera import Camera, Pose


def aruco_dictionary(name: str):
    """The OpenCV ArUco dictionary of a name such as ``"DICT_4X4_50"`` or ``"4x4_50"``."""
    key = name.upper()
    if not key.startswith("DICT_"):
        key = "DICT_" + key
    if not hasattr(cv2.aruco, key):
        raise ConfigError(f"unknown ArUco dictionary {name!r}; use e.g. DICT_4X4_50, DICT_5X5_100, DICT_6X6_250")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, key))


# the sides a printed ChArUco square can have: 1 mm (about 12 dots at 300 dpi) to 1 m (no sheet is larger
# than A0, 841 x 1189 mm); outside, the value is a unit mistake (40 for 40 mm) or nonsense (1e40)
MIN_SQUARE_M, MAX_SQUARE_M = 1e-3, 1.0
MAX_PRINT_DPI = 1200  # the finest raster of physar.vision.printing (its dpi limit)


@dataclass(frozen=True)
class CharucoSpec:
    """A ChArUco board: squares_x by squares_y squares of `square` m with markers of `marker` m."""

    squares_x: int = 7
    squares_y: int = 5
    square: float = 0.04
    marker: float = 0.03
    dictionary: str = "DICT_5X5_100"

    def __post_init__(self):
        if self.squares_x < 3 or self.squares_y < 3:
            raise ConfigError(f"ChArUco board needs at least 3x3 squares, got {self.squares_x}x{self.squares_y}")
        if not MIN_SQUARE_M <= self.square <= MAX_SQUARE_M:  # also NaN; OpenCV failed on 1e40 (float32)
            raise ConfigError(f"ChArUco square side (--square) {self.square:g} m is outside {MIN_SQUARE_M:g}.."
                              f"{MAX_SQUARE_M:g} m (a printable board; sides are in metres, e.g. 0.04 for 40 mm "
                              "squares)")
        if not 0 < self.marker < self.square:
            raise ConfigError(f"ChArUco marker side ({self.marker}) must be positive and smaller than the "
                              f"square side ({self.square})")
        dictionary = aruco_dictionary(self.dictionary)
        # the marker's cells (its bits and a one-cell border each side) must each get a printer dot at least
        cells = int(dictionary.markerSize) + 2
        smallest = cells * 0.0254 / MAX_PRINT_DPI
        if self.marker < smallest:  # OpenCV failed on 1e-300 (0 in float32)
            raise ConfigError(f"ChArUco marker side (--marker) {self.marker:g} m is too small to print: its {cells} "
                              f"cells need at least {smallest * 1e3:.3g} mm (one dot each at {MAX_PRINT_DPI} dpi)")
        # a board carries one marker per white square, each a distinct id of its dictionary: this bounds the
        # board (and what OpenCV allocates for it) before anything is built
        markers = self.squares_x * self.squares_y // 2
        available = dictionary.bytesList.shape[0]
        if markers > available:
            raise ConfigError(f"a {self.squares_x}x{self.squares_y} ChArUco board has {markers} markers but "
                              f"{self.dictionary} has {available} ids; use fewer squares or a larger dictionary")

    def board(self):
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square, self.marker,
                                      aruco_dictionary(self.dictionary))

    def image(self, px_per_square: int = 80) -> np.ndarray:
        """The board as a grey image, pixel (i, j) covering board point :math:`((j+.5)/s, (i+.5)/s)`
        (:math:`s` px per m)."""
        w, h = self.squares_x * px_per_square, self.squares_y * px_per_square
        return self.board().generateImage((w, h), marginSize=0, borderBits=1)


def render_plane(camera: Camera, pose: Pose, texture: np.ndarray, px_per_m: float,
                 background: float | tuple = 128, supersample: int = 1) -> np.ndarray:
    """Image of a textured plane :math:`z = 0` (texture pixel (i, j) at plane point
    :math:`((j+.5)/s, (i+.5)/s)`, :math:`s` = px_per_m).

    Each image pixel is undistorted to a ray, intersected with the plane and looked up in the texture
    (bilinear), so lens distortion is rendered exactly. ``supersample`` > 1 renders that many times
    larger and area-averages down (anti-aliasing, needed for sub-0.1 px corner accuracy).
    """
    if supersample > 1:
        big = render_plane(camera.scaled(supersample), pose, texture, px_per_m, background)
        return cv2.resize(big, camera.size, interpolation=cv2.INTER_AREA)
    w, h = camera.size
    jj, ii = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    X = camera.backproject_to_plane(np.column_stack([jj.ravel(), ii.ravel()]), pose, [0, 0, 0], [0, 0, 1])
    mx = (X[:, 0] * px_per_m - 0.5).reshape(h, w).astype(np.float32)
    my = (X[:, 1] * px_per_m - 0.5).reshape(h, w).astype(np.float32)
    return cv2.remap(texture, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=background)


def detect_charuco(image: np.ndarray, spec: CharucoSpec, detector=None):
    """(object points (n, 3), image points (n, 2)) of the ChArUco corners found in `image`."""
    if detector is None:
        detector = cv2.aruco.CharucoDetector(spec.board())
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    corners, ids, _, _ = detector.detectBoard(gray)
    if ids is None or len(ids) < 6:
        return None
    obj, img = detector.getBoard().matchImagePoints(corners, ids)
    return obj.reshape(-1, 3), img.reshape(-1, 2)


def _png_size(path: Path) -> tuple[int, int] | None:
    """Width and height a PNG's IHDR chunk declares (None for another format or a short file)."""
    with open(path, "rb") as fh:
        head = fh.read(24)
    if len(head) == 24 and head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        return struct.unpack(">II", head[16:24])
    return None


def read_gray(path) -> np.ndarray:
    """An image file as a grey array; one PhysarError naming the file when it cannot be decoded, or when its
    header declares more pixels than OpenCV decodes (``CV_IO_MAX_IMAGE_PIXELS``, 2**30 by default: a
    "decompression bomb" of a few bytes declaring 60000 x 60000 pixels; OpenCV raised cv2.error)."""
    try:
        im = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    except cv2.error as exc:
        if "CV_IO_MAX_IMAGE_PIXELS" in str(exc):
            wh = _png_size(Path(path))
            size = f"{wh[0]} x {wh[1]} pixels, " if wh else ""
            raise PhysarError(f"{path}: image too large ({size}over OpenCV's limit of 2**30 pixels)") from None
        raise PhysarError(f"{path}: cannot decode image") from None
    if im is None:
        raise PhysarError(f"{path}: cannot decode image")
    return im


def calibrate_charuco(images: Sequence, spec: CharucoSpec = CharucoSpec(), dist_coeffs: int = 5,
                      progress: Callable[[int, int], None] | None = None) -> tuple[Camera, dict]:
    """Calibrate from ChArUco views (arrays or image paths). Returns (camera, info) with info["rms_px"].

    ``dist_coeffs``: 0 (none), 2 (k1, k2), 5 (k1, k2, p1, p2, k3) or 8 (rational model).
    """
    if dist_coeffs not in (0, 2, 5, 8):
        raise ConfigError(f"dist_coeffs must be 0, 2, 5 or 8, got {dist_coeffs}")
    detector = cv2.aruco.CharucoDetector(spec.board())
    objs, imgs, used, size = [], [], [], None
    for k, im in enumerate(images):
        name = str(im) if isinstance(im, (str, Path)) else f"image {k}"
        if isinstance(im, (str, Path)):
            if not Path(im).is_file():
                raise PhysarError(f"{im}: image not found")
            im = read_gray(im)
        s = im.shape[1], im.shape[0]
        if size is None:
            size = s
        elif s != size:
            raise PhysarError(f"{name}: size {s[0]}x{s[1]} differs from the first image's {size[0]}x{size[1]}")
        found = detect_charuco(im, spec, detector)
        if found is not None:
            objs.append(found[0].astype(np.float32))
            imgs.append(found[1].astype(np.float32))
            used.append(name)
        if progress:
            progress(k + 1, len(images))
    if len(objs) < 3:
        raise PhysarError(f"calibration needs at least 3 images where the ChArUco board is found, got {len(objs)} "
                          f"(board {spec.squares_x}x{spec.squares_y}, {spec.dictionary})")
    flags = 0
    if dist_coeffs == 0:
        flags |= cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    elif dist_coeffs == 2:
        flags |= cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    elif dist_coeffs == 8:
        flags |= cv2.CALIB_RATIONAL_MODEL
    rms, K, d, _, _ = cv2.calibrateCamera(objs, imgs, size, None, None, flags=flags)
    d = np.asarray(d, float).ravel()[: max(dist_coeffs, 5) if dist_coeffs != 8 else 8]
    cam = Camera(K, d, size[0], size[1])
    doubts = calibration_warnings(cam, float(rms))
    for w in doubts:
        warnings.warn(w, PhysarWarning, stacklevel=2)
    return cam, {"rms_px": float(rms), "images_used": used, "images_total": len(images), "warnings": doubts}


MAX_RMS_PX = 1.0  # ChArUco corners are located to ~0.1 px; a good calibration reprojects well below 1 px
MAX_RADIAL_CHANGE = 0.5  # the distortion may scale the image corners' radius by 0.5..1.5 at most


def calibration_warnings(cam: Camera, rms_px: float) -> list[str]:
    """Reasons to doubt a calibration (empty when none), as OpenCV users check them by hand.

    * reprojection rms above ``MAX_RMS_PX`` = 1 px: ChArUco corners are found to about 0.1 px, so a good
      calibration stays well below 1 px (typically 0.1-0.5 px); more means blurred or too few views, corners
      matched to the wrong board (squares, square/marker sides, dictionary) or a lens the model cannot fit;
    * a radial distortion (k1, k2, k3 and, for the rational model, k4-k6) that, within the image (out to the
      corners' normalised radius r_c), folds the image over itself (r f(r) not increasing) or scales a radius
      by more than ``MAX_RADIAL_CHANGE`` = 50 % (a factor f outside 0.5..1.5). This judges the coefficients by
      their effect where there are pixels: a large high-order term is harmless at small r, while k3 =
      -82,498 at r_c = 0.6 turns the corners inside out;
    * what :meth:`Camera.load` refuses: a principal point outside the image or pixels far from square
      (:meth:`Camera.intrinsics_problem`), a distortion that folds the image (:meth:`Camera.distortion_problem`,
      tangential terms included).
    """
    out = []
    if not rms_px <= MAX_RMS_PX:
        out.append(f"reprojection rms {rms_px:.3g} px is above {MAX_RMS_PX:g} px: check the board settings "
                   "(--squares, --square, --marker, --dictionary) and use sharper views from more angles")
    K, w, h = cam.K, cam.width, cam.height
    cx, cy = K[0, 2], K[1, 2]
    bad_k = cam.intrinsics_problem()  # what Camera.load refuses of the intrinsics
    if bad_k:
        out.append(f"{bad_k}: the camera file will be refused when loaded; recalibrate with more views")
    k = np.zeros(8)
    d = np.asarray(cam.dist, float).ravel()
    for i, j in enumerate((0, 1, 4, 5, 6, 7)):  # k1 k2 (p1 p2) k3 k4 k5 k6 in OpenCV's order
        if j < d.size:
            k[i] = d[j]
    corners = np.array([[0, 0], [w, 0], [0, h], [w, h]], float)
    rc = float(np.max(np.hypot((corners[:, 0] - cx) / K[0, 0], (corners[:, 1] - cy) / K[1, 1])))
    r = np.linspace(0.0, rc, 512)
    r2 = r * r
    with np.errstate(all="ignore"):
        f = (1 + k[0] * r2 + k[1] * r2**2 + k[2] * r2**3) / (1 + k[3] * r2 + k[4] * r2**2 + k[5] * r2**3)
        folds = not np.all(np.diff(r * f) > 0)
    radial = not np.all(np.isfinite(f)) or folds or np.abs(f - 1).max() > MAX_RADIAL_CHANGE
    if radial:
        out.append(f"distortion {', '.join(f'{v:.4g}' for v in d)} is implausible within the image (its "
                   f"radial factor reaches {f[np.argmax(np.abs(f - 1))]:.3g} before the corners' normalised radius "
                   f"{rc:.2f}" + (", folding the image" if folds else "") + "): add views that fill the image "
                   "corners, or use --dist 2")
    why = cam.distortion_problem()  # what Camera.load refuses (tangential terms too): said here, at calibration
    if why and radial:
        out[-1] += "; the camera file will be refused when loaded"
    elif why:
        out.append(f"{why}: the camera file will be refused when loaded; recalibrate with views that fill the "
                   "image, or use --dist 2")
    return out
