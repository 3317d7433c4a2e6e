"""`physar recon import` reads the mask formats segmenters write besides single-channel label PNGs: per-object
binary PNGs in two folders (SAM / SAM 2 / Track-Anything; 0/255, 0/1 or 16-bit, anti-aliased edges), RGB label
PNGs in the DAVIS / PASCAL VOC palette's colours; a frame count mismatch names the missing frame numbers.

References: the shapes drawn here (binary masks: the hard shape before the anti-aliased halo and the lossy
noise were added), the label arrays written here with the VOC colours typed in from the published palette
table (not computed), the label-PNG import of the same clip (`test_recon_import`'s `user` fixture), and the
frame numbers removed by hand.
"""

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image
from test_recon_import import _snapshot, cli, err_lines, hull_holds_the_box, imported, spin_views, user  # noqa: F401 - fixtures reused here

from physar.errors import ConfigError
from physar.mpm.io import mp4_encoder
from physar.recon import masks as M
from physar.recon.io import read_pngs, write_mp4

needs_mp4 = pytest.mark.skipif(mp4_encoder() is None, reason="PyAV has no MP4 encoder")

#: the DAVIS / PASCAL VOC palette as published (VOC2012 class colours: 15 person, 20 tv monitor, 255 void)
VOC = {0: (0, 0, 0), 1: (128, 0, 0), 2: (0, 128, 0), 3: (128, 128, 0), 4: (0, 0, 128), 5: (128, 0, 128),
       7: (128, 128, 128), 8: (64, 0, 0), 9: (192, 0, 0), 12: (64, 0, 128), 15: (192, 128, 128), 16: (0, 64, 0),
       20: (0, 64, 128), 255: (224, 224, 192)}


def soft(truth: np.ndarray, rng, top: int = 255) -> np.ndarray:
    """A segmenter's soft mask of the hard shape ``truth``: inside near ``top`` (lossy noise down to 97 %), a
    one-pixel inner edge at 51-98 % and an outer halo at 2-49 % (anti-aliasing), elsewhere 0-2 % noise: cut at
    half intensity it is ``truth`` again; cut at > 0 the halo and the noise enter."""
    k = np.ones((3, 3), np.uint8)
    t8 = truth.astype(np.uint8)
    edge = truth & ~(cv2.erode(t8, k) > 0)
    halo = (cv2.dilate(t8, k) > 0) & ~truth
    f = rng.uniform(0.0, 0.02, truth.shape)
    f[truth] = rng.uniform(0.97, 1.0, truth.sum())
    f[edge] = rng.uniform(0.51, 0.98, edge.sum())
    f[halo] = rng.uniform(0.02, 0.49, halo.sum())
    return np.round(f * top).astype(np.uint16 if top > 255 else np.uint8)


def save_mask(path: Path, truth: np.ndarray, kind: str, rng) -> None:
    """``truth`` written as one of the binary formats: soft 8-bit grey, 0/1 grey, soft 16-bit grey, soft grey
    saved as RGB, or a 0/1 palette PNG."""
    if kind == "grey":
        Image.fromarray(soft(truth, rng)).save(path)
    elif kind == "01":
        Image.fromarray(truth.astype(np.uint8), mode="L").save(path)
    elif kind == "16bit":
        Image.fromarray(soft(truth, rng, 65535)).save(path)
    elif kind == "rgb":
        Image.fromarray(np.repeat(soft(truth, rng)[..., None], 3, -1), mode="RGB").save(path)
    elif kind == "palette_white0":   # PIL's adaptive 2-colour palette puts white at index 0 (by frequency)
        q = Image.fromarray(np.where(truth, 0, 1).astype(np.uint8), mode="P")
        q.putpalette([255, 255, 255, 0, 0, 0] + [0] * 762)
        q.save(path)
    elif kind == "rgba_cutout":       # white everywhere, the mask in alpha (a cut-out)
        a = np.full(truth.shape + (4,), 255, np.uint8)
        a[..., 3] = soft(truth, rng)
        Image.fromarray(a, mode="RGBA").save(path)
    else:
        im = Image.fromarray(truth.astype(np.uint8), mode="P")
        im.putpalette([0, 0, 0, 255, 255, 255] + [0] * 762)
        im.save(path)


