"""Users' own videos through the AR frame loop (physar.ar.runner.run_video, VideoReader, sources): a phone's
rotated clip, a variable frame rate, a resolution change mid-stream, a truncated file, an odd frame size. The
clips are written here with PyAV; expected numbers are the clips' own timestamps and sizes, written out."""
import csv
import sys
from dataclasses import dataclass, field
from pathlib import Path

import av
import numpy as np
import pytest

from physar.ar.runner import run_video
from physar.ar.sources import open_source
from physar.ar.video import VideoReader, VideoWriter
from physar.errors import ConfigError, PhysarError, PhysarWarning
from physar.media import VideoChanged
from physar.vision.camera import Camera

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from test_media import H, W, _ts, pattern, white_corner, write_clip


@dataclass
class Result:
    status: str = "tracking"
    latency_ms: float = 1.0
    stages_ms: dict = field(default_factory=dict)


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.reader(fh))[1:]


def _stored(path):
    """(width, height, frame count, display rotation) of a written video, as stored."""
    with av.open(str(path)) as c:
        fr = list(c.decode(c.streams.video[0]))
    return fr[0].width, fr[0].height, len(fr), fr[0].rotation


def test_rotated_phone_clip_runs_upright_against_a_portrait_camera(tmp_path):
    # stored 64x32 with a 90 deg (counter-clockwise) display matrix: shown 32x64, the top-left block bottom-left
    # mutant caught: VideoReader ignoring the rotation (refused as "64x32 but the camera is for 32x64")
    clip = write_clip(tmp_path / "portrait.mp4", [pattern()] * 4, rotation=90)
    seen = []

    def process(k, frame, draw):
        seen.append(white_corner(frame))
        return frame, Result()

    s = run_video(process, Camera.from_fov(H, W, 60), clip, tmp_path / "o.mp4", tmp_path / "o.csv",
                  handle_signals=False)
    assert s["frames"] == 4 and seen == ["bl"] * 4
    assert _stored(tmp_path / "o.mp4") == (H, W, 4, 0)  # written upright: portrait pixels, no display matrix
    # the landscape camera is refused naming the file and the displayed size
    with pytest.raises(ConfigError) as e:
        run_video(process, Camera.from_fov(W, H, 60), clip, handle_signals=False)
    assert str(e.value) == (f"{clip}: video is 32x64 as displayed (stored turned 90 deg) but the camera is for "
                            "64x32; the video is turned 90 deg against the calibration (portrait vs landscape): "
                            "calibrate with the camera held as it was for this video")
    live = open_source(str(clip), live=True)  # a file replayed as live goes through the same decoding
    try:
        assert (live.width, live.height) == (H, W)
        assert white_corner(next(iter(live))) == "bl"
    finally:
        live.close()


def test_variable_frame_rate_rows_carry_the_frame_timestamps(tmp_path):
    # and the augmented video keeps them (plays as long as the clip)
    # mutants caught: time_s = k / fps for files (runner: `t_src = ... if live else None`); the writer spreading
    # the frames evenly at the header's rate (VideoWriter without timestamps)
    pts = [0, 100, 150, 200, 233, 300, 400, 433, 700, 733]
    clip = write_clip(tmp_path / "vfr.mkv", [pattern()] * len(pts), pts_ms=pts, fmt="matroska")
    run_video(lambda k, f, d: (f, Result()), Camera.from_fov(W, H, 60), clip, tmp_path / "t.mp4",
              tmp_path / "t.csv", handle_signals=False)
    rows = _rows(tmp_path / "t.csv")
    assert [r[0] for r in rows] == [str(k) for k in range(len(pts))]
    assert [r[1] for r in rows] == [f"{p / 1000:.4f}" for p in pts]
    with av.open(str(tmp_path / "t.mp4")) as c:
        times = [f.time for f in c.decode(c.streams.video[0])]
    np.testing.assert_allclose(times, np.array(pts) / 1000, atol=1e-4)


def test_unanswered_udp_stream_says_nothing_arrived(tmp_path):
    # mutant caught: the interrupt callback's "Immediate exit requested" passed on as the reason
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sk:
        sk.bind(("127.0.0.1", 0))
        port = sk.getsockname()[1]
    url = f"udp://127.0.0.1:{port}"
    with pytest.raises(PhysarError) as e:
        open_source(url, timeout=0.5)
    assert str(e.value) == (f"{url}: cannot open stream: nothing arrived within the 0.5 s timeout (is the sender "
                            "running, sending to this address and port?)")


