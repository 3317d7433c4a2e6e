r"""Real-data front end of the reconstruction (issue 17 part 1, seed 002 §5.1-5.2): ``physar recon import``
turns a user's video, segmentation masks, a camera, an up vector, a pose file and an object mesh into a
DATA_DIR in the format ``physar recon fit`` reads (:func:`physar.recon.train.load_dataset`), and ``physar recon
check`` reports what is missing or inconsistent in a DATA_DIR.

Inputs and conventions:

* **Frames**: any video PyAV decodes. Frame :math:`k` of the output (rate ``fps``) is source frame
  :math:`i_k = \operatorname{round}(k\, f_\text{src} / f)` (all frames when ``fps`` is not given), resized to
  ``size`` (area averaging when shrinking). The background (outside the masks) is replaced by the constant
  ``background`` colour that the Gaussian renderer composites over.
* **Masks**: PNGs, one per frame in frame order (:func:`physar.media.frame_order`: the numbers in the names
  compared as numbers; one per *source* frame, or one per output frame), in one of the formats video segmenters
  write (``masks`` or ``person_masks`` + ``object_masks``, not both):

  - *label PNGs* (``masks``; DAVIS / XMem / Cutie / SAM 2): 0 = background, one integer id per tracked object,
    as palette PNGs (the indices), grey PNGs (the values), or RGB(A) PNGs coloured with the DAVIS / PASCAL VOC
    palette (:data:`physar.recon.masks.VOC_PALETTE`: label :math:`k` has the colour of :math:`k`'s bits interleaved,
    1 = (128, 0, 0), 2 = (0, 128, 0), 3 = (128, 128, 0); each colour is mapped back to its label, a colour off
    the palette is refused naming it and its pixel count; alpha ignored). ``person_labels`` and ``object_labels`` name the ids
    of the person and of the object (default 1 and 2); ``ignore_labels`` are treated as background; any other
    value is refused, and so are label sets that share a value or use 0.
  - *per-object binary PNGs* (``person_masks``, ``object_masks``: a folder each, as SAM / SAM 2 /
    Track-Anything save one mask per object; ``object_masks`` may be several folders, an object tracked in parts,
    whose union is the object; the same number of files, paired in frame order; no folder given twice): grey, palette (by the palette's colours) or RGB (the largest colour channel; with alpha, the
    smaller of that and the alpha), foreground :math:`v \ge s/2` with :math:`s` = 1 for a folder of 0/1 files
    (its largest value 1), else 255 (8-bit) or 65535 (16-bit): anti-aliased or lossy edges are cut at half
    intensity. :math:`P` = the person's foreground, :math:`O` = the object's.

  The DATA_DIR mask is the foreground :math:`M = [\ell \in P \cup O]` (binary: :math:`P \cup O`), resized by
  area averaging and thresholded at 1/2. When the mask and video frame counts differ, the error names the frame
  numbers without a mask (from the names' last numbers).
* **Camera**: intrinsics in OpenCV's pixel-centre convention (pixel :math:`(0, 0)` centred at :math:`(0, 0)`)
  for the source size :math:`W \times H` — from a ``physar calibrate`` TOML or from a focal length in pixels or
  a 35 mm-equivalent focal length :math:`f_{35}` (EXIF ``FocalLengthIn35mmFilm``, defined by the diagonal
  angle of view: :math:`f_\text{px} = f_{35} \sqrt{W^2 + H^2} / \sqrt{36^2 + 24^2}`, principal point at the
  image centre). With distortion the frames and masks are undistorted first (same K). Rescaled to
  :math:`W' \times H'` in the renderer's convention (pixel centres at :math:`i + 1/2`):

  .. math::

      f_x' = f_x \frac{W'}{W}, \quad c_x' = (c_x + \tfrac12) \frac{W'}{W}, \quad
      f_y' = f_y \frac{H'}{H}, \quad c_y' = (c_y + \tfrac12) \frac{H'}{H}.

  The camera is static (one camera for all clips, as in the synthetic scenes).
* **Up**: a vector :math:`u` in camera coordinates (OpenCV: x right, y down, z forward; an upright camera has
  :math:`u = (0, -1, 0)`, the default: seed §5.1 records with a static camera whose vertical axis is aligned
  with gravity), e.g. from the phone's accelerometer or a level. No marker board is read (skipped: give the
  vector). The world frame: :math:`e_z = u/|u|`, :math:`e_x` = the camera's x made orthogonal to it,
  :math:`e_y = e_z \times e_x`; its origin on the object's support (lowest point along :math:`u`) below the
  centre of the object's bounding box; gravity :math:`-9.81\, e_z`. World :math:`\to` camera:
  :math:`p_C = R p_W + t`, :math:`R = [e_x\ e_y\ e_z]`.
* **Poses**: SMPL / SMPL-X parameter sequences as pose estimators write them, ``.npz`` (read with
  ``allow_pickle=False``: pickled objects are refused, never executed) or JSON (a table of arrays, or a list of
  per-frame tables): ``global_orient`` (F, 3) axis-angle (or (F, 3, 3) matrices), ``body_pose`` (F, 63 | 69),
  (F, 21 | 23, 3) or matrices (F, 21 | 23, 3, 3), ``transl`` (F, 3) m, ``betas`` (checked, not used: the body's
  size is ``height``); AMASS-style ``poses`` (F, >= 66: SMPL 72, SMPL+H 156, SMPL-X 165 values, the root's
  first) and ``trans``, or AMASS stage-ii ``root_orient``, ``pose_body`` and ``trans``, are accepted too; a
  ``body_pose`` of more than 23 joints (a whole pose, root first, would shift every joint) is refused. One pose
  per video frame, or AMASS's ``mocap_framerate``: the pose nearest in time to each frame (both start together).
  The body is in camera
  coordinates: a point of SMPL's canonical frame (y up, facing +z, x = the body's left) is posed as
  :math:`G_0 (x - J_0) + J_0 + \text{transl}`; :math:`J_0` (the pelvis joint of the template for the user's
  betas) is ``pelvis_offset`` (default 0: ``transl`` is the pelvis position).
* **Body** (``body``): the recon body the poses are retargeted onto, ``anny`` (default), ``capsule`` (the
  procedural figure) or ``smpl:PATH`` (the user's SMPL / SMPL-X ``.npz`` model file, exact), written to
  ``scene.json`` ``body.model`` (:func:`physar.skinning.load_body`); all are in the recon frame (z up, facing -y,
  the body's left at +x) and scaled to ``height``.
* **Retargeting** by joint-name correspondence (the body's ``smpl_map``: bone :math:`\leftarrow` SMPL joint):
  SMPL's global joint rotations :math:`G_j = G_{\mathrm{parent}(j)} \exp([\theta_j]_\times)` (Rodrigues) give
  each mapped bone the world rotation from its rest to its posed state

  .. math:: \Delta_k = R^\top G_{s(k)} M^\top C_k,

  with :math:`M` the change of canonical axes (SMPL :math:`\to` body: :math:`x \to x`, :math:`y \to z`,
  :math:`z \to -y`, ``SMPL_TO_BODY``) and :math:`C_k` the rest-pose correction: the smallest rotation taking the
  body's rest segment direction :math:`d_k` (its head to the head of the bone ``tpose[k]`` names) onto the
  segment's direction in SMPL's T-pose (identity for bones without an entry: their rest pose is taken as
  SMPL's). Unmapped bones move rigidly with their parent (:math:`\Delta_k = \Delta_{\mathrm{parent}(k)}`). With
  the body's rest frames :math:`G^\text{rest}_k = [Q_k, h_k]`, the local rotations of
  :meth:`physar.skinning.Skeleton.pose` are :math:`L_k = Q_k^\top \Delta_{\mathrm{parent}(k)}^\top \Delta_k Q_k`
  (:math:`\Delta = I` above the root), and the root translation puts the body's root joint :math:`h_\text{root}`
  on the pelvis: :math:`\tau = R^\top (J_0 + \text{transl} - t) - h_\text{root}`.

  What is approximate: every bone segment takes its SMPL segment's direction, not its length (joint positions
  follow the body's own proportions, not the user's betas); the A-pose of anny is brought to SMPL's T-pose by
  the minimal rotation per arm segment (upper arm, forearm, hand along :math:`\pm x`), so the twist about each
  of these segments (the palm's facing) is not matched; anny's other bones are assumed to rest as SMPL's do
  (legs, spine, neck, collars within a few degrees); SMPL's three spine joints drive three of anny's five
  spine bones (the others follow rigidly), its foot joint all the toes; hands and fingers follow the wrist. The
  capsule figure rests in SMPL's T-pose (exact for its 12 bones: intermediate SMPL joints (spine1-2, neck,
  collars) enter through the composed global rotations; wrists, hands, feet and the face are dropped);
  ``smpl:PATH`` is exact.
* **Object**: either a closed surface mesh (any format trimesh or meshio reads), vertices in metres (or
  ``mesh_units`` ``cm`` / ``mm``) in camera coordinates (a scan registered to the camera; one larger than 5 m is
  refused as another unit, one with holes
  imported with a warning), voxelised by the generalised winding number (inside: :math:`w > 1/2`); or the
  visual hull carved from the spin clip's object masks (:func:`carve_hull`), which needs the camera pose of
  every spin frame (``spin_cameras``: ``R`` (S, 3, 3), ``t`` (S, 3), :math:`p_i = R_i p_C + t_i` from the
  reference camera's coordinates, e.g. from a structure-from-motion run or a marker board; same intrinsics):
  with one static camera, as in seed §5.1, the spin clip shows the object from one side only and no hull can
  be carved, so give the mesh. Either way the object is voxelised on the MPM grid (cell
  :math:`\Delta x = \text{size}/\text{resolution}`) and written as the union of boxes (x-runs of voxels) that
  ``scene.json`` ``object.boxes`` holds, so that the recon's lattice at :math:`\Delta x / k` samples it exactly.
  A moving camera's spin frames are used for the hull only and left out of the DATA_DIR (``recon fit`` assumes
  one static camera); its appearance stage then starts from the first dynamic frame.

The first ``spin_frames`` output frames form the spin clip (the person turning next to the object at rest,
seed §5.1); the rest is the dynamic clip, of which the first ``n_obs`` are observed. No novel clip, no truth.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import warnings
import zipfile
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from physar import media
from physar.errors import ConfigError, PhysarError, PhysarWarning
from physar.output import atomic_folder, check_folder, check_memory, own_names
from physar.recon import scene as S
from physar.recon.io import imread
from physar.recon.masks import (
    check_mask_inputs,
    missing_frames,
    number_ranges,
    object_folders,
    read_binary_masks,
    read_masks,
)
from physar.skinning import (
    SMPL_JOINTS,
    SMPL_PARENTS,
    SMPL_TO_BODY,
    axis_angle_to_matrix,
    load_body,
    winding_number,
)
from physar.skinning.capsule import HUMANOID_SMPL_MAP

#: the capsule figure's bone <- SMPL joint map (each body carries its own: ``body.smpl_map``)
RETARGET = HUMANOID_SMPL_MAP
N_MAPPED = 22  # SMPL joints 0..21 (pelvis to the wrists: SMPL-X's 21 body joints and the root) are read

DATA_DIR_FILES = own_names(r"scene\.json", r"(spin_)?poses\.npz", r"rgb", r"mask", r"spin")


# ----------------------------------------------------------------------------------------------- camera
@dataclass
class Intrinsics:
    """Pinhole intrinsics of the source video in OpenCV's pixel-centre convention, px; distortion (OpenCV
    order)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    dist: tuple = ()

    @classmethod
    def from_focal(cls, width: int, height: int, focal_px: float | None = None,
                   focal_35mm: float | None = None) -> Intrinsics:
        r"""Square pixels, principal point at the centre :math:`((W-1)/2, (H-1)/2)`; focal length in px or
        35 mm-equivalent (mm, diagonal: :math:`f = f_{35} \sqrt{W^2+H^2} / 43.27`)."""
        if (focal_px is None) == (focal_35mm is None):
            raise ConfigError("give the focal length once: --focal-px or --focal-35mm (or --camera TOML)")
        f = focal_px if focal_px is not None else focal_35mm * math.hypot(width, height) / math.hypot(36.0, 24.0)
        if not (math.isfinite(f) and f > 0):
            raise ConfigError(f"focal length must be a positive number, got {f}")
        return cls(f, f, (width - 1) / 2, (height - 1) / 2, width, height)

    def scene_camera(self, width: int, height: int, R: np.ndarray, t: np.ndarray) -> dict:
        """scene.json camera for images resized to ``width`` x ``height`` (module docstring)."""
        sx, sy = width / self.width, height / self.height
        return {"fx": self.fx * sx, "fy": self.fy * sy, "cx": (self.cx + 0.5) * sx, "cy": (self.cy + 0.5) * sy,
                "width": int(width), "height": int(height), "R": np.asarray(R).tolist(), "t": np.asarray(t).tolist()}