@pytest.mark.parametrize("kind", ["grey", "01", "16bit", "rgb", "palette", "palette_white0", "rgba_cutout"])
def test_binary_folders_give_the_thresholded_truth(tmp_path, kind):
    # 12 frames named 1.png .. 12.png (unpadded); frame i: a person disc at column 8 + 2i, an object bar i + 3 px
    # wide, overlapping the disc (none in frame 12: an empty mask; in 0/255 folders it holds three 1s, soft-mask
    # rounding); one binary format per folder. Mutants caught: foreground at > 0 (the halo and the noise enter),
    # the person and object folders swapped, names sorted as text (frames 10-12 read as 2-4), a palette read by
    # index (white at index 0: inverted), the alpha of a cut-out ignored (all foreground), the full intensity
    # decided per file (the three 1s of the empty frame read as a 0/1 mask's foreground)
    rng = np.random.default_rng(0)
    H, W = 24, 40
    yy, xx = np.mgrid[:H, :W]
    (tmp_path / "person").mkdir()
    (tmp_path / "object").mkdir()
    truth = []
    for i in range(12):
        p = (yy - 8) ** 2 + (xx - 8 - 2 * i) ** 2 <= 25
        o = np.zeros((H, W), bool)
        if i < 11:
            o[12:20, 10 : 13 + i] = True
        save_mask(tmp_path / "person" / f"{i + 1}.png", p, kind, rng)
        if i == 11 and kind == "grey":
            stray = np.zeros((H, W), np.uint8)
            stray[[3, 9, 15], [4, 20, 33]] = 1
            Image.fromarray(stray, mode="L").save(tmp_path / "object" / f"{i + 1}.png")
        else:
            save_mask(tmp_path / "object" / f"{i + 1}.png", o, kind, rng)
        truth.append((p | o, o))
    files, masks = M.read_binary_masks(tmp_path / "person", tmp_path / "object")
    assert [f.name for f in files] == [f"{i + 1}.png" for i in range(12)]
    for i, (fg, obj) in enumerate(truth):
        assert masks[i][0].dtype == np.float32
        assert np.array_equal(masks[i][0] > 0.5, fg), i
        assert np.array_equal(masks[i][1] > 0.5, obj), i


def test_binary_folder_problems(tmp_path):
    # one line each: an object folder short of frames 5 and 7 (named), frames of different sizes, a person
    # empty in every frame (its files hold 0-2 % noise). Mutants caught: the emptiness check removed, foreground
    # at > 0 (the noise makes the blank person non-empty)
    rng = np.random.default_rng(1)
    t = np.zeros((8, 8), bool)
    t[2:5, 2:5] = True
    for name in ("person", "object", "blank"):
        (tmp_path / name).mkdir()
    for i in range(10):
        save_mask(tmp_path / "person" / f"p_{i:03d}.png", t, "grey", rng)
        save_mask(tmp_path / "blank" / f"b_{i:03d}.png", np.zeros_like(t), "grey", rng)
        if i not in (5, 7):
            save_mask(tmp_path / "object" / f"o_{i:03d}.png", t, "01", rng)
    with pytest.raises(ConfigError, match=r"object: 8 object masks for 10 person masks \(.*person\): frame count "
                                          r"mismatch; object/ has no mask for frames 5, 7$"):
        M.read_binary_masks(tmp_path / "person", tmp_path / "object")
    save_mask(tmp_path / "object" / "o_005.png", t, "01", rng)
    save_mask(tmp_path / "object" / "o_007.png", np.zeros((8, 9), bool), "01", rng)
    with pytest.raises(ConfigError, match=r"o_007.png: object mask 9x8 px, but the person mask p_007.png of the "
                                          "same frame is 8x8 px"):
        M.read_binary_masks(tmp_path / "person", tmp_path / "object")
    save_mask(tmp_path / "object" / "o_007.png", t, "01", rng)
    with pytest.raises(ConfigError, match=r"blank: the person masks are empty \(all background\) in all 10 files"):
        M.read_binary_masks(tmp_path / "blank", tmp_path / "object")



