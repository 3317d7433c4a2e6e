"""`physar recon import` on users' own videos: a phone's rotated clip (masks drawn on the displayed frames), a
variable frame rate (resampled by timestamp: the expected source frames are the nearest ones, worked out by hand
below), a resolution change mid-stream, a truncated file, and a clip too large for memory (refused before
decoding it, with a smaller --size to try). Clips are written here with PyAV."""
import sys
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

import physar.output
from physar.errors import PhysarWarning
from physar.media import VideoChanged
from physar.recon import importer as I

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_media import H, W, _ts, pattern, white_corner, write_clip
from test_recon_import import cli, err_lines, imported, user  # noqa: F401 - its fixtures, reused here

PTS = [0, 100, 120, 140, 300, 320, 340, 500, 520, 540, 700, 720]  # ms: bursts of three, 160 ms gaps


def _levels(n):
    """Grey frames whose level tells the source index: 15 + 20 i."""
    return [np.full((32, 48, 3), 15 + 20 * i, np.uint8) for i in range(n)]


def _index(img) -> int:
    return round((float(img.mean()) - 15) / 20)


def test_rotated_clip_is_read_as_displayed(tmp_path):
    # mutant caught: read_video decoding the stored (sideways) picture
    clip = I.read_video(write_clip(tmp_path / "r.mp4", [pattern()] * 4, rotation=90))
    assert clip.size == (H, W) and clip.frames[0].shape == (W, H, 3)
    assert [white_corner(f) for f in clip.frames] == ["bl"] * 4


def test_variable_frame_rate_is_resampled_by_timestamp(tmp_path):
    # output times k / 10 s, k = 0..7 (<= 0.72 s); nearest source times:
    #   0 -> 0, .1 -> .1 (1), .2 -> .14 (3: .06 vs .1 away), .3 -> 4, .4 -> .34 (6), .5 -> 7, .6 -> .54 (9), .7 -> 10
    # mutant caught: VFR not detected (frames picked by index at the header's rate: the physics clock runs off)
    p = write_clip(tmp_path / "vfr.mkv", _levels(12), pts_ms=PTS, fmt="matroska", codec="ffv1", pix="yuv444p")
    clip = I.read_video(p, fps=10.0)
    assert clip.variable and clip.out_fps == 10.0 and clip.n_src == 12
    assert clip.indices.tolist() == [0, 1, 3, 4, 6, 7, 9, 10]
    assert [_index(f) for f in clip.frames] == [0, 1, 3, 4, 6, 7, 9, 10]
    # without --fps: its mean rate 11 frame intervals / 0.72 s, said in a warning
    with pytest.warns(PhysarWarning) as w:
        clip = I.read_video(p)
    assert clip.fps == clip.out_fps == pytest.approx(11 / 0.72)
    assert [str(x.message) for x in w] == [(
        f"{p}: variable frame rate (frame intervals 20-160 ms, median 20 ms): resampled by timestamp at its mean rate "
        "15.28 fps (set --fps to choose the rate)")]
    assert len(clip.frames) == 12 and clip.indices[0] == 0 and clip.indices[-1] == 11
    with pytest.raises(I.ConfigError, match=r"--fps 20.0 must be in \(0, 15.28\] \(the mean rate of this "
                                            r"variable-rate video; frames are not invented\)"):
        I.read_video(p, fps=20.0)


def test_constant_120_fps_on_a_millisecond_clock_is_not_variable(tmp_path):
    # Matroska stores times in 1 ms ticks: 120 fps reads back as 8, 8, 9 ms intervals, a spread of 12 % of the
    # median that is rounding, not a variable rate (it was resampled at 119.8 fps and --fps 120 refused).
    # mutant caught: the clock's tick ignored in the VFR test
    p = write_clip(tmp_path / "c120.mkv", _levels(12), rate=120, fmt="matroska", codec="ffv1", pix="yuv444p")
    clip = I.read_video(p, fps=120.0)
    assert not clip.variable and clip.fps == 120.0 and clip.indices.tolist() == list(range(12))


def test_constant_rate_clips_keep_the_index_rule(tmp_path):
    p = write_clip(tmp_path / "c.mkv", _levels(10), rate=30, fmt="matroska", codec="ffv1", pix="yuv444p")
    clip = I.read_video(p, fps=12.0)
    assert not clip.variable and clip.indices.tolist() == I.source_indices(10, 30.0, 12.0).tolist() == [0, 2, 5, 8]
    assert [_index(f) for f in clip.frames] == [0, 2, 5, 8]