def world_rotation(up) -> np.ndarray:
    """World -> camera rotation R = [e_x e_y e_z] (columns in camera coordinates) for an up vector ``up``."""
    u = np.asarray(up, dtype=np.float64).reshape(-1)
    if u.shape != (3,) or not np.all(np.isfinite(u)) or np.linalg.norm(u) < 1e-9:
        raise ConfigError(f"--up must be three numbers, not all zero (camera coordinates), got {np.asarray(up).tolist()}")
    ez = u / np.linalg.norm(u)
    ref = np.array([1.0, 0.0, 0.0]) if abs(ez[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    ex = ref - ez * (ref @ ez)
    ex /= np.linalg.norm(ex)
    return np.stack([ex, np.cross(ez, ex), ez], axis=1)


# ----------------------------------------------------------------------------------------------- video
def source_indices(n_src: int, src_fps: float, fps: float | None) -> np.ndarray:
    r"""Source frames of the output frames: :math:`i_k = \operatorname{round}(k f_\text{src}/f) < n_\text{src}`."""
    if fps is None or abs(fps - src_fps) < 1e-9 * src_fps:
        return np.arange(n_src)
    k = np.arange(math.floor((n_src - 1) * fps / src_fps + 1e-9) + 1)
    return np.minimum(np.round(k * src_fps / fps).astype(np.int64), n_src - 1)


#: frame intervals spreading more than this fraction of their median make a clip variable-frame-rate
VFR_SPREAD = 0.1


def nearest_indices(times: np.ndarray, fps: float) -> np.ndarray:
    r"""Source frames of the output frames of a variable-frame-rate clip: for each output time
    :math:`\tau_k = t_0 + k/f \le t_\text{last}`, the index of the source frame whose presentation time
    :math:`t_i` (s, increasing) is nearest (the earlier one on a tie)."""
    t = np.asarray(times, dtype=np.float64)
    tau = t[0] + np.arange(math.floor((t[-1] - t[0]) * fps + 1e-9) + 1) / fps
    j = np.clip(np.searchsorted(t, tau), 1, len(t) - 1)
    return np.where(tau - t[j - 1] <= t[j] - tau, j - 1, j)


def _packet_times(path: Path) -> np.ndarray | None:
    """Presentation times (s, sorted) of the video packets of ``path`` (demuxed, not decoded: a pass over the
    file's bytes); None when a packet has no timestamp."""
    import av

    pts = []
    with av.open(str(path)) as c:
        st = c.streams.video[0]
        for pkt in c.demux(st):
            if pkt.size == 0:  # the demuxer's flush packet
                continue
            if pkt.pts is None:
                return None
            pts.append(pkt.pts)
        tb = st.time_base
    return np.sort(np.asarray(pts, dtype=np.float64)) * float(tb) if pts and tb else None


@dataclass
class VideoClip:
    """What :func:`read_video` keeps: ``frames`` (one per output frame, prepared; a source frame used twice is
    the same object), ``fps`` (source rate: the stream's, or for a variable-frame-rate clip its mean rate
    :math:`(n-1)/(t_\text{last}-t_0)`), ``n_src`` (source frames), ``size`` (displayed (W, H) px),
    ``indices`` (the source frame of each output frame), ``out_fps`` (the output rate), ``variable`` (VFR)."""

    frames: list
    fps: float
    n_src: int
    size: tuple[int, int]
    indices: np.ndarray
    out_fps: float
    variable: bool = False


def read_video(path: str | Path, fps: float | None = None, prepare=None, budget=None) -> VideoClip:
    """Decode a video PyAV reads, in its displayed orientation (:mod:`physar.media`: a phone's rotated clip as it
    plays), keeping only the source frames that the output rate ``fps`` uses, each passed through
    ``prepare(W, H)(frame)`` (built on the first frame, W x H the displayed size; default: unchanged RGB uint8),
    so that memory holds the output frames, not the whole video. ``budget(n)`` is called with the number of
    frames to keep once ``prepare`` is built, before any is kept (e.g. to refuse a job too large for memory).

    The clip's timestamps are read first (demuxing, no decoding). A constant-rate clip keeps the frames
    :func:`source_indices` picks (all without ``fps``); a variable-frame-rate one (frame intervals spreading
    more than :data:`VFR_SPREAD` of their median and 2.5 ticks of the stream's clock: phones record so) is
    resampled by timestamp,
    :func:`nearest_indices`, at ``fps`` or, without it, at its mean rate (a PhysarWarning says so). A frame
    of another size than the first (:class:`physar.media.VideoChanged`) is an error; a clip that ends clearly
    before its header's duration a PhysarWarning (truncated?)."""
    import av

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: video not found")
    try:
        with av.open(str(path)) as c:
            fmt = c.format.name
            if fmt == "image2" or fmt.endswith("_pipe"):  # FFmpeg's still-image demuxers (png_pipe, jpeg_pipe, ...)
                raise ConfigError(f"{path}: an image or image stream (format {fmt}), not a video: it has no frame rate; "
                                  "give a video file (MP4, MOV, ...)")
            if not c.streams.video:
                raise ConfigError(f"{path}: holds no video stream")
            st = c.streams.video[0]
            rate = st.average_rate or st.guessed_rate or st.base_rate
            if rate is None or float(rate) <= 0:
                raise ConfigError(f"{path}: the video has no frame rate")
            rate = float(rate)
            tick = float(st.time_base) if st.time_base else 0.0  # MKV/WebM: 1 ms
        times = _packet_times(path)
    except av.FFmpegError as e:
        raise ConfigError(f"{path}: not a video PyAV can read ({' '.join(str(e).split())[:100]})") from None
    n_pkt = len(times) if times is not None else None
    variable = False
    if times is not None and n_pkt >= 3:
        dt = np.diff(times)
        med = float(np.median(dt))
        # a constant rate stored on a coarse clock (120 fps in 1 ms ticks: 8, 8, 9 ms) is not variable
        variable = med > 0 and float(dt.max() - dt.min()) > max(VFR_SPREAD * med, 2.5 * tick)
    if variable:
        rate = (n_pkt - 1) / float(times[-1] - times[0])
        if fps is None:
            warnings.warn(f"{path}: variable frame rate (frame intervals {dt.min() * 1e3:.0f}-{dt.max() * 1e3:.0f} ms, "
                          f"median {med * 1e3:.0f} ms): resampled by timestamp at its mean rate {rate:.4g} fps "
                          "(set --fps to choose the rate)", PhysarWarning, stacklevel=2)
    if fps is not None and not (math.isfinite(fps) and 0 < fps <= rate * (1 + 1e-9)):
        what = "mean rate of this variable-rate video" if variable else "video's rate"
        raise ConfigError(f"--fps {fps} must be in (0, {rate:.4g}] (the {what}; frames are not invented)")
    out_fps = rate if fps is None else float(fps)
    if variable:
        want = nearest_indices(times, out_fps)
        slots: dict[int, list[int]] = {}
        for k, i in enumerate(want.tolist()):
            slots.setdefault(i, []).append(k)
        n_keep = len(want)
    else:
        r = 1.0 if fps is None else rate / fps
        n_keep = len(source_indices(n_pkt, rate, fps)) if n_pkt else None
    kept: list = [None] * n_keep if variable else []
    n, conv, dur = 0, None, None
    try:
        with av.open(str(path)) as c:
            st = c.streams.video[0]
            dur = media.duration_of(c, st)
            checked = media.Checked(c.decode(st), path)
            for frame in checked:
                if conv is None:
                    conv = prepare(*checked.size) if prepare is not None else (lambda x: x)
                    if budget is not None and n_keep:
                        budget(n_keep)
                if variable:
                    if n in slots:
                        x = conv(media.to_rgb(frame))
                        for k in slots[n]:
                            kept[k] = x
                else:
                    k = round(n / r)
                    last = n_keep if n_keep is not None else k + 2   # the frames source_indices keeps
                    if any(round(j * r) == n for j in (k - 1, k, k + 1) if 0 <= j < last):
                        kept.append(conv(media.to_rgb(frame)))
                n += 1
    except av.FFmpegError as e:
        raise ConfigError(f"{path}: not a video PyAV can read ({' '.join(str(e).split())[:100]})") from None
    if not n:
        raise ConfigError(f"{path}: the video has no frame")
    if n < 3:
        raise ConfigError(f"{path}: the video has {n} frame{'s' if n > 1 else ''}; a clip needs >= 3")
    short = media.shortfall(checked, dur, rate)
    if short:
        warnings.warn(short, PhysarWarning, stacklevel=2)
    if variable:
        if n != n_pkt:
            raise ConfigError(f"{path}: decoded {n} frames of its {n_pkt} packets (damaged?); cannot resample it by "
                              "timestamp")
        idx = want
    else:
        idx = source_indices(n, rate, fps)
        if len(kept) != len(idx):
            raise ConfigError(f"{path}: kept {len(kept)} frames for {len(idx)} output frames (timestamps broken?)")
    return VideoClip(kept, rate, n, checked.size, idx, out_fps, variable)


def parse_size(size: str | None, width: int, height: int) -> tuple[int, int]:
    """Output size from ``WxH``, ``N`` (longer side N px, aspect kept) or None (source size)."""
    if size is None:
        return width, height
    try:
        if "x" in size.lower():
            w, h = (int(v) for v in size.lower().split("x"))
        else:
            n = int(size)
            s = n / max(width, height)
            w, h = max(1, round(width * s)), max(1, round(height * s))
    except ValueError:
        raise ConfigError(f"--size must be N (longer side, px) or WxH, got {size!r}") from None
    if not (8 <= w <= 8192 and 8 <= h <= 8192):
        raise ConfigError(f"--size {size}: {w}x{h} px is outside 8..8192")
    return w, h


def _resize(img: np.ndarray, w: int, h: int) -> np.ndarray:
    if img.shape[1] == w and img.shape[0] == h:
        return img
    shrink = w < img.shape[1] or h < img.shape[0]
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


# ----------------------------------------------------------------------------------------------- poses
def _load_pose_file(path: Path, what: str = "pose file") -> dict:
    if not path.is_file():
        raise ConfigError(f"{path}: {what} not found")
    if path.suffix.lower() == ".json":
        try:
            raw = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise ConfigError(f"{path}: invalid JSON ({' '.join(str(e).split())[:100]})") from None
        if isinstance(raw, list):  # one table per frame
            if not raw or not all(isinstance(r, dict) for r in raw):
                raise ConfigError(f"{path}: a JSON list must hold one table per frame")
            for f, r in enumerate(raw):
                lack = [k for k in raw[0] if k not in r]
                if lack:
                    raise ConfigError(f"{path}: frame {f} lacks field '{lack[0]}' (the first frame has it)")
            raw = {k: [r.get(k) for r in raw] for k in raw[0]}
        if not isinstance(raw, dict):
            raise ConfigError(f"{path}: the JSON must be a table of arrays or a list of per-frame tables")
        out = {}
        for k, v in raw.items():
            try:
                a = np.asarray(v, dtype=np.float64)
            except (TypeError, ValueError, OverflowError):
                if k in ("global_orient", "body_pose", "transl", "betas", "poses", "trans", "R", "t"):
                    raise ConfigError(f"{path}: field '{k}' is not an array of numbers") from None
                continue
            out[k] = a
        return out
    try:
        with np.load(path, allow_pickle=False) as d:
            if not isinstance(d, np.lib.npyio.NpzFile):
                raise ConfigError(f"{path}: a single .npy array, not an .npz of named arrays")
            out = {}
            for k in d.files:
                try:
                    out[k] = d[k]
                except ValueError as e:
                    if "pickle" in str(e):
                        raise ConfigError(f"{path}: field '{k}' holds pickled Python objects (refused: never "
                                          "unpickled); save plain numeric arrays") from None
                    raise
            return out
    except ConfigError:
        raise
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as e:
        why = ("neither a zip of arrays nor a .npy array: numpy could only unpickle it, which is refused"
               if "pickle" in str(e) else ' '.join(str(e).split())[:100])
        raise ConfigError(f"{path}: not a readable .npz or .json file ({why})") from None


def _rotations(a: np.ndarray, n_joints: int | None, path: Path, field: str) -> np.ndarray:
    """(F, J, 3, 3) rotations from axis-angle (F, 3J) / (F, J, 3) or matrices (F, J, 3, 3) / (F, 3, 3)."""
    a = np.asarray(a)
    if a.dtype.kind not in "fiu":
        raise ConfigError(f"{path}: field '{field}' holds {a.dtype} values, not numbers")
    a = a.astype(np.float64)
    if not np.all(np.isfinite(a)):
        raise ConfigError(f"{path}: field '{field}' holds non-finite values")
    F = a.shape[0] if a.ndim else 0
    if F == 0 or a.size == 0:
        raise ConfigError(f"{path}: field '{field}' has no frames (shape {a.shape})")
    if a.ndim >= 3 and a.shape[-2:] == (3, 3):
        m = a.reshape(F, -1, 3, 3)
        err, det = S.rotation_error(m)
        bad = np.argwhere((err > S.ROTATION_TOL) | (det < 0))  # lenient: float32 estimator output
        if len(bad):
            f, j = bad[0]
            raise ConfigError(f"{path}: field '{field}' [frame {f}, joint {j}] is not a rotation matrix (|R^T R - I| "
                              f"= {err[f, j]:.3g}, det {det[f, j]:.3g}; expected orthonormal with det +1)")
    elif a.ndim == 2 and a.shape[1] % 3 == 0:
        m = axis_angle_to_matrix(torch.as_tensor(a.reshape(F, -1, 3))).numpy()
    elif a.ndim == 3 and a.shape[2] == 3:
        m = axis_angle_to_matrix(torch.as_tensor(a)).numpy()
    else:
        raise ConfigError(f"{path}: field '{field}' has shape {a.shape}; expected axis-angle (F, 3J) or (F, J, 3) "
                          "or rotation matrices (F, J, 3, 3)")
    if n_joints is not None and m.shape[1] < n_joints:
        raise ConfigError(f"{path}: field '{field}' has {m.shape[1]} joints per frame, needs >= {n_joints}")
    return m


def load_smpl(path: str | Path) -> dict:
    """SMPL / SMPL-X parameters of a pose file (module docstring): "rotations" (F, 24, 3, 3) local joint
    rotations (SMPL's hand joints 22, 23 set to identity unless the file holds SMPL's 23 body joints) and
    "transl" (F, 3)."""
    path = Path(path)
    d = _load_pose_file(path)
    full = False   # body_pose cut from a full pose vector: its hand / face joints follow the body joints
    if "global_orient" not in d and "root_orient" in d and "pose_body" in d:  # AMASS / SOMA stage-ii names
        d["global_orient"], d["body_pose"] = d["root_orient"], d["pose_body"]
    elif "global_orient" not in d and "poses" in d:  # AMASS layout: the root's 3 values, then the body's
        p = np.asarray(d["poses"])
        if p.ndim != 2 or p.shape[1] < 3 * N_MAPPED:
            raise ConfigError(f"{path}: field 'poses' must be (F, >= {3 * N_MAPPED}) axis-angle, got {p.shape}")
        d["global_orient"], d["body_pose"], full = p[:, :3], p[:, 3:], True
    if "transl" not in d and "trans" in d:
        d["transl"] = d["trans"]
    fps = None
    for k in ("mocap_framerate", "mocap_frame_rate"):  # AMASS: the sequence's own rate
        if k in d:
            v = np.asarray(d[k])
            if v.size != 1 or v.dtype.kind not in "fiu" or not (np.isfinite(v.ravel()[0]) and v.ravel()[0] > 0):
                raise ConfigError(f"{path}: field '{k}' must be one positive frame rate, got {v.ravel()[:3].tolist()}")
            fps = float(v.ravel()[0])
    for k in ("global_orient", "body_pose", "transl"):
        if k not in d:
            raise ConfigError(f"{path}: missing field '{k}' (SMPL parameters: global_orient, body_pose, betas, transl)")
    g = _rotations(d["global_orient"], 1, path, "global_orient")[:, :1]
    b = _rotations(d["body_pose"], N_MAPPED - 1, path, "body_pose")
    if not full and b.shape[1] > len(SMPL_JOINTS) - 1:  # a whole pose (root first) would shift every joint by one
        raise ConfigError(f"{path}: field 'body_pose' has {b.shape[1]} joints (SMPL: 23, SMPL-X: 21, without the "
                          "root); a whole pose vector with the root first belongs in 'poses' (AMASS layout)")
    F = len(g)
    t = np.asarray(d["transl"])
    if t.dtype.kind not in "fiu" or t.size != 3 * F or t.ndim < 2 or len(t) != F:
        raise ConfigError(f"{path}: field 'transl' must be ({F}, 3) numbers, got {t.shape} {t.dtype}")
    t = t.reshape(F, 3).astype(np.float64)
    if not np.all(np.isfinite(t)):
        raise ConfigError(f"{path}: field 'transl' holds non-finite values")
    if len(b) != F:
        raise ConfigError(f"{path}: field 'body_pose' has {len(b)} frames, global_orient {F}")
    if "betas" in d:
        be = np.asarray(d["betas"])
        if be.dtype.kind not in "fiu" or not np.all(np.isfinite(be.astype(np.float64))):
            raise ConfigError(f"{path}: field 'betas' must hold finite numbers")
        if be.ndim > 2 or (be.ndim == 2 and len(be) not in (1, F)) or not 1 <= (be.shape[-1] if be.ndim else 0) <= 400:
            raise ConfigError(f"{path}: field 'betas' has shape {be.shape}: shape coefficients are (B,), (1, B) or "
                              f"({F}, B) with B <= 400 (10 for SMPL, 10-300 for SMPL-X)")
    R = np.tile(np.eye(3), (F, len(SMPL_JOINTS), 1, 1))
    R[:, :1] = g
    nb = min(b.shape[1], len(SMPL_JOINTS) - 1)
    if full and b.shape[1] != len(SMPL_JOINTS) - 1:  # SMPL+H / SMPL-X vectors: fingers, jaw, eyes after joint 21,
        nb = min(nb, 21)                            # not SMPL's hands (22, 23): those stay identity
    R[:, 1:1 + nb] = b[:, :nb]
    if not full and b.shape[1] not in (21, len(SMPL_JOINTS) - 1):  # SMPL-X has 21 body joints; SMPL 23
        raise ConfigError(f"{path}: field 'body_pose' has {b.shape[1]} joints (SMPL: 23, SMPL-X: 21)")
    return {"rotations": R, "transl": t, "fps": fps}


def smpl_global_rotations(local: np.ndarray) -> np.ndarray:
    r"""Global joint rotations :math:`G_j = G_{\mathrm{parent}(j)} L_j` (F, 24, 3, 3) of SMPL's tree."""
    G = np.empty_like(local)
    for j, p in enumerate(SMPL_PARENTS):
        G[:, j] = local[:, j] if p < 0 else G[:, p] @ local[:, j]
    return G


def rotation_between(d: np.ndarray, e: np.ndarray) -> np.ndarray:
    r"""The smallest rotation (3, 3) taking the direction of ``d`` onto that of ``e``: axis :math:`v = \hat d \times
    \hat e`, :math:`R = I + [v]_\times + [v]_\times^2 / (1 + \hat d \cdot \hat e)` (a half turn about an axis
    normal to ``d`` when they are opposite)."""
    d, e = np.asarray(d, float) / np.linalg.norm(d), np.asarray(e, float) / np.linalg.norm(e)
    v, c = np.cross(d, e), float(d @ e)
    if c < -1 + 1e-12:
        a = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
        a /= np.linalg.norm(a)
        return 2 * np.outer(a, a) - np.eye(3)
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K / (1 + c)


def retarget(smpl: dict, body, R: np.ndarray, t: np.ndarray, pelvis_offset=(0.0, 0.0, 0.0)) -> dict:
    r"""Local rotations (F, B, 3, 3) and root translations (F, 3) of a recon body (:class:`physar.skinning.Body`:
    its ``smpl_map`` and ``tpose``) for SMPL parameters in camera coordinates and the world-to-camera pose (R, t)
    (module docstring: :math:`\Delta_k = R^\top G_{s(k)} M^\top C_k`,
    :math:`L_k = Q_k^\top \Delta_{\mathrm{parent}(k)}^\top \Delta_k Q_k`)."""
    G = smpl_global_rotations(smpl["rotations"])
    sk = body.skeleton
    F, parents = len(G), sk.parents.tolist()
    Q = sk.rest_global[:, :3, :3].double().numpy()
    heads = sk.rest_global[:, :3, 3].double().numpy()
    D = np.empty((F, sk.n_bones, 3, 3))
    for k, name in enumerate(sk.names):
        joint = body.smpl_map.get(name)
        if joint is None:
            if parents[k] < 0:
                raise ConfigError(f"the recon body's root bone {name!r} has no SMPL joint in its retarget map")
            D[:, k] = D[:, parents[k]]
            continue
        C = np.eye(3)
        if name in body.tpose:
            end, direction = body.tpose[name]
            C = rotation_between(heads[sk.index(end)] - heads[k], direction)
        D[:, k] = R.T @ G[:, SMPL_JOINTS.index(joint)] @ SMPL_TO_BODY.T @ C
    L = np.empty_like(D)
    for k, p in enumerate(parents):
        rel = D[:, k] if p < 0 else np.swapaxes(D[:, p], -1, -2) @ D[:, k]
        L[:, k] = Q[k].T @ rel @ Q[k]
    iroot = next(k for k, p in enumerate(parents) if p < 0)
    pelvis_c = smpl["transl"] + np.asarray(pelvis_offset, dtype=np.float64)
    root_t = (pelvis_c - t) @ R - heads[iroot]  # R^T (p - t) - h, row-wise
    return {"rotations": L, "root_translation": root_t}


#: keys that make a pose file SMPL parameters (:func:`load_smpl`) rather than a recon pose sequence
SMPL_KEYS = ("global_orient", "poses", "root_orient")


def is_smpl_file(path: str | Path) -> bool:
    """Whether ``path`` holds SMPL / SMPL-X / AMASS parameters (a JSON file, or an npz with one of
    :data:`SMPL_KEYS`) rather than recon poses (``rotations``, ``root_translation``)."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        return True
    try:
        with np.load(path, allow_pickle=False) as d:
            return isinstance(d, np.lib.npyio.NpzFile) and any(k in d.files for k in SMPL_KEYS)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error, AttributeError, TypeError):
        return False


def retarget_to_scene(path: str | Path, meta: dict, body) -> tuple[np.ndarray, np.ndarray]:
    """SMPL parameters of ``path`` (camera coordinates of the imported clip's camera, :func:`load_smpl`)
    retargeted onto ``body`` in the world of an imported scene ``meta`` (its camera's (R, t) and the import's
    ``pelvis_offset``), as :func:`import_video` does for the clip: (rotations (F, B, 3, 3), root translations
    (F, 3)) for ``physar recon predict``."""
    smpl = load_smpl(path)
    c = meta["camera"]
    R, t = np.asarray(c["R"], dtype=np.float64), np.asarray(c["t"], dtype=np.float64)
    pose = retarget(smpl, body, R, t, meta.get("import", {}).get("pelvis_offset", (0.0, 0.0, 0.0)))
    return pose["rotations"], pose["root_translation"]


def import_body(spec: str, height: float):
    """The recon body named by ``--body`` (:func:`physar.skinning.load_body`), one ConfigError line naming it."""
    try:
        return load_body(spec, height, "--body")
    except PhysarError as e:
        raise ConfigError(str(e)) from None


# ----------------------------------------------------------------------------------------------- object
def read_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and triangles (T, 3) of a surface mesh file (trimesh, else meshio)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: object mesh not found")
    # the readers' own prints (meshio's PLY reader writes to stdout and exits on a bad header) are kept out of
    # the command's output: a failure becomes one line
    try:
        import trimesh

        with contextlib.redirect_stdout(io.StringIO()):
            m = trimesh.load(str(path), force="mesh", process=False)
        V, T = np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)
    except (Exception, SystemExit):  # noqa: BLE001 - any reader failure: try meshio, then one line
        said = io.StringIO()
        try:
            import meshio

            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(said):
                m = meshio.read(str(path))
            V = np.asarray(m.points, dtype=np.float64)[:, :3]
            tri = [c.data for c in m.cells if c.type == "triangle"]
            T = np.concatenate(tri).astype(np.int64) if tri else np.zeros((0, 3), np.int64)
        except (Exception, SystemExit) as e:  # noqa: BLE001
            why = said.getvalue().strip().replace(str(path), "it") if isinstance(e, SystemExit) else str(e)
            raise ConfigError(f"{path}: not a mesh trimesh or meshio can read ({' '.join(why.split())[:80]})") from None
    if len(T) == 0 or len(V) < 4:
        raise ConfigError(f"{path}: the mesh has no triangle")
    if not np.all(np.isfinite(V)):
        raise ConfigError(f"{path}: the mesh has non-finite vertices")
    return V, T


def open_edges(V: np.ndarray, T: np.ndarray) -> int:
    """Edges used by one triangle only, after merging vertices that coincide (to 1e-7 of the mesh's size: STL and
    per-face-normal OBJ files repeat each corner): 0 for a closed mesh."""
    scale = max(float(np.ptp(V, axis=0).max()), 1e-12)
    _, inv = np.unique(np.round(V / (1e-7 * scale)), axis=0, return_inverse=True)
    f = inv.reshape(-1)[T]
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    e = e[e[:, 0] != e[:, 1]]  # degenerate triangles' collapsed edges
    _, count = np.unique(e, axis=0, return_counts=True)
    return int(np.sum(count == 1))


def runs_to_boxes(inside: np.ndarray, lo: np.ndarray, cell: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Occupied voxels (nx, ny, nz) of the grid ``lo + cell * (i, j, k)`` as the union of boxes [(min, max), ...]
    made of their x-runs."""
    boxes = []
    _, ny, nz = inside.shape
    for j in range(ny):
        for k in range(nz):
            d = np.diff(np.r_[False, inside[:, j, k], False].astype(np.int8))
            for a, b in zip(np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]):
                boxes.append((lo + cell * np.array([a, j, k]), lo + cell * np.array([b, j + 1, k + 1])))
    return boxes


def _grid(lo: np.ndarray, hi: np.ndarray, cell: float) -> tuple[np.ndarray, tuple]:
    n = tuple(np.maximum(1, np.ceil((hi - lo) / cell - 1e-9).astype(int)).tolist())
    axes = [lo[i] + (np.arange(n[i]) + 0.5) * cell for i in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3), n


def voxel_boxes(V: np.ndarray, T: np.ndarray, cell: float, lo: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The inside of a closed mesh (winding number > 1/2 at voxel centres) on the grid ``lo + cell * (i, j, k)``
    up to the mesh's bounding box, as boxes (:func:`runs_to_boxes`)."""
    P, n = _grid(lo, V.max(0), cell)
    w = winding_number(torch.as_tensor(P), torch.as_tensor(V), torch.as_tensor(T)).numpy()
    return runs_to_boxes((np.abs(w) > 0.5).reshape(n), lo, cell)


def carve_hull(views, R: np.ndarray, cell: float | None = None, far: float = 5.0, n_coarse: int = 40,
               resolution: int = 16) -> tuple[np.ndarray, np.ndarray, float]:
    r"""Visual hull of an object seen in several views, on a grid of the rotated frame :math:`q` (world axes,
    reference-camera origin: :math:`p_C = R q`).

    ``views``: [(K (3, 3) OpenCV px, :math:`R_i`, :math:`t_i`, mask (H, W) bool), ...] with view coordinates
    :math:`p_i = R_i p_C + t_i`; the object must be whole inside every view. A voxel is kept when its centre
    projects inside every image onto the mask: :math:`H = \bigcap_i \{q : \pi_i(q) \in M_i\}`. Coarse to fine:
    ``n_coarse`` cells per axis over view 0's frustum up to ``far`` m (a coarse voxel kept when its centre is
    within the voxel's projected radius of every mask: a distance transform, at each voxel's own depth), three
    times, then the final ``cell`` (default: twice the hull's largest extent / ``resolution``,
    the importer's MPM cell) over the coarse hull's box. Returns (occupancy (nx, ny, nz), grid origin, cell)."""
    # distance (px) from each pixel to the nearest mask pixel (0 on the mask), once per view
    dist = [cv2.distanceTransform((~np.asarray(m, bool)).astype(np.uint8), cv2.DIST_L2, 5) for *_, m in views]

    def keep(Q: np.ndarray, radius: float) -> np.ndarray:
        """Voxel centres ``Q`` whose ball of ``radius`` (m) may meet the object: in every view the projected
        centre lies within the ball's projected radius :math:`f r / z` of the mask (centre's own depth; 0: on
        the mask)."""
        pc = Q @ R.T
        ok = np.ones(len(Q), dtype=bool)
        for (K, Ri, ti, m), dm in zip(views, dist):
            p = pc @ np.asarray(Ri).T + np.asarray(ti)
            front = p[:, 2] > 1e-6
            z = np.maximum(p[:, 2], 1e-9)
            uf, vf = K[0, 0] * p[:, 0] / z + K[0, 2], K[1, 1] * p[:, 1] / z + K[1, 2]
            H, W = m.shape
            if radius > 0:
                u, v = np.clip(np.round(uf), 0, W - 1).astype(np.int64), np.clip(np.round(vf), 0, H - 1).astype(np.int64)
                off = np.hypot(np.maximum(np.abs(uf - u) - 0.5, 0), np.maximum(np.abs(vf - v) - 0.5, 0))  # outside
                ok &= front & (dm[v, u] + off <= K[0, 0] * radius / z + 0.5)
            else:
                u, v = np.round(uf).astype(np.int64), np.round(vf).astype(np.int64)
                ok &= front & (u >= 0) & (u < W) & (v >= 0) & (v < H)
                ok[ok] &= np.asarray(m, bool)[v[ok], u[ok]]
        return ok

    K0, R0, t0, m0 = views[0]
    H, W = m0.shape
    corners = []
    for d in (0.05, far):
        for u, v in ((-0.5, -0.5), (W - 0.5, -0.5), (-0.5, H - 0.5), (W - 0.5, H - 0.5)):
            corners.append([(u - K0[0, 2]) / K0[0, 0] * d, (v - K0[1, 2]) / K0[1, 1] * d, d])
    pc = (np.asarray(corners) - t0) @ np.asarray(R0)  # view 0 -> reference camera
    q = pc @ R
    lo, hi = q.min(0), q.max(0)
    for _ in range(3):
        c = float((hi - lo).max() / n_coarse)
        P, n = _grid(lo, hi, c)
        ok = keep(P, 0.87 * c)
        if not ok.any():
            raise ConfigError("visual hull: no point lies inside every view's object mask (wrong spin cameras, or "
                              "the object leaves a view?)")
        z0 = (P[ok] @ R.T @ np.asarray(R0).T + t0)[:, 2]
        if z0.max() > 0.9 * far:
            raise ConfigError("visual hull: the views do not bound the object in depth (the spin cameras must look "
                              "at it from different directions)")
        lo, hi = P[ok].min(0) - c, P[ok].max(0) + c
    if cell is None:
        cell = float(2 * (hi - lo - 2 * c).max() / resolution)
    P, n = _grid(lo, hi, cell)
    occ = keep(P, 0.0).reshape(n)
    if not occ.any():
        raise ConfigError(f"visual hull: no voxel of {cell:.3f} m lies inside every view's object mask")
    return occ, lo, cell


# ----------------------------------------------------------------------------------------------- import
@dataclass
class ImportOptions:
    """Settings of :func:`import_video` (SI units; see the module docstring)."""

    size: str | None = None
    fps: float | None = None
    spin_frames: int = 0
    n_obs: int | None = None
    person_labels: tuple = (1,)
    object_labels: tuple = (2,)
    ignore_labels: tuple = ()
    up: tuple = (0.0, -1.0, 0.0)
    height: float = 1.7
    body: str = "anny"
    pelvis_offset: tuple = (0.0, 0.0, 0.0)
    background: tuple = (0.3, 0.3, 0.35)
    domain_size: float | None = None
    grid_resolution: int = 16
    substeps: int = 32
    density: float = 200.0
    nu: float = 0.3
    floor: str = "sticky"
    mesh_units: str = "m"
    body_E: float = 1.0e4
    body_density: float = 1000.0


def _check_options(o: ImportOptions) -> None:
    """One-line ConfigErrors for the options not checked elsewhere: labels (non-negative integers, 0 is the
    background, the three sets disjoint), the grid resolution, the domain size, the pelvis offset and the
    background colour."""
    sets = {"--person-labels": o.person_labels, "--object-labels": o.object_labels, "--ignore-labels": o.ignore_labels}
    for name, v in sets.items():
        if not all(isinstance(x, (int, np.integer)) and not isinstance(x, bool) and x >= 0 for x in v):
            raise ConfigError(f"{name} must be non-negative integers, got {list(v)}")
    for name in ("--person-labels", "--object-labels"):
        if not sets[name]:
            raise ConfigError(f"{name} is empty: give the label value(s) of the masks")
        if 0 in sets[name]:
            raise ConfigError(f"{name} {list(sets[name])}: 0 is the background of the label PNGs")
    names = list(sets)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            both = sorted(set(sets[a]) & set(sets[b]))
            if both:
                raise ConfigError(f"{a} and {b} share the label(s) {both}: each label value names one thing")
    g = o.grid_resolution
    if not (isinstance(g, (int, np.integer)) and 2 <= g <= S.MAX_GRID_RESOLUTION):
        raise ConfigError(f"--grid-resolution must be an integer in [2, {S.MAX_GRID_RESOLUTION}], got {g}")
    if o.domain_size is not None and not (math.isfinite(o.domain_size) and o.domain_size > 0):
        raise ConfigError(f"--domain-size must be a positive length [m], got {o.domain_size}")
    if len(o.pelvis_offset) != 3 or not all(math.isfinite(x) for x in o.pelvis_offset):
        raise ConfigError(f"--pelvis-offset must be 3 finite numbers [m], got {list(o.pelvis_offset)}")
    if o.mesh_units not in MESH_UNITS:
        raise ConfigError(f"--mesh-units {o.mesh_units!r}: use {', '.join(MESH_UNITS)}")
    if len(o.background) != 3 or not all(math.isfinite(x) and 0 <= x <= 1 for x in o.background):
        raise ConfigError(f"--background must be 3 numbers in [0, 1] (RGB), got {list(o.background)}")


MAX_OBJECT_EXTENT = 5.0  # m: an object a person squeezes or lifts; larger is a mesh in other units
MESH_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}  # --mesh-units: the object mesh's length unit, in metres


def _load_cameras(path: str | Path, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-view camera poses of the spin clip: ``R`` (n, 3, 3) and ``t`` (n, 3), :math:`p_i = R_i p_C + t_i` from
    the reference (dynamic-clip) camera's coordinates, m; .npz (no pickles) or JSON."""
    path = Path(path)
    d = _load_pose_file(path, "spin cameras file")
    for k, shape in (("R", (n, 3, 3)), ("t", (n, 3))):
        if k not in d:
            raise ConfigError(f"{path}: missing field '{k}' {shape} (spin cameras: p_i = R_i p + t_i)")
        a = np.asarray(d[k])
        if a.dtype.kind not in "fiu" or a.shape != shape or not np.all(np.isfinite(a)):
            raise ConfigError(f"{path}: field '{k}' must be {shape} finite numbers (one per spin frame), got "
                              f"{a.shape} {a.dtype}")
    Rs = np.asarray(d["R"], dtype=np.float64)
    err, det = S.rotation_error(Rs)
    bad = np.flatnonzero((err > 1e-4) | (det < 0))
    if len(bad):  # the first bad view (a reflection has err 0: not err.argmax())
        raise ConfigError(f"{path}: field 'R' [{int(bad[0])}] is not a rotation matrix (|R^T R - I| = "
                          f"{err[bad[0]]:.3g}, det {det[bad[0]]:.3g})")
    return Rs, np.asarray(d["t"], dtype=np.float64)


def mocap_indices(mocap_fps: float, n: int, src_fps: float, idx: np.ndarray, where, video) -> np.ndarray:
    r"""The pose of a mocap sequence (``n`` poses at ``mocap_fps``, starting with the video) nearest in time to each
    kept video frame :math:`k` (time :math:`k / f_{src}`): :math:`j = \mathrm{round}(k f_{mocap} / f_{src})`;
    one ConfigError line when the sequence ends before the video."""
    j = np.round(np.asarray(idx, dtype=np.float64) * mocap_fps / src_fps).astype(np.int64)
    if j.max() >= n:
        raise ConfigError(f"{where}: {n} poses at {mocap_fps:g} fps (mocap_framerate) cover {n / mocap_fps:.2f} s, "
                          f"the video {video} {(idx.max() + 1) / src_fps:.2f} s: the poses must span the clip")
    return j


def _count_match(n: int, n_src: int, idx: np.ndarray, what: str, where, video, files=None) -> np.ndarray:
    """Which of ``n`` per-frame entries feed the output frames: one per source frame (select ``idx``) or one per
    output frame. On a mismatch, ``files`` (the entries' files, when given) name the frame numbers missing, of
    the source frames or of the output frames, whichever count is nearer ``n``."""
    if n == n_src:
        return idx
    if n == len(idx):
        return np.arange(n)
    lack = ""
    if files is not None:
        lack = missing_frames(files, n_src if abs(n - n_src) <= abs(n - len(idx)) else len(idx))
    raise ConfigError(f"{where}: {n} {what} for {n_src} video frames ({video}, {len(idx)} after resampling): "
                      f"frame count mismatch{lack}")


def _folder_names(object_masks) -> str | list[str] | None:
    """``scene.json``'s record of the object mask folders: None, one path, or a list of several."""
    objs = [str(f) for f in object_folders(object_masks)]
    return None if not objs else objs[0] if len(objs) == 1 else objs


def _mask_pixels(mdict: dict, midx, n_out: int) -> dict:
    """Per output frame (spin frames first), the pixels of the object's mask and of the person's outside it (the
    DATA_DIR keeps their union only): ``recon check`` names the frames where either is empty (a segmenter that
    lost one)."""
    obj = [int((mdict[midx[k]][1] > 0).sum()) for k in range(n_out)]
    person = [int(((mdict[midx[k]][0] > 0) & ~(mdict[midx[k]][1] > 0)).sum()) for k in range(n_out)]
    return {"object": obj, "person": person}


def import_video(video: str | Path, out_dir: str | Path, *, masks: str | Path | None = None, poses: str | Path,
                 person_masks: str | Path | None = None,
                 object_masks: str | Path | Sequence[str | Path] | None = None,
                 intrinsics: Intrinsics | None = None, focal_px: float | None = None, focal_35mm: float | None = None,
                 object_mesh: str | Path | None = None, spin_cameras: str | Path | None = None,
                 opts: ImportOptions | None = None) -> dict:
    """Write a DATA_DIR for ``physar recon fit`` from a video, masks (``masks``: label PNGs, or ``person_masks`` and
    ``object_masks``: binary PNGs, one object folder or several, :func:`physar.recon.masks.check_mask_inputs`), a pose file, a camera and an object mesh (module
    docstring). Everything is read and checked before anything is written; the folder appears
    whole (``physar.output.atomic_folder``). Returns a summary."""
    o = opts or ImportOptions()
    out = check_folder(out_dir, own=DATA_DIR_FILES, inputs=[video, masks, person_masks, *object_folders(object_masks),
                                                               poses,
                                                               object_mesh, spin_cameras],
                       kind="DATA_DIR")
    if o.floor not in ("sticky", "slip", "separate"):
        raise ConfigError(f"--floor {o.floor!r}: use sticky, slip or separate")
    for name, v in (("height", o.height), ("density", o.density), ("grid_resolution", o.grid_resolution),
                    ("substeps", o.substeps), ("body_E", o.body_E), ("body_density", o.body_density)):
        if not (math.isfinite(v) and v > 0):
            raise ConfigError(f"--{name.replace('_', '-')} must be positive, got {v}")
    if not -1 < o.nu < 0.5:
        raise ConfigError(f"--nu must be in (-1, 0.5), got {o.nu}")
    _check_options(o)
    if (object_mesh is None) == (spin_cameras is None):
        raise ConfigError("give the object's geometry once: --object-mesh FILE, or --spin-cameras FILE (the spin "
                          "frames' camera poses) for a visual hull carved from the spin clip's object masks")
    if spin_cameras is not None and o.spin_frames < 2:
        raise ConfigError("--spin-cameras needs the spin clip: --spin-frames N (N >= 2 views of the object)")
    spin_cams = _load_cameras(spin_cameras, o.spin_frames) if spin_cameras is not None else None
    check_mask_inputs(masks, person_masks, object_masks)
    smpl = load_smpl(poses)  # the small inputs first: their errors come before the video is decoded
    body_spec = o.body.strip()
    if body_spec.lower().startswith("smpl:"):  # stored absolute: scene.json is read from any folder
        body_spec = "smpl:" + str(Path(body_spec[5:]).expanduser().resolve())
    body = import_body(body_spec, o.height)
    # ---- read everything (frames and masks kept at the output size only)
    geo = {}

    def prepare_frames(W0: int, H0: int):
        cam = intrinsics or Intrinsics.from_focal(W0, H0, focal_px, focal_35mm)
        if abs(cam.width / cam.height - W0 / H0) > 0.01 * W0 / H0:
            raise ConfigError(f"camera: calibrated for {cam.width}x{cam.height} px, the video is {W0}x{H0} (another "
                              "aspect ratio): calibrate at the video's size")
        s0 = W0 / cam.width  # a calibration at another size of the same aspect: rescale to the video's
        if (cam.width, cam.height) != (W0, H0):
            warnings.warn(PhysarWarning(
                f"camera: calibrated for {cam.width}x{cam.height} px, the video is {W0}x{H0}: rescaled by {s0:.4g} "
                "(taken as the calibrated mode resized, same field of view; calibrate at the video's size if it "
                "is another crop of the sensor)"), stacklevel=2)
        cam = Intrinsics(cam.fx * s0, cam.fy * s0, (cam.cx + 0.5) * s0 - 0.5, (cam.cy + 0.5) * s0 - 0.5, W0, H0,
                         cam.dist)
        W, H = parse_size(o.size, W0, H0)
        dist = np.asarray(cam.dist, dtype=np.float64)
        K0 = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1.0]])
        maps = (cv2.initUndistortRectifyMap(K0, dist, None, K0, (W0, H0), cv2.CV_32FC1)
                if dist.size and np.any(dist != 0) else None)
        geo.update(cam=cam, W=W, H=H, W0=W0, H0=H0, maps=maps)

        def conv(img):  # kept as uint8 (3 bytes a pixel): converted where the images are composed
            if maps is not None:
                img = cv2.remap(img, *maps, cv2.INTER_LINEAR)
            return _resize(img, W, H)

        return conv

    def budget(n_keep: int) -> None:
        """Refuse before keeping anything when the kept frames and masks would not fit in memory."""
        W, H, W0, H0 = geo["W"], geo["H"], geo["W0"], geo["H0"]
        per = W * H * (3 + 2)  # RGB and two masks, uint8
        # + the undistortion maps (two float32 planes) + transient buffers of a source frame (decoded RGB, its
        # remapped copy, a label image: 16 bytes a source pixel, generously)
        need = n_keep * per + (W0 * H0 * 8 if geo["maps"] is not None else 0) + 16 * W0 * H0
        try:
            check_memory(need, f"{video}: {n_keep} frames of {W}x{H} px")
        except ConfigError as e:
            from physar.output import available_memory

            side = 16 * max(1, int(max(W, H) * math.sqrt(0.5 * available_memory() / need) // 16))
            raise ConfigError(f"{e}; give a smaller --size (e.g. --size {side}: longer side in px) or a lower "
                              "--fps") from None

    clip = read_video(video, o.fps, prepare_frames, budget)
    frames, src_fps, n_src, idx, fps = clip.frames, clip.fps, clip.n_src, clip.indices, clip.out_fps
    cam, W, H, W0, H0, maps = (geo[k] for k in ("cam", "W", "H", "W0", "H0", "maps"))

    def prepare_mask(p: Path, m: np.ndarray) -> np.ndarray:
        if m.shape != (H0, W0):
            if abs(m.shape[1] / m.shape[0] - W0 / H0) > 0.01 * W0 / H0:
                raise ConfigError(f"{p}: mask size {m.shape[1]}x{m.shape[0]} px does not match the video's "
                                  f"{W0}x{H0} px")
            m = cv2.resize(m, (W0, H0), interpolation=cv2.INTER_NEAREST)
        if maps is not None:
            m = cv2.remap(m, *maps, cv2.INTER_NEAREST)
        return (_resize(m, W, H) >= 0.5).astype(np.uint8)  # {0, 1}

    wanted = set(idx.tolist())
    keep = lambda i, n: n != n_src or i in wanted
    if masks is not None:
        mfiles, mdict = read_masks(masks, o.person_labels, o.object_labels, o.ignore_labels, keep, prepare_mask)
    else:
        mfiles, mdict = read_binary_masks(person_masks, object_masks, keep, prepare_mask)
    midx = _count_match(len(mfiles), n_src, idx, "mask PNGs", masks if masks is not None else person_masks, video,
                        mfiles)
    n_pose = len(smpl["transl"])
    if n_pose not in (n_src, len(idx)) and smpl.get("fps"):  # a mocap sequence at its own rate (AMASS)
        pidx = mocap_indices(smpl["fps"], n_pose, src_fps, idx, poses, video)
    else:
        pidx = _count_match(n_pose, n_src, idx, "poses", poses, video)
    n_out = len(idx)
    if o.fps is not None and n_out < n_src and n_out < 3 + max(o.spin_frames, 0):
        raise ConfigError(f"--fps {o.fps:g}: keeps {n_out} of the {n_src} frames of {video} ({src_fps:g} fps); the "
                          f"clip needs >= {3 + max(o.spin_frames, 0)} (3 dynamic + --spin-frames {o.spin_frames})")
    if o.spin_frames < 0 or (o.spin_frames and o.spin_frames < 2) or n_out - o.spin_frames < 3:
        raise ConfigError(f"--spin-frames {o.spin_frames}: needs 0 or >= 2 and leaves {n_out - o.spin_frames} of "
                          f"{n_out} frames for the dynamic clip (needs >= 3)")
    n_dyn = n_out - o.spin_frames
    n_obs = o.n_obs if o.n_obs is not None else min(n_dyn - 1, max(2, round(0.75 * n_dyn)))
    if not 2 <= n_obs <= n_dyn - 1:
        raise ConfigError(f"--n-obs {n_obs} must be in [2, {n_dyn - 1}] (dynamic clip of {n_dyn} frames)")
    # ---- world frame, object, domain (q: the rotated camera frame, world axes and camera origin, p_C = R q)
    R = world_rotation(o.up)
    if spin_cams is None:
        V, T = read_mesh(object_mesh)
        V = V * MESH_UNITS[o.mesh_units]  # camera coordinates in the mesh's unit: positions and sizes scale alike
        holes = open_edges(V, T)
        if holes:
            warnings.warn(f"{object_mesh}: the mesh is not closed ({holes} edges border one face only): its inside "
                          "is estimated by the winding number, which holes make uncertain; a watertight mesh gives "
                          "the exact volume", PhysarWarning, stacklevel=2)
        Vw = V @ R  # rows: q = R^T v
        lo, hi = Vw.min(0), Vw.max(0)
        ext = hi - lo
        if not np.all(np.isfinite(ext)) or ext.max() > MAX_OBJECT_EXTENT:
            unit = {"m": "metres", "cm": "centimetres", "mm": "millimetres"}[o.mesh_units]
            raise ConfigError(f"{object_mesh}: the mesh spans {np.round(ext, 3).tolist()} m (read in {unit}), more "
                              f"than {MAX_OBJECT_EXTENT:g} m: is it in other units? give --mesh-units mm or cm")
        size = float(o.domain_size) if o.domain_size is not None else float(2 * ext.max())
        if not (size > 1.05 * ext[:2].max() and size > 1.05 * ext[2]):
            raise ConfigError(f"--domain-size {size:g} m: give at least {1.05 * ext.max():.3g} m (1.05 x the "
                              f"object's extent {np.round(ext, 3).tolist()} m, mesh {object_mesh})")
        cell = size / o.grid_resolution
        boxes = voxel_boxes(Vw, T, cell, lo)
        if not boxes:
            raise ConfigError(f"{object_mesh}: no voxel of {cell:.3f} m lies inside the mesh (is it closed, in metres?)")
    else:
        sx, sy = W / W0, H / H0
        Kout = np.array([[cam.fx * sx, 0, (cam.cx + 0.5) * sx - 0.5], [0, cam.fy * sy, (cam.cy + 0.5) * sy - 0.5],
                         [0, 0, 1.0]])  # OpenCV convention at the output size
        views = [(Kout, Ri, ti, mdict[midx[k]][1] > 0) for k, (Ri, ti) in enumerate(zip(*spin_cams))]
        cell0 = None if o.domain_size is None else float(o.domain_size) / o.grid_resolution
        occ, glo, cell = carve_hull(views, R, cell0, resolution=o.grid_resolution)
        boxes = runs_to_boxes(occ, glo, cell)
        size = cell * o.grid_resolution
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)
    ext = hi - lo
    if not (math.isfinite(size) and size > 1.05 * ext[:2].max() and size > 1.05 * ext[2]):
        raise ConfigError(f"--domain-size {size:g} m: give at least {1.05 * ext.max():.3g} m (1.05 x the object's "
                          f"extent {np.round(ext, 3).tolist()} m)")
    org = np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]])
    t = R @ org  # p_C = R (p_W + org) = R p_W + t
    boxes = [(a - org, b - org) for a, b in boxes]
    blo = np.min([b[0] for b in boxes], axis=0)
    bhi = np.max([b[1] for b in boxes], axis=0)
    pose = retarget(smpl, body, R, t, o.pelvis_offset)
    rot, root_t = pose["rotations"][pidx], pose["root_translation"][pidx]
    meta = {
        "format_version": S.FORMAT_VERSION, "kind": "physar.recon imported scene",
        "fps": fps, "frames": n_dyn, "n_obs": int(n_obs), "novel_frames": 0,
        "camera": cam.scene_camera(W, H, R, t), "background": [float(c) for c in o.background],
        "body": {"model": body_spec, "kind": "procedural_humanoid" if body_spec == "capsule" else "mesh",
                 "height": float(o.height), "simulated_bones": [],
                 "E": float(o.body_E), "density": float(o.body_density)},
        "object": {"shape": "box_union", "kind": "mesh" if spin_cams is None else "visual_hull", "action": "unknown", "min": blo.tolist(), "max": bhi.tolist(),
                   "boxes": [[a.tolist(), b.tolist()] for a, b in boxes], "parts": ["object"],
                   "density": float(o.density), "nu": float(o.nu), "material": "fixed_corotated"},
        "sim": {"size": size, "resolution": int(o.grid_resolution), "substeps": int(o.substeps),
                "origin": [-size / 2, -size / 2, 0.0], "gravity": [0.0, 0.0, -9.81],
                "walls": {**{k: "slip" for k in ("x_min", "x_max", "y_min", "y_max", "z_max")}, "z_min": o.floor},
                "kp": 3.0e3, "kd": 110.0},
        "import": {"video": str(video), "source_fps": src_fps, "source_frames": n_src,
                   "source_variable_rate": bool(clip.variable),
                   "source_size": [W0, H0], "source_indices": idx.tolist(), "masks": None if masks is None else str(masks),
                   "person_masks": None if person_masks is None else str(person_masks),
                   "object_masks": _folder_names(object_masks), "poses": str(poses),
                   "object_mesh": None if object_mesh is None else str(object_mesh),
                   "spin_cameras": None if spin_cameras is None else str(spin_cameras), "up_camera": [float(v) for v in o.up],
                   "spin_frames": int(o.spin_frames), "pelvis_offset": [float(v) for v in o.pelvis_offset],
                   "mask_pixels": _mask_pixels(mdict, midx, n_out)},
    }
    # ---- images: the background outside the masks set to the renderer's constant colour
    bg = (np.clip(np.asarray(o.background, dtype=np.float64), 0, 1) * 255 + 0.5).astype(np.uint8)

    def composed(k: int) -> tuple[np.ndarray, np.ndarray]:  # (BGR, mask) uint8 of output frame k, made as written
        fg = mdict[midx[k]][0]
        rgb = np.where(fg[..., None] > 0, frames[k], bg)
        return cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), (fg > 0).astype(np.uint8) * 255

    sp = o.spin_frames if spin_cams is None else 0  # a moving camera's spin frames carve the hull, not written
    with atomic_folder(out, own=DATA_DIR_FILES) as tmp:
        (tmp / "scene.json").write_text(json.dumps(meta, indent=1))
        clips = [("", slice(o.spin_frames, n_out), "poses.npz")] + ([("spin", slice(0, sp), "spin_poses.npz")] if sp else [])
        for sub, sl, pname in clips:
            np.savez(tmp / pname, rotations=rot[sl], root_translation=root_t[sl])
            d = tmp / sub if sub else tmp
            (d / "rgb").mkdir(parents=True)
            (d / "mask").mkdir(parents=True)
            for f, k in enumerate(range(n_out)[sl]):
                bgr, fg = composed(k)
                cv2.imwrite(str(d / "rgb" / f"{f:04d}.png"), bgr)
                cv2.imwrite(str(d / "mask" / f"{f:04d}.png"), fg)
    return {"data_dir": str(out), "frames": n_dyn, "spin_frames": sp, "n_obs": int(n_obs), "fps": fps,
            "object": "mesh" if spin_cams is None else f"visual hull of {o.spin_frames} views",
            "size": [W, H], "body": body_spec, "object_boxes": len(boxes), "object_volume_m3": float(sum(np.prod(b - a) for a, b in boxes))}