def test_object_in_several_folders_is_their_union(tmp_path):
    # a pillow and a bag as SAM 2 saves them, one folder each (the bag empty in the first 4 frames: it enters
    # later), and a third folder that repeats one: the object is the union drawn here, frame by frame; each
    # folder's count, emptiness and repetition checked in one line naming it. Mutants caught: only the first
    # object folder read (the bag missing), the second folder's count unchecked (zip stops early: no error), the
    # emptiness checked on the union only (the blank folder passes)
    rng = np.random.default_rng(4)
    H, W = 16, 20
    for name in ("person", "pillow", "bag", "blank", "short"):
        (tmp_path / name).mkdir()
    truth = []
    for i in range(8):
        p, a, b = (np.zeros((H, W), bool) for _ in range(3))
        p[2:6, i:i + 4] = True
        a[8:12, 2:9] = True
        if i >= 4:
            b[10:15, 10 + i:14 + i] = True
        save_mask(tmp_path / "person" / f"{i:02d}.png", p, "grey", rng)
        save_mask(tmp_path / "pillow" / f"{i:02d}.png", a, "01", rng)
        save_mask(tmp_path / "bag" / f"{i:02d}.png", b, "grey", rng)
        save_mask(tmp_path / "blank" / f"{i:02d}.png", np.zeros((H, W), bool), "grey", rng)
        if i != 6:
            save_mask(tmp_path / "short" / f"{i:02d}.png", b, "grey", rng)
        truth.append((p | a | b, a | b))
    person = tmp_path / "person"
    _, masks = M.read_binary_masks(person, [tmp_path / "pillow", tmp_path / "bag"])
    for i, (fg, obj) in enumerate(truth):
        assert np.array_equal(masks[i][0] > 0.5, fg), i
        assert np.array_equal(masks[i][1] > 0.5, obj), i
    with pytest.raises(ConfigError, match=r"short: 7 object 2 masks for 8 person masks .*no mask for frames 6"):
        M.read_binary_masks(person, [tmp_path / "pillow", tmp_path / "short"])
    with pytest.raises(ConfigError, match=r"blank: the object 2 masks are empty \(all background\) in all 8 files"):
        M.read_binary_masks(person, [tmp_path / "pillow", tmp_path / "blank"])
    with pytest.raises(ConfigError, match=r"pillow: the same folder for the object 1's and the object 3's masks"):
        M.read_binary_masks(person, [tmp_path / "pillow", tmp_path / "bag", tmp_path / "pillow"])
    with pytest.raises(ConfigError, match=r"person: the same folder for the person's and the object's masks"):
        M.read_binary_masks(person, person)


def test_rgb_davis_colours_read_as_their_labels(tmp_path):
    # every colour of the typed-in table, in random places, and the same labels saved as RGBA. Mutants caught:
    # the palette's bit order reversed (label 1 would be (1, 0, 0): (128, 0, 0) is refused), red and blue swapped
    rng = np.random.default_rng(2)
    keys = np.array(sorted(VOC))
    lab = keys[rng.integers(0, len(keys), (20, 30))]
    rgb = np.array([VOC[k] for k in keys], np.uint8)[np.searchsorted(keys, lab)]
    Image.fromarray(rgb, mode="RGB").save(tmp_path / "a.png")
    Image.fromarray(np.concatenate([rgb, np.full((20, 30, 1), 255, np.uint8)], -1), mode="RGBA").save(tmp_path / "b.png")
    assert np.array_equal(M.read_label_png(tmp_path / "a.png"), lab)
    assert np.array_equal(M.read_label_png(tmp_path / "b.png"), lab)
    for k, c in VOC.items():
        assert tuple(M.VOC_PALETTE[k]) == c, k


def test_colour_off_the_palette_refused(tmp_path):
    # white (a binary mask saved as RGB) at 5 pixels and another colour at 2: the most frequent one is named with
    # its count. Mutant caught: colours matched to the nearest palette entry without the equality check
    lab = np.zeros((10, 10, 3), np.uint8)
    lab[2:4, 2:6] = VOC[1]
    lab[0, :5] = 255
    lab[9, :2] = (10, 20, 30)
    Image.fromarray(lab, mode="RGB").save(tmp_path / "m.png")
    with pytest.raises(ConfigError, match=r"m.png: colour \(255, 255, 255\) at 5 pixels is not a DAVIS / PASCAL "
                                          r"VOC palette colour .*; 1 other colours off the palette too"):
        M.read_label_png(tmp_path / "m.png")
    Image.fromarray(lab[..., :2], mode="LA").save(tmp_path / "la.png")
    with pytest.raises(ConfigError, match="la.png: mask mode LA is not a label image"):
        M.read_label_png(tmp_path / "la.png")