def test_size_change_and_truncation(tmp_path):
    # mutant caught: read_video without the per-frame size check (a crash deep in the resize, or masks misplaced)
    p = _ts(tmp_path / "cat.ts", [(W, H, 5), (32, 16, 5)])
    with pytest.raises(VideoChanged, match=r"cat.ts: frame 5 is 32x16 px but frames 0-4 are 64x32 px"):
        I.read_video(p)
    full = write_clip(tmp_path / "full.mkv", [pattern(corner=c) for c in ("tl", "br") * 30], fmt="matroska",
                      codec="ffv1", pix="yuv444p")
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(full.read_bytes()[: full.stat().st_size // 2])
    with pytest.warns(PhysarWarning, match=r"cut.mkv: decoded \d\.\d s \(\d+ frames\) of a 2.0 s video \(truncated\?\)"):
        clip = I.read_video(cut)
    assert 5 < clip.n_src < 50 and clip.frames[0].dtype == np.uint8


def _rotated_copy(src: Path, dst: Path) -> Path:
    """The clip's frames stored turned clockwise with a 90 deg (counter-clockwise) display matrix: it plays
    exactly as ``src``, as a phone's portrait clip does."""
    with av.open(str(src)) as c:
        st = c.streams.video[0]
        rate = st.average_rate
        frames = [f.to_ndarray(format="bgr24") for f in c.decode(st)]
    # np.rot90(k=-1) turns clockwise; checked on a marked frame so that the test does not trust np.rot90's sign
    mark = np.zeros((4, 6), np.uint8)
    mark[0, 0] = 1
    assert np.rot90(mark, -1)[0, -1] == 1  # top-left -> top-right: clockwise
    write_clip(dst, [np.ascontiguousarray(np.rot90(f, -1)) for f in frames], rate=rate, rotation=90)
    return dst


def test_rotated_phone_clip_imports_like_the_upright_one(user, imported, tmp_path):  # noqa: F811
    # masks were drawn on the displayed frames; the import of the rotated copy must equal the upright import
    # mutant caught: the importer decoding stored pictures (frames turned against the masks)
    rot = _rotated_copy(user["dir"] / "clip.mp4", tmp_path / "portrait.mp4")
    args = list(user["args"])
    args[args.index(user["dir"] / "clip.mp4")] = rot
    r = cli(*args, "--out", tmp_path / "data")
    assert r.exit_code == 0, (r.output, r.exception)
    for sub in ("rgb", "spin/rgb"):
        ref = sorted((imported / sub).glob("*.png"))
        got = sorted((tmp_path / "data" / sub).glob("*.png"))
        assert len(got) == len(ref) > 0
        err = max(np.abs(cv2.imread(str(a)).astype(int) - cv2.imread(str(b)).astype(int)).mean()
                  for a, b in zip(ref, got))
        assert err < 4.0, err  # two lossy encodings of the same frames; a turned frame differs by tens


def test_clip_too_large_for_memory_is_refused_with_a_size_to_try(user, tmp_path, monkeypatch):  # noqa: F811
    # 9 output frames of 32x32 px (the fixture's 18 at 60 fps, --fps 30, --size 32): 9 * 32 * 32 * 5 bytes kept
    # (uint8 RGB and two masks) + 16 bytes per 64x64 source pixel of decoding buffers = 111,616 bytes > 50,000
    # mutant caught: no estimate before decoding (the job runs into swap / the OOM killer)
    monkeypatch.setattr(physar.output, "available_memory", lambda: 50_000)
    r = cli(*user["args"], "--out", tmp_path / "out")
    lines = err_lines(r)
    assert r.exit_code == 2 and len(lines) == 1, r.output
    clip = user["dir"] / "clip.mp4"
    assert lines[0] == (f"error: {clip}: 9 frames of 32x32 px needs about {111616 / 2**20:.3g} MiB of memory, more "
                        f"than the {50000 / 2**20:.3g} MiB available; give a smaller --size (e.g. --size 16: longer "
                        "side in px) or a lower --fps")
    assert not (tmp_path / "out").exists()
