"""physar.media: the video decoding every layer shares. Clips are written here with PyAV (libx264 / FFV1), the
display rotation set with PyAV's own ``set_display_rotation`` (documented counter-clockwise); the expected
displayed images are written out by hand (which corner a quarter turn moves a block to), not by np.rot90."""
from fractions import Fraction
from types import SimpleNamespace

import av
import numpy as np
import pytest

from physar import media
from physar.errors import PhysarError

W, H = 64, 32  # stored size: landscape


def pattern(w=W, h=H, corner="tl") -> np.ndarray:
    """Dark BGR frame with a white 16x16 block in one corner (tl, tr, bl, br)."""
    img = np.full((h, w, 3), 20, np.uint8)
    r = slice(0, 16) if corner[0] == "t" else slice(h - 16, h)
    c = slice(0, 16) if corner[1] == "l" else slice(w - 16, w)
    img[r, c] = 235
    return img


def write_clip(path, frames, *, rate=30, rotation=None, pts_ms=None, fmt=None, codec="libx264", pix="yuv420p"):
    """Encode BGR ``frames`` into ``path``; ``pts_ms``: presentation times in ms (variable frame rate)."""
    with av.open(str(path), "w", format=fmt) as c:
        s = c.add_stream(codec, rate=None if pts_ms is not None else rate)
        s.width, s.height, s.pix_fmt = frames[0].shape[1], frames[0].shape[0], pix
        if codec == "libx264":
            s.options = {"crf": "12", "preset": "ultrafast"}
        if pts_ms is not None:
            s.codec_context.time_base = Fraction(1, 1000)
            s.time_base = Fraction(1, 1000)
        if rotation is not None:
            s.set_display_rotation(rotation)
        for i, img in enumerate(frames):
            f = av.VideoFrame.from_ndarray(img, format="bgr24")
            if pts_ms is not None:
                f.pts, f.time_base = int(pts_ms[i]), Fraction(1, 1000)
            for p in s.encode(f):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path


def white_corner(img) -> str:
    """Which corner of ``img`` holds the white block (checked: exactly one is bright, the centre is dark)."""
    h, w = img.shape[:2]
    g = img if img.ndim == 2 else img.mean(-1)
    c = {"tl": g[:8, :8], "tr": g[:8, -8:], "bl": g[-8:, :8], "br": g[-8:, -8:]}
    bright = [k for k, v in c.items() if v.mean() > 150]
    assert len(bright) == 1 and g[h // 2 - 2:h // 2 + 2, w // 2 - 2:w // 2 + 2].mean() < 80, {k: v.mean() for k, v in c.items()}
    return bright[0]


def decode(path):
    with av.open(str(path)) as c:
        return list(c.decode(c.streams.video[0]))


@pytest.mark.parametrize("degrees,corner", [(90, "bl"), (-90, "tr"), (180, "br"), (0, "tl")])
def test_frames_come_out_as_displayed(tmp_path, degrees, corner):
    # A counter-clockwise quarter turn moves the top-left corner to the bottom-left (and the picture becomes
    # portrait); clockwise: to the top-right; a half turn: to the bottom-right.
    # mutant caught: upright() leaving the stored picture (k = 0), or turning the other way (np.rot90(img, -k))
    p = write_clip(tmp_path / "r.mp4", [pattern()] * 3, rotation=degrees)
    frames = decode(p)
    assert media.rotation_of(frames[0]) == degrees % 360
    bgr, y = media.to_bgr(frames[0], "opencv")
    rgb = media.to_rgb(frames[0])
    portrait = degrees % 180 != 0
    assert bgr.shape == ((W, H, 3) if portrait else (H, W, 3)) and media.displayed_size(frames[0]) == (
        (H, W) if portrait else (W, H))
    assert white_corner(bgr) == white_corner(rgb) == white_corner(y) == corner
    assert y.shape == bgr.shape[:2] and bgr.flags.c_contiguous


def _ts(path, parts):
    """MPEG-TS files of the sizes in ``parts`` ((w, h, n frames)) concatenated byte by byte into ``path``."""
    data = b""
    for i, (w, h, n) in enumerate(parts):
        q = write_clip(path.with_suffix(f".{i}.ts"), [pattern(w, h)] * n, fmt="mpegts")
        data += q.read_bytes()
    path.write_bytes(data)
    return path


def test_a_size_change_names_file_frame_and_both_sizes(tmp_path):
    # mutant caught: Checked not comparing each frame's size with the first's (frames 5.. pass silently)
    p = _ts(tmp_path / "cat.ts", [(64, 32, 5), (32, 16, 5)])
    with av.open(str(p)) as c:
        ch = media.Checked(c.decode(c.streams.video[0]), p)
        got = []
        with pytest.raises(media.VideoChanged) as e:
            for f in ch:
                got.append(f.width)
    assert got == [64] * 5 and ch.count == 5
    assert str(e.value) == (f"{p}: frame 5 is 32x16 px but frames 0-4 are 64x32 px (the video changes resolution "
                            "mid-stream; cut it there or convert it to one size)")
    assert isinstance(e.value, PhysarError)


def _checked(t0, t_last, count, name="v.mkv"):
    return SimpleNamespace(first_time=t0, last_time=t_last, count=count, name=name)


def test_shortfall_compares_the_decoded_span_with_the_header():
    # 27 frames at 30 fps decoded from 1/15 s to 0.933 s of a 2.0 s file: span 0.9 s (frag MP4 cut at 70 %)
    # mutant caught: no shortfall check (the truncated file ends silently)
    assert media.shortfall(_checked(1 / 15, 0.9333, 27), 2.0, 30.0) == \
        "v.mkv: decoded 0.9 s (27 frames) of a 2.0 s video (truncated?)"
    # within 2.5 frames of the header: a whole file (last frame at 1.967 s of 2.0 s; 2 frames missing)
    assert media.shortfall(_checked(0.0, 1.967, 60), 2.0, 30.0) is None
    assert media.shortfall(_checked(0.0, 1.967 - 2 / 30, 58), 2.0, 30.0) is None
    assert media.shortfall(_checked(0.0, 1.967 - 3 / 30, 57), 2.0, 30.0) is not None
    # a header counting the start offset (Matroska starting at 10 s says 11.98 s): the end time matches
    assert media.shortfall(_checked(10.0, 11.947, 60), 11.98, 30.0) is None
    assert media.shortfall(_checked(None, None, 60), 2.0, 30.0) is None  # no timestamps: nothing to compare


def test_truncated_matroska_is_reported(tmp_path):
    # mutant caught: duration_of ignoring the container's duration (Matroska streams carry none)
    frames = [pattern(corner=c) for c in ("tl", "tr", "bl", "br") * 15]
    full = write_clip(tmp_path / "full.mkv", frames, fmt="matroska", codec="ffv1", pix="yuv444p")
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(full.read_bytes()[: int(full.stat().st_size * 0.5)])
    with av.open(str(cut)) as c:
        st = c.streams.video[0]
        ch = media.Checked(c.decode(st), cut)
        n = sum(1 for _ in ch)
        dur = media.duration_of(c, st)
    assert dur == pytest.approx(2.0, abs=0.01) and 5 < n < 50
    assert media.shortfall(ch, dur, 30.0) == f"{cut}: decoded {n / 30:.1f} s ({n} frames) of a 2.0 s video (truncated?)"