def test_missing_frame_numbers_named():
    # the frames of the names' numbering that no file carries, and numbers beyond them. Mutant caught: the
    # count-only message (empty clause)
    files = [Path(f"m/frame_{i:04d}.png") for i in range(18) if i not in (12, 13)]
    assert M.missing_frames(files, 18) == "; no mask for frames 12-13 (of 0-17, numbered as the names)"
    files = [Path(f"m/{i}.png") for i in range(1, 21)]  # 1-based, two more than the video
    assert M.missing_frames(files, 18) == "; masks numbered 19-20 have no frame (of 1-18, numbered as the names)"
    assert M.missing_frames([Path("a.png"), Path("b.png")], 3) == ""  # no numbers: nothing to say
    assert M.number_ranges(range(0, 30, 2)) == "0, 2, 4, 6, 8, 10, ... (15 in all)"


# ------------------------------------------------------------------------------------------- through the CLI
def _refused(args, tmp_path, *needles):
    before = _snapshot(tmp_path)
    r = cli(*args, "--out", tmp_path / "out")
    lines = err_lines(r)
    assert r.exit_code == 2, (r.output, r.exception)
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    assert all(n in lines[0] for n in needles), lines
    assert r.stdout == "" and not (tmp_path / "out").exists() and _snapshot(tmp_path) == before


def _binary_args(u, person, obj) -> list:
    args = list(u["args"])
    i = args.index("--masks")
    return args[:i] + ["--person-masks", person, "--object-masks", obj] + args[i + 2:]


def _binary_folders(u, root: Path) -> tuple[Path, Path]:
    """The user's label PNGs (person 1, object 2) split into two folders of soft binary masks named 0.png ..
    17.png (unpadded); frame 3 as 0/1 files."""
    rng = np.random.default_rng(3)
    person, obj = root / "person", root / "object"
    person.mkdir(parents=True)
    obj.mkdir()
    files = sorted((u["dir"] / "masks").iterdir())
    for i, f in enumerate(files):
        lab = np.asarray(Image.open(f))
        kind = "01" if i == 3 else "grey"
        save_mask(person / f"{i}.png", lab == 1, kind, rng)
        save_mask(obj / f"{i}.png", lab == 2, kind, rng)
    return person, obj


def _frames(d: Path, kind: str, gray: bool) -> np.ndarray:
    return np.concatenate([read_pngs(d / "spin" / kind, 4, gray), read_pngs(d / kind, 5, gray)])


@needs_mp4
def test_import_binary_folders_writes_the_label_import(user, imported, tmp_path):  # noqa: F811
    """--person-masks / --object-masks of soft binary PNGs: the DATA_DIR's masks and images equal those of the
    label-PNG import of the same clip (and the masks the generator's: IoU 1). Mutants caught: foreground at > 0
    (the halo widens every mask), names sorted as text (10.png after 1.png: frames 2-9 get later masks)."""
    person, obj = _binary_folders(user, tmp_path)
    out = tmp_path / "data"
    r = cli(*_binary_args(user, person, obj), "--out", out)
    assert r.exit_code == 0, (r.output, r.exception)
    m = _frames(out, "mask", True)
    assert np.array_equal(m, _frames(imported, "mask", True))
    assert np.array_equal(_frames(out, "rgb", False), _frames(imported, "rgb", False))
    assert np.array_equal(m > 0.5, user["mask"])
    meta = json.loads((out / "scene.json").read_text())["import"]
    assert (meta["masks"], meta["person_masks"], meta["object_masks"]) == (None, str(person), str(obj))



