"""`recon import --fps` keeps exactly the frames that source_indices names, at rates where the nearest-frame
rule of a later output frame also lands on the clip's last frame (25 -> 7, 14, 16 fps of a 40-frame clip: the
reviewer's "kept 12 frames for 11 output frames" refusal). Reference: the output count is floor((N - 1) fps / r)
+ 1 frames of a clip of N frames at r fps, computed here by hand. Mutant caught: the upper bound on the output
index dropped (the clip is refused)."""
import math

import av
import numpy as np
import pytest

from physar.recon.importer import read_video


@pytest.mark.parametrize("fps", [7.0, 14.0, 16.0, 12.5])
def test_resampled_frame_count(tmp_path, fps):
    path = tmp_path / "c.mkv"
    with av.open(str(path), "w") as c:
        s = c.add_stream("ffv1", rate=25)
        s.width, s.height, s.pix_fmt = 32, 24, "yuv420p"
        for i in range(40):
            img = np.full((24, 32, 3), 6 * i, np.uint8)
            for p in s.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    clip = read_video(path, fps=fps)
    n = len(clip.frames)
    assert n == math.floor(39 * fps / 25 + 1e-9) + 1, n
