"""The general project pipeline (physar.ar.project_pipeline, driven by examples/ar/cantilever/project.toml)
against the specialised cantilever pipeline (physar.ar.pipeline.ARPipeline) on the same seed-000 scene (a)
videos, in the same run (issue 16).

Accuracy: the judged frames of :func:`physar.ar.demo.judged_frames` (tracking, load beyond 20 % of the span,
the 5 frames after the full occlusion left out), over scene noise seeds (renders cached in ``--cache``, shared
with benchmarks/bench_ar_noise_seeds.py). Speed: seed 0 end to end (decode, estimate, overlay, H.264 encode
with x264 ultrafast) for both pipelines, alternating, with the machine's load average written beside it.

    .venv/bin/python benchmarks/bench_ar_project.py --seeds 0 1 2 3 4 5 6 7 8 9 --cache /tmp/physar_ar_seeds
"""
from __future__ import annotations

import argparse
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _project(tmp: Path):
    from physar.ar.project import load_project

    src = ROOT / "examples" / "ar" / "cantilever"
    for f in ("project.toml", "rom.toml"):
        shutil.copy(src / f, tmp / f)
    shutil.copy(ROOT / "examples" / "camera_720p.toml", tmp / "camera.toml")
    p = tmp / "project.toml"
    p.write_text(p.read_text().replace('"../../camera_720p.toml"', '"camera.toml"'))
    return load_project(p)


def _score(spec, d, csv):
    from physar.ar.demo import judged_frames
    from physar.ar.pipeline import read_estimates
    from physar.ar.scene import read_truth

    truth, est = read_truth(d / "truth.csv"), read_estimates(csv)
    err, sel, rec = judged_frames(spec.beam.length, truth, est)
    e = err[sel] * 1e3
    return {"judged": int(sel.sum()), "within": int(np.sum(e <= 5.0)), "max_mm": float(e.max()),
            "mean_mm": float(e.mean()), "recovery": rec}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--cache", type=Path, default=Path("/tmp/physar_ar_seeds"))
    ap.add_argument("--speed-runs", type=int, default=2)
    args = ap.parse_args(argv)
    from physar.ar.demo import demo_scene
    from physar.ar.pipeline import ARPipeline, build_scene_model
    from physar.ar.project_pipeline import ProjectPipeline
    from physar.ar.scene import render_scene
    from physar.vision.camera import Camera

    tmp = Path(tempfile.mkdtemp())
    project = _project(tmp)
    spec0 = demo_scene()
    rom, obj, _, _ = build_scene_model(spec0)
    rows = []
    for seed in args.seeds:
        spec = spec0.model_copy(update={"seed": seed})
        d = args.cache / f"seed{seed}"
        if not (d / "scene.mp4").exists():
            render_scene(spec, d)
        cam = Camera.load(d / "camera.toml")
        ARPipeline(rom, cam, obj, overlay=False).run(d / "scene.mp4", None, tmp / "old.csv", fps=spec.video.fps)
        ProjectPipeline(project, overlay=False).run(d / "scene.mp4", None, tmp / "new.csv", fps=spec.video.fps)
        a, b = _score(spec, d, tmp / "old.csv"), _score(spec, d, tmp / "new.csv")
        rows.append((seed, a, b))
        print(f"seed {seed}: specialised {a['within']}/{a['judged']} max {a['max_mm']:.2f} mean {a['mean_mm']:.2f} "
              f"rec {a['recovery']} | project {b['within']}/{b['judged']} max {b['max_mm']:.2f} "
              f"mean {b['mean_mm']:.2f} rec {b['recovery']}", flush=True)
    for name, k in (("specialised", 1), ("project", 2)):
        w = sum(r[k]["within"] for r in rows)
        j = sum(r[k]["judged"] for r in rows)
        print(f"{name}: {w}/{j} judged frames within 5 mm, worst {max(r[k]['max_mm'] for r in rows):.2f} mm, "
              f"mean {np.mean([r[k]['mean_mm'] for r in rows]):.2f} mm")
    d = args.cache / f"seed{args.seeds[0]}"
    cam = Camera.load(d / "camera.toml")
    print(f"speed on seed {args.seeds[0]} (1280x720, overlay + H.264 ultrafast), load average "
          f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores:")
    for run in range(args.speed_runs):
        for name, pipe in (("specialised", ARPipeline(rom, cam, obj)), ("project", ProjectPipeline(project))):
            s = pipe.run(d / "scene.mp4", tmp / "aug.mp4", None)
            st = s["stages_ms_median"]
            print(f"  run {run} {name}: {s['fps']:.1f} fps, latency median {s['latency_ms_median']:.2f} ms, "
                  + ", ".join(f"{k} {v:.2f}" for k, v in st.items()) + f" (load {os.getloadavg()[0]:.2f})",
                  flush=True)
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