@needs_mp4
def test_import_object_split_over_two_folders(user, imported, tmp_path):  # noqa: F811
    """The object's binary masks split into its left and right halves (two --object-masks folders, as a
    segmenter that tracks two parts writes them): the DATA_DIR's masks equal the label-PNG import's, and
    scene.json records both folders. Mutant caught: only the first --object-masks folder read (half the object
    missing from every mask)."""
    person, obj = _binary_folders(user, tmp_path)
    left, right = tmp_path / "left", tmp_path / "right"
    left.mkdir()
    right.mkdir()
    for f in sorted(obj.iterdir()):
        m = np.asarray(Image.open(f))
        cols = np.flatnonzero(m.max(axis=0) > m.max() / 2)
        cut = (cols.min() + cols.max() + 1) // 2 if len(cols) else m.shape[1] // 2
        a, b = m.copy(), m.copy()
        a[:, cut:], b[:, :cut] = 0, 0
        Image.fromarray(a).save(left / f.name)
        Image.fromarray(b).save(right / f.name)
    args = _binary_args(user, person, left)
    i = args.index("--object-masks")
    args[i + 2:i + 2] = ["--object-masks", right]
    out = tmp_path / "data"
    r = cli(*args, "--out", out)
    assert r.exit_code == 0, (r.output, r.exception)
    assert np.array_equal(_frames(out, "mask", True), _frames(imported, "mask", True))
    meta = json.loads((out / "scene.json").read_text())["import"]
    assert meta["object_masks"] == [str(left), str(right)]


@needs_mp4
def test_import_rgb_davis_label_pngs(user, imported, tmp_path):  # noqa: F811
    """The user's label PNGs saved as RGB in the VOC colours (label 1 = (128, 0, 0), 2 = (0, 128, 0)): the
    same DATA_DIR masks as the palette PNGs. Mutant caught: the palette's bit order reversed (refused)."""
    rgbdir = tmp_path / "rgbmasks"
    rgbdir.mkdir()
    for f in sorted((user["dir"] / "masks").iterdir()):
        lab = np.asarray(Image.open(f))
        Image.fromarray(np.array([VOC[0], VOC[1], VOC[2]], np.uint8)[lab], mode="RGB").save(rgbdir / f.name)
    args = list(user["args"])
    args[args.index("--masks") + 1] = rgbdir
    r = cli(*args, "--out", tmp_path / "data")
    assert r.exit_code == 0, (r.output, r.exception)
    assert np.array_equal(_frames(tmp_path / "data", "mask", True), _frames(imported, "mask", True))
    lab = np.asarray(Image.open(rgbdir / "frame_00003.png")).copy()
    lab[0, :5] = 255
    Image.fromarray(lab, mode="RGB").save(rgbdir / "frame_00003.png")
    _refused(args, tmp_path, "frame_00003.png: colour (255, 255, 255) at 5 pixels is not a DAVIS / PASCAL VOC "
             "palette colour")


@needs_mp4
def test_mask_options_given_one_way(user, tmp_path):  # noqa: F811
    """--masks with --person-masks, neither, --person-masks alone, label options with binary masks: one line
    each, exit 2, nothing written. Mutant caught: the exclusivity check removed (--masks silently wins)."""
    person, obj = _binary_folders(user, tmp_path)
    args = list(user["args"])
    _refused([*args, "--person-masks", person, "--object-masks", obj], tmp_path,
             "give the masks one way: --masks DIR (label PNGs) or --person-masks DIR and --object-masks DIR")
    i = args.index("--masks")
    bare = args[:i] + args[i + 2:]
    _refused(bare, tmp_path, "give the masks: --masks DIR (label PNGs), or --person-masks DIR and --object-masks")
    _refused([*bare, "--person-masks", person], tmp_path, "--person-masks needs --object-masks DIR too")
    _refused([*_binary_args(user, person, obj), "--person-labels", "3"], tmp_path,
             "--person-labels names values of --masks label PNGs")
    _refused(_binary_args(user, person, tmp_path / "nope"), tmp_path, "nope: object masks folder not found")


@needs_mp4
def test_frame_count_mismatch_names_the_missing_frames(user, tmp_path):  # noqa: F811
    """Masks of frames 12 and 13 removed: the error names them; two extra masks (18, 19): named too; binary
    folders likewise, by the person folder. Mutant caught: the old count-only message."""
    gap = tmp_path / "gap"
    shutil.copytree(user["dir"] / "masks", gap)
    for n in (12, 13):
        (gap / f"frame_{n:05d}.png").unlink()
    args = list(user["args"])
    args[args.index("--masks") + 1] = gap
    _refused(args, tmp_path, "gap: 16 mask PNGs for 18 video frames (",
             "frame count mismatch; no mask for frames 12-13 (of 0-17, numbered as the names)")
    more = tmp_path / "more"
    shutil.copytree(user["dir"] / "masks", more)
    for n in (18, 19):
        shutil.copy(more / "frame_00000.png", more / f"frame_{n:05d}.png")
    args[args.index("--masks") + 1] = more
    _refused(args, tmp_path, "more: 20 mask PNGs for 18 video frames (", "masks numbered 18-19 have no frame")
    person, obj = _binary_folders(user, tmp_path / "bin")
    (person / "7.png").unlink()
    (obj / "7.png").unlink()
    _refused(_binary_args(user, person, obj), tmp_path, "person: 17 mask PNGs for 18 video frames",
             "no mask for frames 7 (of 0-17")


