"""physar.ar.runner.run_video: the frame loop shared by the AR pipelines (outputs, atomicity, statistics)."""
import csv
from dataclasses import dataclass, field

import cv2
import numpy as np
import pytest

from physar.ar.runner import run_video
from physar.ar.video import VideoReader
from physar.errors import ConfigError, PhysarError
from physar.vision.camera import Camera

W, H = 64, 48


@dataclass
class Result:
    status: str
    value: float
    latency_ms: float
    stages_ms: dict = field(default_factory=dict)


def _frames(n, seed=0):
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (H, W, 3), dtype=np.uint8) for _ in range(n)]


def _process(k, frame, draw):
    """Frame k: latency k + 1 ms, stage "a" k ms, stage "b" 1 ms on even frames only."""
    st = {"a": float(k)} | ({"b": 1.0} if k % 2 == 0 else {})
    return frame, Result("tracking" if k % 2 else "hold", 0.5 * k, k + 1.0, st)


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.reader(fh))


def test_csv_rows_video_and_statistics(tmp_path):
    cam = Camera.from_fov(W, H, 60)
    frames = _frames(7)
    s = run_video(_process, cam, frames, tmp_path / "v.mp4", tmp_path / "e.csv", fps=10.0, csv_header=["value"],
                  csv_row=lambda r: [f"{r.value:.2f}"], snapshots={2: tmp_path / "snap.png"}, max_frames=5)
    rows = _rows(tmp_path / "e.csv")
    assert rows[0] == ["frame", "time_s", "status", "value"]
    assert rows[1:] == [["0", "0.0000", "hold", "0.00"], ["1", "0.1000", "tracking", "0.50"],
                        ["2", "0.2000", "hold", "1.00"], ["3", "0.3000", "tracking", "1.50"],
                        ["4", "0.4000", "hold", "2.00"]]
    assert s["frames"] == 5 and len(s["results"]) == 5
    assert sorted(s) == sorted(["frames", "wall_s", "fps", "latency_ms_median", "latency_ms_p95",
                                "stages_ms_median", "results", "status_counts"])
    assert s["status_counts"] == {"hold": 3, "tracking": 2}      # the statuses of the rows above
    # latencies 1..5 ms: median 3, 95th percentile (linear) 1 + 0.95 * 4
    assert s["latency_ms_median"] == pytest.approx(3.0) and s["latency_ms_p95"] == pytest.approx(4.8)
    # stage "a" 0..4 -> 2; "b" 1, 0, 1, 0, 1 (missing counts 0) -> 1; stages sorted by name
    assert list(s["stages_ms_median"].items()) == [("a", 2.0), ("b", 1.0)]
    video = list(VideoReader(tmp_path / "v.mp4"))
    assert len(video) == 5 and video[0].shape == (H, W, 3)
    # the snapshot is the lossless PNG of frame 2; the H.264 frame is close to it
    snap = cv2.imread(str(tmp_path / "snap.png"))
    assert np.array_equal(snap, frames[2])
    assert np.mean(np.abs(video[2].astype(float) - frames[2])) < np.mean(np.abs(video[2].astype(float) - frames[3]))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e.csv", "snap.png", "v.mp4"]


def test_stage_names_draw_flag_and_no_video(tmp_path):
    cam = Camera.from_fov(W, H, 60)
    draws = []

    def process(k, frame, draw):
        draws.append(draw)
        return _process(k, frame, draw)

    s = run_video(process, cam, _frames(3), None, tmp_path / "e.csv", fps=30.0, snapshots={1: tmp_path / "s.png"},
                  stage_names=("b", "a", "c"))
    assert draws == [False, True, False]  # the image is needed only for the snapshot
    assert list(s["stages_ms_median"]) == ["b", "a", "c"] and s["stages_ms_median"]["c"] == 0.0
    assert [r[:3] for r in _rows(tmp_path / "e.csv")[1:]] == [["0", "0.0000", "hold"], ["1", "0.0333", "tracking"],
                                                             ["2", "0.0667", "hold"]]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e.csv", "s.png"]


def test_deferred_frames_io_timing_and_cpu(tmp_path):
    cam = Camera.from_fov(W, H, 60)
    frames = _frames(4, seed=1)
    called = []

    def process(k, frame, draw):
        def job():
            called.append(k)
            return 255 - frame
        return job, Result("tracking", 0.0, 1.0, {})

    s = run_video(process, cam, frames, tmp_path / "v.mp4", None, fps=25.0, snapshots={3: tmp_path / "s.png"},
                  time_io=True, cpu=True)
    assert called == [0, 1, 2, 3]  # every deferred image drawn once, in order, by the encoder thread
    assert np.array_equal(cv2.imread(str(tmp_path / "s.png")), 255 - frames[3])
    assert len(list(VideoReader(tmp_path / "v.mp4"))) == 4
    assert all(set(r.stages_ms) == {"decode", "encode"} for r in s["results"])
    assert s["process_cpu_ms_per_frame"] > 0


def test_no_partial_outputs_after_an_error(tmp_path):
    cam = Camera.from_fov(W, H, 60)

    def process(k, frame, draw):
        if k == 3:
            raise RuntimeError("estimation failed at frame 3")
        return _process(k, frame, draw)

    with pytest.raises(RuntimeError, match="frame 3"):
        run_video(process, cam, _frames(6), tmp_path / "v.mp4", tmp_path / "e.csv", fps=30.0,
                  csv_row=lambda r: [r.value])
    assert list(tmp_path.iterdir()) == []  # neither the outputs nor their temporaries


def test_errors(tmp_path):
    cam = Camera.from_fov(W, H, 60)
    with pytest.raises(PhysarError, match=r"^\[\]: no frames$"):
        run_video(_process, cam, [], tmp_path / "v.mp4", tmp_path / "e.csv")
    assert list(tmp_path.iterdir()) == []

    class Source(list):
        width, height, fps = 32, 24, 30.0

    with pytest.raises(ConfigError, match="video is 32x24 but the camera is for 64x48"):
        run_video(_process, cam, Source(_frames(2)), tmp_path / "v.mp4")


def test_one_blas_thread_while_frames_are_processed():
    """Inside the frame loop every BLAS library runs one thread (idle OpenBLAS workers spin on the cores the
    decoder and encoder need: benchmarks/RESULTS.md, "H.264 bitrate"), and the caller's limits come back after.
    Catches: the limit dropped, or left in place after the run."""
    threadpoolctl = pytest.importorskip("threadpoolctl")

    def blas_threads():
        return [p["num_threads"] for p in threadpoolctl.threadpool_info() if p["user_api"] == "blas"]

    np.ones((64, 64)) @ np.ones((64, 64))   # numpy's BLAS loaded
    seen = []

    def process(k, frame, draw):
        seen.append(blas_threads())
        return _process(k, frame, draw)

    with threadpoolctl.threadpool_limits(2, user_api="blas"):   # two outside, whatever the machine's cores
        before = blas_threads()
        run_video(process, Camera.from_fov(W, H, 60.0), _frames(3), None, None)
        after = blas_threads()
    assert before and min(before) == 2, before
    assert seen and all(t and max(t) == 1 for t in seen), seen
    assert after == before
