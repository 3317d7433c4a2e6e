"""Soak: 20,000 frames through the AR project pipeline (issue 21, bounded memory in long runs): a quick clip of
examples/ar/cantilever from the test-data renderer, looped as a live source (`from_frames`, no frame dropped:
``latest=False``) through `ProjectPipeline.run` with the overlay drawn, the augmented video and the CSV written
as they go and results not kept (`keep_results=False`, as `physar ar run` does for live sources); the process's
resident memory (RSS, /proc/self/statm) sampled every second. Reports the growth after warm-up (the first 10 %
of the frames) and the machine's load.

    .venv/bin/python benchmarks/bench_ar_soak.py --frames 20000
"""
from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20000)
    args = ap.parse_args(argv)
    from physar.ar.project import load_project
    from physar.ar.project_pipeline import ProjectPipeline
    from physar.ar.sources import from_frames
    from physar.ar.video import VideoReader
    from physar.synth.render import render_project
    from physar.synth.scenario import load_scenario
    from physar.vision.camera import Camera

    ex = ROOT / "examples" / "ar" / "cantilever"
    project = load_project(ex / "project.toml")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        render_project(project, load_scenario(ex / "scenario.toml", project), tmp / "clip", quick=True)
        clip = list(VideoReader(tmp / "clip" / "video.mp4"))
        project.camera = Camera.load(tmp / "clip" / "camera.toml")
        pipe = ProjectPipeline(project)
        n = args.frames

        def frames():
            for k in range(n):
                yield clip[k % len(clip)]

        samples, done = [], threading.Event()

        def sampler():
            t0 = time.perf_counter()
            while not done.is_set():
                samples.append((time.perf_counter() - t0, rss_mb()))
                done.wait(1.0)

        th = threading.Thread(target=sampler, daemon=True)
        load0 = os.getloadavg()[0]
        th.start()
        src = from_frames(frames(), fps=30.0, latest=False)
        s = pipe.run(src, tmp / "soak.mp4", tmp / "soak.csv", keep_results=False)
        done.set()
        th.join()
        rows = sum(1 for _ in open(tmp / "soak.csv")) - 1
    load1 = os.getloadavg()[0]
    warm = samples[max(1, len(samples) // 10)][1]
    peak_after = max(r for _, r in samples[len(samples) // 10:])
    print(f"frames {s['frames']} (CSV rows {rows}), {s['fps']:.1f} fps, RSS after warm-up {warm:.1f} MB, "
          f"max after {peak_after:.1f} MB, end {samples[-1][1]:.1f} MB: growth {samples[-1][1] - warm:+.1f} MB "
          f"(max {peak_after - warm:+.1f} MB); load {load0:.1f} -> {load1:.1f}")
    step = max(1, len(samples) // 12)
    print("| t [s] | RSS [MB] |\n|---|---|")
    for t, r in samples[::step]:
        print(f"| {t:.0f} | {r:.1f} |")


if __name__ == "__main__":
    main()
