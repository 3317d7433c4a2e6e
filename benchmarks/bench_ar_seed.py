"""Frame rate of the markerless AR pipelines of seed 000 §5.2 (foam beam) and §5.3 (virtual boot seal) at
1280x720 (the seed: 60 Hz on 1280x720 video).

For each scene a short video is rendered, its reduced model built, then the pipeline is timed three ways on
the same decoded frames (held in memory): estimation only, estimation + overlay drawing, and the full run
with H.264 encoding (VideoWriter in its thread). The peer in the same process is plain H.264 decoding of the
same video (PyAV), so "x decode" is the pipeline's rate relative to just reading the video here.

    .venv/bin/python benchmarks/bench_ar_seed.py            # 1280x720
    .venv/bin/python benchmarks/bench_ar_seed.py --quick    # 640x360, coarse meshes
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np


def _decode_fps(path):
    from physar.ar.video import VideoReader

    t = time.perf_counter()
    n = sum(1 for _ in VideoReader(path, threaded=False))
    return n / (time.perf_counter() - t)


def _time(pipe_factory, frames, draw):
    pipe = pipe_factory()
    t = time.perf_counter()
    for k, f in enumerate(frames):
        pipe.process(f, k, draw=draw)
    return len(frames) / (time.perf_counter() - t)


def bench_foam(out: Path, w: int, h: int, quick: bool):
    from physar.ar.foam import (
        FoamLoad,
        FoamPipeline,
        FoamSceneSpec,
        FoamSection,
        build_foam_model,
        render_foam_scene,
    )
    from physar.ar.scene import VideoSection
    from physar.ar.video import VideoReader
    from physar.vision import Camera

    foam = FoamSection(truth_cells=(24, 3, 3), model_cells=(16, 2, 2)) if quick else FoamSection()
    spec = FoamSceneSpec(video=VideoSection(width=w, height=h, duration=3.5), foam=foam,
                         load=FoamLoad(positions=[0.25, 0.55, 0.4], dwell=1.0))
    render_foam_scene(spec, out)
    rom, obj, _, _ = build_foam_model(spec)
    cam = Camera.load(out / "camera.toml")
    frames = list(VideoReader(out / "scene.mp4", threaded=False))
    make = lambda: FoamPipeline(rom, cam, obj)
    full = make().run(out / "scene.mp4", out / "augmented.mp4", out / "est.csv", fps=spec.video.fps)
    return {"scene": "foam (b)", "modes": rom.n_modes, "frames": len(frames),
            "est": _time(make, frames, False), "draw": _time(make, frames, True), "full": full["fps"],
            "decode": _decode_fps(out / "scene.mp4"), "stages": full["stages_ms_median"]}


def bench_seal(out: Path, w: int, h: int, quick: bool):
    from physar.ar.scene import VideoSection
    from physar.ar.seal import (
        PlateObject,
        SealPipeline,
        SealSceneSpec,
        SealSection,
        build_seal_model,
        render_seal_scene,
    )
    from physar.ar.video import VideoReader
    from physar.vision import Camera

    seal = SealSection(n_phi=8, n_profile=10, theta_max=40.0) if quick else SealSection()
    spec = SealSceneSpec(video=VideoSection(width=w, height=h, duration=4.0), seal=seal,
                         keyframes=[(0.0, 0.0), (1.5, seal.theta_max), (4.0, 10.0)], look_away=[])
    render_seal_scene(spec, out)
    rom, vm, model, _ = build_seal_model(spec)
    cam = Camera.load(out / "camera.toml")
    frames = list(VideoReader(out / "scene.mp4", threaded=False))
    plate = PlateObject.load(out / "plate.json")
    make = lambda: SealPipeline(rom, vm, cam, plate, out, seal=model)
    full = make().run(out / "scene.mp4", out / "augmented.mp4", out / "est.csv", fps=spec.video.fps)
    return {"scene": "seal (c)", "modes": rom.n_modes, "frames": len(frames),
            "est": _time(make, frames, False), "draw": _time(make, frames, True), "full": full["fps"],
            "decode": _decode_fps(out / "scene.mp4"), "stages": full["stages_ms_median"]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="640x360 and coarse meshes")
    ap.add_argument("--scene", choices=["foam", "seal", "both"], default="both")
    a = ap.parse_args()
    w, h = (640, 360) if a.quick else (1280, 720)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        if a.scene in ("foam", "both"):
            rows.append(bench_foam(Path(tmp) / "foam", w, h, a.quick))
        if a.scene in ("seal", "both"):
            rows.append(bench_seal(Path(tmp) / "seal", w, h, a.quick))
    load = os.getloadavg()
    print(f"\nmarkerless AR pipelines at {w}x{h}, {os.cpu_count()} cores, load average {load[0]:.1f} "
          f"(numbers under load are lower bounds)\n")
    print("| scene | modes | frames | fps estimation | fps + overlay | fps + overlay + H.264 | decode-only fps "
          "| full / decode | median stage ms |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        st = ", ".join(f"{k} {v:.1f}" for k, v in r["stages"].items())
        print(f"| {r['scene']} | {r['modes']} | {r['frames']} | {r['est']:.1f} | {r['draw']:.1f} | {r['full']:.1f} | "
              f"{r['decode']:.1f} | {r['full'] / r['decode']:.2f} | {st} |")
    return rows


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