@needs_mp4
def test_visual_hull_from_binary_object_masks(user, tmp_path):  # noqa: F811
    """The spin clip of `test_recon_import`'s hull test (8 views of the object from a circling camera, a 6 px
    ring of the person's hands around it) given as binary folders: the hull carved from the object folder holds
    the true box (>= 97 % of a 1 cm lattice of it shrunk by half a voxel) and not much more (1.0-1.6 x its
    volume). Mutant caught: the person and object folders swapped where import_video passes them (the hull of
    the hands' ring misses the box)."""

    rng = np.random.default_rng(4)
    R0 = user["R"]
    frames, ms, rings, Rs, ts = spin_views(user)
    masks = [(ring & ~m, m) for m, ring in zip(ms, rings)]
    up2 = lambda a: np.repeat(np.repeat(a, 2, 0), 2, 1)
    ns = user["ns"]
    for f, m in zip(user["rgb"][ns:], user["mask"][ns:]):
        frames.append(up2((f * 255 + 0.5).astype(np.uint8)))
        masks.append((up2(m), np.zeros((64, 64), bool)))
    assert write_mp4(tmp_path / "v.mp4", frames, 30.0)
    for name in ("p", "o"):
        (tmp_path / name).mkdir()
    for i, (p, o) in enumerate(masks):
        save_mask(tmp_path / "p" / f"{i:04d}.png", p, "grey", rng)
        save_mask(tmp_path / "o" / f"{i:04d}.png", o, "grey", rng)
    s = dict(np.load(user["dir"] / "smpl.npz"))
    pick = [2 * ns] * 8 + [2 * f for f in range(ns, len(user["rgb"]))]
    np.savez(tmp_path / "p.npz", **{k: v[pick] for k, v in s.items()})
    np.savez(tmp_path / "cams.npz", R=np.array(Rs), t=np.array(ts))
    up = ",".join(repr(float(v)) for v in R0[:, 2])
    out = tmp_path / "d"
    r = cli("recon", "import", tmp_path / "v.mp4", "--out", out, "--person-masks", tmp_path / "p", "--object-masks",
            tmp_path / "o", "--poses", tmp_path / "p.npz", "--camera", user["dir"] / "camera.toml", f"--up={up}",
            "--spin-cameras", tmp_path / "cams.npz", "--spin-frames", 8, "--n-obs", 3, "--size", 32)
    assert r.exit_code == 0, (r.output, r.exception)
    hull_holds_the_box(user, json.loads((out / "scene.json").read_text()))


def test_same_folder_twice_and_binary_masks_as_labels(tmp_path):
    # the person's folder given as the object's too: refused (it imported the whole person as the object);
    # 0/255 binary masks given to --masks: the refusal points to --person-masks / --object-masks
    t = np.zeros((8, 8), bool)
    t[2:5, 2:5] = True
    (tmp_path / "p").mkdir()
    for i in range(3):
        Image.fromarray(t.astype(np.uint8) * 255, mode="L").save(tmp_path / "p" / f"{i}.png")
    with pytest.raises(ConfigError, match=r"the same folder for the person's and the object's masks"):
        M.read_binary_masks(tmp_path / "p", tmp_path / "p" / ".." / "p")
    with pytest.raises(ConfigError, match=r"0.png: label value 255 is neither .*: binary masks \(one object per "
                                          r"file\)\? give --person-masks DIR and --object-masks DIR"):
        M.read_masks(tmp_path / "p", [1], [2])


def test_two_masks_of_one_frame_are_named():
    # 00001.png and 00001_1.png (a second object's mask of frame 1): the count mismatch names them. Mutant: the
    # clause left empty when two names share a number
    files = [Path(f"{n}.png") for n in ("00000", "00001", "00001_1", "00002")]
    assert M.missing_frames(files, 3).startswith("; 00001.png and 00001_1.png carry the same frame number 1")
