"""physar.ar.video: the decoder's luma plane and the FFmpeg / OpenCV colour conversions (ported from the removed
cantilever-scene tests, on a textured clip written here)."""
import cv2
import numpy as np
import pytest

from physar.ar.video import VideoReader, VideoWriter
from physar.errors import PhysarError


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """3 frames 640x360: smooth, weakly saturated colour noise over most of the grey range, shifted between frames (H.264 crf 12)."""
    rng = np.random.default_rng(4)
    grey = rng.uniform(30, 225, (45, 80, 1)) + rng.uniform(-15, 15, (45, 80, 3))   # low saturation, as a scene
    base = cv2.resize(grey.astype(np.float32), (700, 380), interpolation=cv2.INTER_CUBIC)
    path = tmp_path_factory.mktemp("video") / "clip.mp4"
    with VideoWriter(path, 640, 360, 30, crf=12) as w:
        for k in range(3):
            w.write(np.clip(base[5 * k:5 * k + 360, 7 * k:7 * k + 640], 0, 255).astype(np.uint8))
    return path


def test_video_luma_and_opencv_conversions(clip, tmp_path):
    """The decoder's luma plane is the BT.601 luma of the decoded colours (limited range: Y = 16 + 219/255 *
    grey of FFmpeg's BGR, within rounding); OpenCV's yuv420p <-> BGR conversions agree with FFmpeg's swscale
    within 3 grey levels; a writer with OpenCV conversion and deferred (callable) frames round-trips at > 38 dB;
    an unknown conversion is refused. Catches: full-range luma (intercept 0, slope 1), chroma planes swapped or
    upsampled off by a pixel in the OpenCV path (colour errors of tens of levels), a deferred frame written as
    the callable or never called."""
    a = list(zip(range(3), VideoReader(clip, convert="ffmpeg").frames_with_luma()))
    b = list(zip(range(3), VideoReader(clip, convert="opencv").frames_with_luma()))
    assert len(a) == len(b) == 3
    for (_, (bgr_f, y_f)), (_, (bgr_o, y_o)) in zip(a, b):
        assert np.array_equal(y_f, y_o) and y_f.shape == (360, 640)
        assert np.abs(bgr_f.astype(int) - bgr_o).max() <= 3
        grey = cv2.cvtColor(bgr_f, cv2.COLOR_BGR2GRAY).astype(float)
        slope, icpt = np.polyfit(grey.ravel(), y_f.ravel().astype(float), 1)
        assert abs(slope / (219 / 255) - 1) < 0.01 and abs(icpt - 16) < 1.5, (slope, icpt)
        assert np.abs(16 + 219 / 255 * grey - y_f).mean() < 1.5
    frames = [f for _, (f, _) in a]
    with VideoWriter(tmp_path / "w.mp4", 640, 360, 30, crf=12, preset="ultrafast", threaded=True,
                     convert="opencv", threads=1) as w:
        for f in frames:
            w.write(lambda f=f: f.copy())
    back = list(VideoReader(tmp_path / "w.mp4"))
    assert len(back) == 3
    for f, g in zip(frames, back):
        mse = np.mean((f.astype(float) - g) ** 2)
        assert 10 * np.log10(255 ** 2 / mse) > 38
    with pytest.raises(PhysarError, match="conversion"):
        VideoReader(clip, convert="sws")
