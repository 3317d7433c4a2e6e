"""Segmentation masks as users' tools write them (seed 002's inputs: the person's and the object's silhouettes).

One PNG per frame, in frame order (:func:`physar.media.frame_order`), in one of two layouts: label PNGs (palette
or grey ids, or RGB in the DAVIS / PASCAL VOC palette's colours) read by :func:`read_masks`, or one folder of
binary PNGs per object (SAM / SAM 2 style, anti-aliased edges cut at half intensity) read by
:func:`read_binary_masks`. Every reader refuses a bad file in one line naming it; the format details are in
:mod:`physar.recon.importer`'s module docstring.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from physar import media
from physar.errors import ConfigError


def voc_palette(n: int = 256) -> np.ndarray:
    """The DAVIS / PASCAL VOC palette, (n, 3) uint8: colour of label k by interleaving k's bits (bit 3i -> red,
    3i + 1 -> green, 3i + 2 -> blue, each placed from the top bit 7 - i down), so that 1 = (128, 0, 0),
    2 = (0, 128, 0), 3 = (128, 128, 0), 255 = (224, 224, 192)."""
    pal = np.zeros((n, 3), np.uint8)
    for k in range(n):
        c, rgb = k, [0, 0, 0]
        for j in range(8):
            for ch in range(3):
                rgb[ch] |= ((c >> ch) & 1) << (7 - j)
            c >>= 3
        pal[k] = rgb
    return pal


VOC_PALETTE = voc_palette()
_VOC_KEYS = (VOC_PALETTE.astype(np.int64) @ np.array([1 << 16, 1 << 8, 1]))  # packed 0xRRGGBB of label k
_VOC_ORDER = np.argsort(_VOC_KEYS)


def palette_labels(path: Path, rgb: np.ndarray) -> np.ndarray:
    """Labels (H, W) of an RGB label image (H, W, 3) whose every colour is a :data:`VOC_PALETTE` colour (each
    mapped back to its index); one ConfigError line naming the most frequent other colour and its pixel count."""
    packed = rgb[..., :3].astype(np.int64) @ np.array([1 << 16, 1 << 8, 1])
    keys = _VOC_KEYS[_VOC_ORDER]
    pos = np.minimum(np.searchsorted(keys, packed), len(keys) - 1)
    ok = keys[pos] == packed
    if not ok.all():
        bad, count = np.unique(packed[~ok], return_counts=True)
        c = int(bad[count.argmax()])
        more = f"; {len(bad) - 1} other colours off the palette too" if len(bad) > 1 else ""
        raise ConfigError(f"{path}: colour ({c >> 16}, {(c >> 8) & 255}, {c & 255}) at {int(count.max())} pixels is "
                          f"not a DAVIS / PASCAL VOC palette colour (label 1 = (128, 0, 0), 2 = (0, 128, 0), ...){more}: "
                          "RGB label PNGs must use the palette (binary masks: --person-masks / --object-masks)")
    return _VOC_ORDER[pos].astype(np.int64)


def read_label_png(path: Path) -> np.ndarray:
    """Integer labels (H, W) of a label PNG: palette (the indices, not the colours), grey (the values), or RGB(A)
    in the DAVIS / PASCAL VOC palette's colours (:func:`palette_labels`; alpha ignored)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            if im.mode in ("P", "L", "I", "I;16", "1"):
                return np.asarray(im).astype(np.int64)
            if im.mode in ("RGB", "RGBA"):
                return palette_labels(path, np.asarray(im.convert("RGB")))
            raise ConfigError(f"{path}: mask mode {im.mode} is not a label image (give palette or grey PNGs, one "
                              "integer id per pixel, or RGB PNGs in the DAVIS palette's colours)")
    except (UnidentifiedImageError, OSError, Image.DecompressionBombError):
        raise ConfigError(f"{path}: not a readable PNG") from None