# ----------------------------------------------------------------------------------------------- check
def _lost_masks(meta: dict, sj: Path) -> list[str]:
    """One problem line per label and clip whose mask is empty in some frames, from the import's per-frame pixel
    counts (``import.mask_pixels``; none for a DATA_DIR written otherwise): the object in any frame, the person
    in the dynamic clip (whose poses draw the body there)."""
    imp = meta.get("import") if isinstance(meta.get("import"), dict) else {}
    px, sp = imp.get("mask_pixels"), imp.get("spin_frames", 0)
    if not isinstance(px, dict) or not isinstance(sp, int):
        return []
    out = []
    for label in ("object", "person"):
        n = px.get(label)
        if not isinstance(n, list):
            continue
        n = np.asarray(n)
        for clip, sl in (("spin", slice(0, sp)), ("dynamic", slice(sp, None))):
            if label == "person" and clip == "spin":
                continue
            empty = np.flatnonzero(n[sl] == 0)
            if len(empty):
                out.append(f"{sj}: the {label}'s mask is empty in {len(empty)} of {len(n[sl])} {clip} frames "
                           f"({number_ranges(empty.tolist())}): a segmenter that lost the {label}? those frames are "
                           f"fitted as if it were hidden (mend the masks, or cut the clip)")
    return out