def test_a_resolution_change_stops_with_file_frame_sizes_and_keeps_the_outputs(tmp_path):
    # mutant caught: the reader's error propagating through clip_outputs (the 5 good frames' outputs removed),
    # or no size check at all (CSV-only: frames 5-9 run against the wrong camera, exit 0)
    clip = _ts(tmp_path / "cat.ts", [(W, H, 5), (2 * W, 2 * H, 5)])
    for out_video in (tmp_path / "o.mp4", None):
        csv_path = tmp_path / f"o{out_video is None}.csv"
        with pytest.raises(VideoChanged) as e:
            run_video(lambda k, f, d: (f, Result()), Camera.from_fov(W, H, 60), clip, out_video, csv_path,
                      handle_signals=False)
        kept = ", ".join(str(p) for p in (out_video, csv_path) if p)
        assert str(e.value) == (f"{clip}: frame 5 is 128x64 px but frames 0-4 are 64x32 px (the video changes "
                                "resolution mid-stream; cut it there or convert it to one size); stopped after 5 "
                                f"frames (kept for them: {kept})")
        assert [r[0] for r in _rows(csv_path)] == ["0", "1", "2", "3", "4"]
    assert _stored(tmp_path / "o.mp4")[:3] == (W, H, 5)


def test_truncated_file_warns_with_the_decoded_span(tmp_path):
    # mutant caught: VideoReader ending a cut file silently (FFmpeg's threaded decoder swallows the error)
    full = write_clip(tmp_path / "full.mkv", [pattern(corner=c) for c in ("tl", "br") * 30], fmt="matroska",
                      codec="ffv1", pix="yuv444p")
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(full.read_bytes()[: full.stat().st_size // 2])
    with pytest.warns(PhysarWarning) as w:
        n = sum(1 for _ in VideoReader(cut))
    assert 5 < n < 50
    assert [str(x.message) for x in w] == [f"{cut}: decoded {n / 30:.1f} s ({n} frames) of a 2.0 s video (truncated?)"]
    with _no_warning():
        assert sum(1 for _ in VideoReader(full)) == 60


class _no_warning:
    def __enter__(self):
        import warnings

        self._w = warnings.catch_warnings(record=True)
        self.log = self._w.__enter__()
        warnings.simplefilter("always")
        return self

    def __exit__(self, *exc):
        self._w.__exit__(*exc)
        assert not [x for x in self.log if issubclass(x.category, PhysarWarning)]


def test_odd_frame_size_is_padded_by_replication(tmp_path):
    # a 33x25 camera: the H.264 file is 34x26, its last column / row copies the frame's last
    # mutant caught: VideoWriter refusing odd sizes (the old "needs an even frame size")
    rng = np.random.default_rng(0)
    grey = np.repeat(np.repeat(rng.integers(30, 220, (5, 3), dtype=np.uint8), 5, 0), 11, 1)[:25, :33]
    img = np.repeat(grey[..., None], 3, 2)  # grey blocks: yuv420p's half-resolution colour does not blur them
    with VideoWriter(tmp_path / "odd.mp4", 33, 25, 10.0, crf=0) as vw:
        for _ in range(3):
            vw.write(img)
    back = list(VideoReader(tmp_path / "odd.mp4"))
    assert len(back) == 3 and back[0].shape == (26, 34, 3)
    err = np.abs(back[0].astype(int)[:25, :33] - img).mean()
    assert err < 3.0
    np.testing.assert_allclose(back[0][:25, 33], back[0][:25, 32], atol=4)  # replicated column
    np.testing.assert_allclose(back[0][25, :33], back[0][24, :33], atol=4)  # replicated row
    # through the frame loop with an odd camera
    clip = write_clip(tmp_path / "odd.mkv", [img] * 3, fmt="matroska", codec="ffv1", pix="yuv444p")
    s = run_video(lambda k, f, d: (f, Result()), Camera.from_fov(33, 25, 60), clip, tmp_path / "o.mp4",
                  handle_signals=False)
    assert s["frames"] == 3 and _stored(tmp_path / "o.mp4")[:3] == (34, 26, 3)
    # a frame of the wrong size names the output, not the temporary it is written through
    with pytest.raises(Exception, match=r"o2\.mp4: frame 0 of shape \(24, 32, 3\) uint8 does not match"):
        run_video(lambda k, f, d: (f[:24, :32].copy(), Result()), Camera.from_fov(33, 25, 60), clip,
                  tmp_path / "o2.mp4", handle_signals=False)
    assert not (tmp_path / "o2.mp4").exists()
