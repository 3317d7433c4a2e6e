"""End-to-end AR pipeline throughput at 1280x720 with a per-stage latency table (issue 4; seed 000 reports 60 Hz,
our goal is >= 120 fps).

    .venv/bin/python benchmarks/bench_ar.py [--frames 150] [--dir bench_ar_out] [--reuse]

Renders a short scene (a) (skipped with --reuse when DIR holds one), builds its reduced model, then runs
  1. decode only (PyAV, threaded reader),
  2. the pipeline without overlay/encoding (estimation only),
  3. the full pipeline (overlay + H.264 encode in a background thread) with libx264 presets.
Prints markdown tables and the machine load (`uptime`), since the CPU may be shared.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import time
from pathlib import Path

import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--dir", default="bench_ar_out")
    ap.add_argument("--reuse", action="store_true")
    a = ap.parse_args()

    from physar.ar.demo import demo_scene
    from physar.ar.pipeline import STAGES, ARPipeline, build_scene_model
    from physar.ar.scene import VideoSection, render_scene
    from physar.ar.video import VideoReader
    from physar.rom import SeparatedModel
    from physar.vision import Camera

    out = Path(a.dir)
    spec = demo_scene()
    spec.video = VideoSection(duration=a.frames / 30.0)
    spec.occlusion = []
    if not (a.reuse and (out / "scene.mp4").exists() and (out / "model.npz").exists()):
        t = time.perf_counter()
        render_scene(spec, out)
        t_render = time.perf_counter() - t
        t = time.perf_counter()
        rom, obj, space, _ = build_scene_model(spec)
        rom.save(out / "model.npz")
        print(f"scene: {spec.n_frames} frames rendered in {t_render:.1f} s; reduced model ({rom.n_modes} modes) "
              f"in {time.perf_counter() - t:.1f} s")
    rom = SeparatedModel.load(out / "model.npz")
    cam = Camera.load(out / "camera.toml")

    t = time.perf_counter()
    n = sum(1 for _ in VideoReader(out / "scene.mp4"))
    dec_fps = n / (time.perf_counter() - t)

    rows = []
    pipe = ARPipeline(rom, cam)
    s = pipe.run(out / "scene.mp4")  # no outputs: no overlay, no encoding
    rows.append(("estimation only (no overlay, no encode)", s))
    for preset in ("ultrafast", "veryfast"):
        pipe = ARPipeline(rom, cam)
        s = pipe.run(out / "scene.mp4", out / f"augmented_{preset}.mp4", out / "estimates.csv", preset=preset)
        rows.append((f"full: overlay + H.264 {preset}", s))

    load = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    print(f"\n## AR pipeline, 1280x720, {n} frames ({time.strftime('%Y-%m-%d')}, {os.cpu_count()} CPUs; {load})\n")
    print(f"decode only (PyAV, threaded): {dec_fps:.0f} fps\n")
    print("| run | fps (wall) | latency median [ms] | latency p95 [ms] | " + " | ".join(STAGES) + " |")
    print("|---|---|---|---|" + "---|" * len(STAGES))
    for name, s in rows:
        st = s["stages_ms_median"]
        print(f"| {name} | {s['fps']:.1f} | {s['latency_ms_median']:.2f} | {s['latency_ms_p95']:.2f} | "
              + " | ".join(f"{st[k]:.2f}" for k in STAGES) + " |")
    print("\nstage columns: median ms per frame on the main thread; decode/encode = time spent waiting for the "
          "reader/writer threads. latency = markers_pose + dots + assimilate + overlay.")
    compute = [np.sum([s["stages_ms_median"][k] for k in ("markers_pose", "dots", "assimilate", "overlay")])
               for _, s in rows]
    print("compute on the main thread (sum of stage medians), ms/frame: "
          + ", ".join(f"{name.split(':')[0].split(' (')[0]} {c:.2f} ms ({1000 / c:.0f} fps)" for (name, _), c in zip(rows, compute)))


if __name__ == "__main__":
    main()