def check_dataset(data_dir: str | Path, max_jump_deg: float = 30.0, min_coverage: float = 0.001,
                  max_coverage: float = 0.99, max_root_speed: float = 5.0) -> dict:
    r"""Problems of a DATA_DIR, one line each (empty list: fine), and what was found: missing files; frame counts of
    rgb/, mask/ and the poses of each clip; per-frame mask coverage outside [``min_coverage``, ``max_coverage``];
    pose jitter (a bone's local rotation turning by more than ``max_jump_deg`` between frames:
    :math:`\arccos((\operatorname{tr}(L_{f}^\top L_{f+1}) - 1)/2)`, or the body's root moving faster than
    ``max_root_speed`` m/s: :math:`\|t_{f+1} - t_f\| \cdot` fps); camera intrinsics against the image size
    (size equal, principal point inside, :math:`0.1 W < f_x < 20 W`); whether a bone reaches the object; frames
    where the segmenter lost the object or the person (:func:`_lost_masks`, from an import's mask pixels)."""
    root = Path(data_dir)
    if not (math.isfinite(max_jump_deg) and 0 < max_jump_deg <= 180):
        raise ConfigError(f"--max-jump-deg must be in (0, 180] degrees, got {max_jump_deg}")
    if not (math.isfinite(max_root_speed) and max_root_speed > 0):
        raise ConfigError(f"--max-root-speed must be a positive speed [m/s], got {max_root_speed}")
    problems: list[str] = []
    info: dict = {"data_dir": str(root), "clips": {}}
    sj = root / "scene.json"
    if not root.is_dir():
        return {**info, "problems": [f"{root}: {'not a folder' if root.exists() else 'DATA_DIR not found'}"]}
    if not sj.is_file():
        return {**info, "problems": [f"{sj}: missing (not a recon DATA_DIR)"]}
    try:
        meta = json.loads(sj.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        return {**info, "problems": [f"{sj}: invalid JSON ({' '.join(str(e).split())[:80]})"]}
    miss = [k for k in ("camera", "sim", "body", "object", "n_obs", "fps") if k not in meta]
    if miss:
        return {**info, "problems": [f"{sj}: missing field '{k}'" for k in miss]}
    try:
        S.check_meta(meta, str(sj))
    except ConfigError as e:
        return {**info, "problems": [str(e)]}
    cam = meta["camera"]
    try:
        body = S.load_body(meta, str(sj))
    except ConfigError as e:
        return {**info, "problems": [str(e)]}
    nb = body.skeleton.n_bones
    all_rot = []
    off: dict[str, list] = {}  # image size -> files whose size is not the camera's
    for name, sub, pname in (("dynamic", "", "poses.npz"), ("spin", "spin", "spin_poses.npz"),
                             ("novel", "novel", "novel_poses.npz")):
        d = root / sub if sub else root
        pfile = root / pname
        if name != "dynamic" and not pfile.exists() and not d.exists():
            continue
        c = info["clips"][name] = {}
        rot = None
        if not pfile.is_file():
            problems.append(f"{pfile}: missing")
        else:
            try:
                with np.load(pfile, allow_pickle=False) as z:
                    arr = {k: z[k] for k in z.files}
                rot, rt = S.check_poses(arr, nb, str(pfile))
                c["poses"] = len(rot)
                all_rot.append((rot, rt))
            except (ConfigError, ValueError, OSError, zipfile.BadZipFile) as e:
                if "pickle" in str(e):  # numpy's own message advises allow_pickle: never here
                    e = "not a readable .npz file (pickled or not an npz; refused, never unpickled)"
                problems.append(f"{pfile}: {e}" if str(pfile) not in str(e) else str(e))
        for kind in ("rgb", "mask"):
            folder = d / kind
            files = sorted(folder.glob("*.png")) if folder.is_dir() else []
            c[kind] = len(files)
            if not folder.is_dir():
                problems.append(f"{folder}: missing")
                continue
            expect = [f"{f:04d}.png" for f in range(len(files))]
            if [p.name for p in files] != expect:
                problems.append(f"{folder}: frames must be 0000.png, 0001.png, ... without gaps")
            cover = []
            for p in files:
                try:
                    img = imread(p, cv2.IMREAD_GRAYSCALE if kind == "mask" else cv2.IMREAD_COLOR)
                except ConfigError as e:
                    problems.append(str(e))
                    continue
                if img is None:
                    problems.append(f"{p}: not a readable image")
                    continue
                if (img.shape[1], img.shape[0]) != (cam.get("width"), cam.get("height")):
                    off.setdefault(f"{img.shape[1]}x{img.shape[0]}", []).append(p)
                if kind == "mask":
                    cv_ = float((img >= 128).mean())
                    cover.append(cv_)
                    if cv_ < min_coverage:
                        problems.append(f"{p}: mask coverage {cv_:.4f}: empty (below {min_coverage})")
                    elif cv_ > max_coverage:
                        problems.append(f"{p}: mask coverage {cv_:.4f}: full (above {max_coverage})")
            if kind == "mask" and cover:
                c["mask_coverage_min"], c["mask_coverage_max"] = min(cover), max(cover)
        counts = {k: c[k] for k in ("rgb", "mask", "poses") if k in c}
        if len(set(counts.values())) > 1:
            problems.append(f"{d}: frame counts differ: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
        if rot is not None and len(rot) > 1:
            tr = np.einsum("fbij,fbij->fb", rot[:-1], rot[1:])  # tr(L_f^T L_{f+1})
            ang = np.degrees(np.arccos(np.clip((tr - 1) / 2, -1, 1)))
            c["max_joint_step_deg"] = float(ang.max())
            for f, b in zip(*np.nonzero(ang > max_jump_deg)):
                problems.append(f"{pfile}: pose jitter: bone {body.skeleton.names[b]} turns {ang[f, b]:.1f} deg "
                                f"between frames {f} and {f + 1} (above {max_jump_deg:g})")
            step = np.linalg.norm(np.diff(rt, axis=0), axis=1)
            fps = meta.get("fps")
            if isinstance(fps, (int, float)) and fps > 0:
                c["max_root_speed_m_s"] = float(step.max() * fps)
                for f in np.flatnonzero(step * fps > max_root_speed):
                    problems.append(f"{pfile}: pose jitter: the body's root moves {100 * step[f]:.1f} cm between "
                                    f"frames {f} and {f + 1} ({step[f] * fps:.1f} m/s at {fps:g} fps, above "
                                    f"{max_root_speed:g})")
    problems += _lost_masks(meta, sj)
    for wh, files in off.items():
        problems.append(f"{sj}: camera.width/height {cam.get('width')}x{cam.get('height')} px, but {len(files)} "
                        f"images are {wh} px (first: {files[0]})")
    if "dynamic" in info["clips"] and "poses" in info["clips"]["dynamic"]:
        n = info["clips"]["dynamic"]["poses"]
        if not isinstance(meta["n_obs"], int) or not 2 <= meta["n_obs"] <= n:
            problems.append(f"{sj}: n_obs = {meta['n_obs']} must be in [2, {n}]")
    try:
        fx, fy, cx, cy = (float(cam[k]) for k in ("fx", "fy", "cx", "cy"))
        W, H = int(cam["width"]), int(cam["height"])
        if not (0 <= cx <= W and 0 <= cy <= H):
            problems.append(f"{sj}: camera principal point ({cx:g}, {cy:g}) lies outside the {W}x{H} image")
        if not (0.1 * W < fx < 20 * W and 0.1 * H < fy < 20 * H):
            problems.append(f"{sj}: camera focal length fx {fx:g}, fy {fy:g} px is implausible for a {W}x{H} "
                            "image (field of view outside 3..160 deg)")
        Rm = np.asarray(cam["R"], dtype=np.float64)
        if Rm.shape != (3, 3) or np.abs(Rm.T @ Rm - np.eye(3)).max() > 1e-6:
            problems.append(f"{sj}: camera.R is not a rotation matrix")
    except (KeyError, TypeError, ValueError):
        problems.append(f"{sj}: camera needs fx, fy, cx, cy, width, height, R, t")
    if all_rot:
        try:
            boxes = S.object_boxes(meta)
            rot, rt = all_rot[0]
            dx = meta["sim"]["size"] / meta["sim"]["resolution"]
            reach = S.reaching_bones(body, rot, rt, boxes, dx)
            info["reaching_bones"] = reach
            if not reach and not meta["body"].get("simulated_bones"):
                problems.append(f"{sj}: no bone of the body comes within {dx:.3f} m of the object in the dynamic clip "
                                "(poses, camera or object placement wrong?)")
            elif reach:  # the bones `recon fit` simulates: those whose particles stay in the MPM domain
                bones, leaving = S.simulated_bones(body, meta, rot, rt, dx, dx, reaching=reach)
                info["simulated_bones"], info["kinematic_bones"] = bones, list(leaving)
                if not bones:
                    problems.append(f"{sj}: " + S.domain_problem(body, meta, leaving, rot, rt, dx))
        except (ConfigError, KeyError, TypeError, ValueError) as e:
            problems.append(f"{sj}: object/sim: {e}")
    info["problems"] = problems
    return info


__all__ = ["ImportOptions", "Intrinsics", "carve_hull", "check_dataset", "import_video", "load_smpl", "retarget"]