def binary_values(path: Path) -> np.ndarray:
    r"""Intensity (H, W) int64 of a binary mask PNG: the grey value; for palette PNGs the colour of each index
    (its largest channel: a palette may put white at index 0); for colour PNGs the largest colour channel; with
    an alpha channel, the smaller of that and the alpha (a cut-out: white everywhere, the mask in alpha)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            if im.mode in ("1", "L", "I", "I;16"):
                return np.asarray(im).astype(np.int64)
            if im.mode == "P":
                im = im.convert("RGBA" if "transparency" in im.info else "RGB")
            if im.mode in ("LA", "RGB", "RGBA", "PA"):
                a = np.asarray(im).astype(np.int64)
                c = 1 if im.mode in ("LA", "PA") else 3
                v = a[..., :c].max(-1)
                return np.minimum(v, a[..., c]) if a.shape[-1] > c else v
            raise ConfigError(f"{path}: mask mode {im.mode} is not a binary mask (give grey, palette or RGB PNGs, "
                              "0 = background)")
    except (UnidentifiedImageError, OSError, Image.DecompressionBombError):
        raise ConfigError(f"{path}: not a readable PNG") from None


def binary_scale(top: int) -> int:
    """Full intensity of binary masks whose largest value is ``top``: 1 (0/1 masks), 255 (8-bit) or 65535."""
    return 1 if top <= 1 else 255 if top <= 255 else 65535


def read_binary_png(path: Path, scale: int | None = None) -> np.ndarray:
    r"""Foreground (H, W) bool of a binary mask PNG: :math:`v \ge s/2` with :math:`v` its intensity
    (:func:`binary_values`) and :math:`s` the full intensity (``scale``; default :func:`binary_scale` of the
    file's own largest value, :func:`read_binary_masks` takes one for the whole folder): anti-aliased or
    lossy-compressed edges are cut at half intensity, and an empty mask (all 0) is background."""
    v = binary_values(path)
    if scale is None:
        scale = binary_scale(int(v.max()) if v.size else 0)
    return 2 * v >= scale


def _png_files(folder: Path, what: str) -> list[Path]:
    if not folder.is_dir():
        raise ConfigError(f"{folder}: {what} folder not found")
    files = sorted((p for p in folder.iterdir() if p.suffix.lower() == ".png"), key=media.frame_order)
    if not files:
        raise ConfigError(f"{folder}: no PNG masks in the folder")
    return files


def read_masks(folder: str | Path, person_labels, object_labels, ignore_labels=(), keep=None,
               prepare=None) -> tuple[list[Path], dict]:
    r"""Label PNGs of ``folder`` (:func:`read_label_png`) in frame order (:func:`physar.media.frame_order`), each
    checked (one error line for a label value that is neither background (0), ignored, person nor object); the
    foreground masks :math:`[\ell \in P \cup O]` (float32 (H, W) in {0, 1}, through ``prepare`` when given) of the
    files whose index ``keep(i, n)`` accepts (all by default), by index, with the object's own masks:
    {i: (foreground, object)}. A person or object label that no file holds is an error (a wrong
    ``--person-labels`` / ``--object-labels``, or masks of another clip)."""
    folder = Path(folder)
    files = _png_files(folder, "masks")
    fg_labels = set(person_labels) | set(object_labels)
    known = fg_labels | {0} | set(ignore_labels)
    out = {}
    seen: set[int] = set()
    for i, p in enumerate(files):
        lab = read_label_png(p)
        vals = np.unique(lab)
        seen.update(int(v) for v in vals)
        bad = [int(v) for v in vals if int(v) not in known]
        if bad:
            hint = (": binary masks (one object per file)? give --person-masks DIR and --object-masks DIR"
                    if 255 in bad or 65535 in bad else "")
            raise ConfigError(f"{p}: label value {bad[0]} is neither background (0), person "
                              f"{sorted(person_labels)} nor object {sorted(object_labels)} (set --person-labels, "
                              f"--object-labels or --ignore-labels){hint}")
        if keep is None or keep(i, len(files)):
            m = np.isin(lab, sorted(fg_labels)).astype(np.float32)
            mo = np.isin(lab, sorted(object_labels)).astype(np.float32)
            out[i] = (prepare(p, m), prepare(p, mo)) if prepare is not None else (m, mo)
    for what, labels, option in (("person", person_labels, "--person-labels"),
                                 ("object", object_labels, "--object-labels")):
        if not seen & set(labels):
            raise ConfigError(f"{folder}: the {what} label(s) {sorted(labels)} appear in none of the {len(files)} "
                              f"masks (labels found: {sorted(seen)}); set {option}")
    return files, out


def object_folders(object_folder) -> list[Path]:
    """The object's mask folders as a list: one folder (a path), or several (a sequence: one per part or per
    object, as SAM / SAM 2 save one folder per tracked object); [] for None or an empty sequence."""
    if object_folder is None:
        return []
    if isinstance(object_folder, (str, Path)):
        return [Path(object_folder)]
    return [Path(f) for f in object_folder]


def read_binary_masks(person_folder: str | Path, object_folder, keep=None,
                      prepare=None) -> tuple[list[Path], dict]:
    r"""Per-object binary mask PNGs as SAM / SAM 2 / Track-Anything write them: one folder for the person, one for
    the object or one per object part (``object_folder``: a path or a sequence of paths, :func:`object_folders`),
    one PNG per frame each (:func:`read_binary_png`), paired in frame order (:func:`physar.media.frame_order`).
    Returns the person folder's files and, for the files whose index ``keep(i, n)`` accepts, {i: (foreground
    :math:`P \cup O`, object :math:`O`)} as float32 (H, W) in {0, 1} (through ``prepare`` when given), as
    :func:`read_masks` does; :math:`O` is the union of the object folders' foregrounds (as ``--object-labels 2,3``
    is for label PNGs). One full intensity per folder (:func:`binary_scale` of its largest value). One error line
    for a folder given twice, folders of different counts (naming the frame numbers one lacks), masks of one
    frame of different sizes, or a person or object folder empty in every frame."""
    objs = object_folders(object_folder)
    if not objs:
        raise ConfigError("no object masks folder given (--object-masks DIR)")
    folders = {"person": Path(person_folder)}
    for j, f in enumerate(objs):
        folders["object" if len(objs) == 1 else f"object {j + 1}"] = f
    seen: dict[Path, str] = {}
    for k, f in folders.items():
        r = f.resolve()
        if r in seen:
            raise ConfigError(f"{f}: the same folder for the {seen[r]}'s and the {k}'s masks (give each its own)")
        seen[r] = k
    files = {k: _png_files(f, f"{k} masks") for k, f in folders.items()}
    fp = files["person"]
    # one full intensity per folder: a 0/255 series whose empty frame holds a few 1s (soft-mask rounding) is not
    # a 0/1 mask there
    scale = {k: binary_scale(max(int(binary_values(f).max(initial=0)) for f in fs)) for k, fs in files.items()}
    okeys = [k for k in folders if k != "person"]
    for k in okeys:
        if len(files[k]) != len(fp):
            lack = _lacking(fp, files[k])
            raise ConfigError(f"{folders[k]}: {len(files[k])} {k} masks for {len(fp)} person masks "
                              f"({folders['person']}): frame count mismatch{lack}")
    out = {}
    found = dict.fromkeys(folders, False)
    for i, p in enumerate(fp):
        mp = read_binary_png(p, scale["person"])
        found["person"] |= bool(mp.any())
        mo = np.zeros_like(mp)
        for k in okeys:
            q = files[k][i]
            mk = read_binary_png(q, scale[k])
            if mk.shape != mp.shape:
                raise ConfigError(f"{q}: {k} mask {mk.shape[1]}x{mk.shape[0]} px, but the person mask {p.name} of "
                                  f"the same frame is {mp.shape[1]}x{mp.shape[0]} px")
            found[k] |= bool(mk.any())
            mo |= mk
        if keep is None or keep(i, len(fp)):
            m, o = (mp | mo).astype(np.float32), mo.astype(np.float32)
            q = files[okeys[0]][i]
            out[i] = (prepare(p, m), prepare(q, o)) if prepare is not None else (m, o)
    for what, ok in found.items():
        if not ok:
            raise ConfigError(f"{folders[what]}: the {what} masks are empty (all background) in all {len(fp)} files")
    return fp, out


def frame_number(path: Path) -> int | None:
    """The frame number a file's name carries: its last group of digits (``frame_00012.png`` -> 12); None
    without digits."""
    nums = re.findall(r"\d+", Path(path).stem)
    return int(nums[-1]) if nums else None


def _numbers(files) -> set[int] | None:
    nums = [frame_number(p) for p in files]
    return set(nums) if nums and None not in nums and len(set(nums)) == len(nums) else None


def _shared(files) -> str:
    """``"; 00001.png and 00001_1.png carry the same frame number 1 (...)"``: the first two files whose names
    carry one frame number (two masks of a frame, e.g. one per object), or empty."""
    seen: dict[int, Path] = {}
    for p in files:
        n = frame_number(p)
        if n is not None and n in seen:
            return (f"; {seen[n].name} and {Path(p).name} carry the same frame number {n} (one mask per frame "
                    "here: several objects per frame go in one label PNG, or in --person-masks / --object-masks)")
        if n is not None:
            seen[n] = Path(p)
    return ""


def number_ranges(nums, cap: int = 6) -> str:
    """``[3, 12, 13, 14, 20]`` -> ``"3, 12-14, 20"``; after ``cap`` runs ``", ... (N in all)"``."""
    runs: list[list[int]] = []
    for n in sorted(nums):
        if runs and n == runs[-1][1] + 1:
            runs[-1][1] = n
        else:
            runs.append([n, n])
    text = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:cap])
    return text + (f", ... ({len(nums)} in all)" if len(runs) > cap else "")


def _lacking(a: list[Path], b: list[Path]) -> str:
    """``"; no object mask for frames 12-13"``-style clause comparing the frame numbers of two folders' files
    (empty when a name carries no number or two share one)."""
    na, nb = _numbers(a), _numbers(b)
    if na is None or nb is None:
        return ""
    parts = []
    if na - nb:
        parts.append(f"{b[0].parent.name}/ has no mask for frames {number_ranges(na - nb)}")
    if nb - na:
        parts.append(f"{a[0].parent.name}/ has no mask for frames {number_ranges(nb - na)}")
    return "; " + ", ".join(parts) if parts else ""


def missing_frames(files: list[Path], n_frames: int) -> str:
    """``"; no mask for frames 12-13 (of 0-17, ...)"``-style clause: the numbers of ``n_frames`` frames counted from
    the smallest number in the names that no file carries, and the numbers beyond them (the numbering is said:
    a missing first frame cannot be told from a 1-based one); empty when a name carries no number or two share
    one."""
    nums = _numbers(files)
    if nums is None:
        return _shared(files)
    first = min(nums)
    want = set(range(first, first + n_frames))
    parts = []
    if want - nums:
        parts.append(f"no mask for frames {number_ranges(want - nums)}")
    if nums - want:
        parts.append(f"masks numbered {number_ranges(nums - want)} have no frame")
    return f"; {', '.join(parts)} (of {first}-{first + n_frames - 1}, numbered as the names)" if parts else ""


def check_mask_inputs(masks, person_masks, object_masks) -> None:
    """One ConfigError line unless the masks are given one way: ``masks`` (label PNGs) alone, or both
    ``person_masks`` and ``object_masks`` (binary PNGs; ``object_masks`` one folder or several,
    :func:`object_folders`); each given folder must exist."""
    objs = object_folders(object_masks)
    binary = person_masks is not None or bool(objs)
    if masks is not None and binary:
        raise ConfigError("give the masks one way: --masks DIR (label PNGs) or --person-masks DIR and --object-masks "
                          "DIR (binary PNGs), not both")
    if masks is None and not binary:
        raise ConfigError("give the masks: --masks DIR (label PNGs), or --person-masks DIR and --object-masks DIR "
                          "(binary PNGs, one folder per object)")
    if binary and (person_masks is None or not objs):
        have, lack = ("--person-masks", "--object-masks") if not objs else ("--object-masks", "--person-masks")
        raise ConfigError(f"{have} needs {lack} DIR too (one binary PNG per frame for each of person and object)")
    for folder, what in ((masks, "masks"), (person_masks, "person masks"), *((f, "object masks") for f in objs)):
        if folder is not None and not Path(folder).is_dir():
            raise ConfigError(f"{folder}: {what} folder not found")


__all__ = ["VOC_PALETTE", "binary_scale", "binary_values", "check_mask_inputs", "frame_number", "missing_frames", "number_ranges", "object_folders",
           "palette_labels",
           "read_binary_masks", "read_binary_png", "read_label_png", "read_masks", "voc_palette"]
