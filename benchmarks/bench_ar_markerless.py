"""The one project pipeline (physar.ar.project_pipeline on examples/ar/foam and examples/ar/seal) against the
specialised markerless pipelines it replaces (physar.ar.foam.FoamPipeline, physar.ar.seal.SealPipeline), on the
same seed-000 scene (b) and (c) videos, in the same run (issue 16).

The videos are the specialised scenes' own renders (their truth from their own finer models: the foam's St.VK
P2 32x4x4 mesh with a uniform disk load, the seal's lever schedule), so the project models (a bump-kernel disk
load, the project's meshes) are a different model from the truth for both pipelines. Accuracy: the
specialised evaluators (evaluate_foam: mean |error| over the loaded frames after 2 settle frames; evaluate_seal:
median |error| with the lever in view, recovery after the look-away). Speed: decode + estimate + overlay +
H.264 encode (x264 ultrafast), alternating, the machine's load average written beside it.

    .venv/bin/python benchmarks/bench_ar_markerless.py --cache /tmp/physar_markerless
"""
from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _load():
    return os.getloadavg()[0]


def _run(pipe, video, out, **kw):
    csv = out / "est.csv"
    s = pipe.run(str(video), out_video=str(out / "aug.mp4"), out_csv=str(csv), **kw)
    return s, csv


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, default=Path("/tmp/physar_markerless"))
    ap.add_argument("--scenes", nargs="+", default=["seal", "foam"])
    args = ap.parse_args(argv)
    from physar.ar.foam import FoamPipeline, build_foam_model, evaluate_foam, foam_demo_scene, render_foam_scene
    from physar.ar.project import load_project
    from physar.ar.project_pipeline import ProjectPipeline
    from physar.ar.seal import (PlateObject, SealPipeline, build_seal_model, evaluate_seal, render_seal_scene,
                                seal_demo_scene)
    from physar.synth.score import read_columns
    from physar.vision.camera import Camera

    rows = []
    for scene in args.scenes:
        d = args.cache / scene
        spec = foam_demo_scene() if scene == "foam" else seal_demo_scene()
        if not (d / "scene.mp4").is_file():
            d.mkdir(parents=True, exist_ok=True)
            (render_foam_scene if scene == "foam" else render_seal_scene)(spec, d)
        cam = Camera.load(d / "camera.toml")
        project = load_project(ROOT / "examples" / "ar" / scene / "project.toml")
        if scene == "foam":
            rom, obj, _space, _ = build_foam_model(spec)

            def old():
                return FoamPipeline(rom, cam, obj)
        else:
            rom, vm, seal, _ = build_seal_model(spec)

            def old():
                return SealPipeline(rom, vm, cam, PlateObject.load(d / "plate.json"), d, seal=seal)

        truth = read_columns(d / "truth.csv")
        for run in range(2):
            for name, make in (("specialised", old), ("project", lambda: ProjectPipeline(project))):
                with tempfile.TemporaryDirectory() as tmp:
                    load0 = _load()
                    s, csv = _run(make(), d / "scene.mp4", Path(tmp))
                    est = read_columns(csv)
                    if scene == "foam":
                        if name == "project":   # the project's s runs along the path from x = 100 mm
                            est = dict(est, s_est=np.asarray(est["s_est"], float) + 0.1)
                        ev = evaluate_foam(truth, est)
                        acc = f"{ev['mean_abs_error_mm']:.2f} mm mean, {ev['max_abs_error_mm']:.2f} mm max"
                    else:
                        if name == "project":
                            est = dict(est, theta_est_deg=est["theta_est"])
                        ev = evaluate_seal(truth, est)
                        acc = (f"{ev['median_abs_error_deg']:.3f} deg median, {ev['max_abs_error_deg']:.2f} max, "
                               f"recovery {ev['recovery_frames_after_look_away']}")
                    st = s.get("stages_ms_median", {})
                    rows.append((scene, name, run, acc, s["fps"], s["latency_ms_median"],
                                 ", ".join(f"{k} {v:.1f}" for k, v in st.items()), (load0 + _load()) / 2))
                    print(rows[-1], flush=True)
    print("\n| scene | pipeline | run | accuracy | fps | median latency [ms] | stage medians [ms] | load |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]} | {r[4]:.1f} | {r[5]:.1f} | {r[6]} | {r[7]:.1f} |")


if __name__ == "__main__":
    main()
