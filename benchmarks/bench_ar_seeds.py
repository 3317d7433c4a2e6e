"""A seed scene over scenario noise seeds (issue 16: "cantilever 3470/3470 judged frames within 1 % over ten noise
seeds"): the project's scenario rendered by the test-data renderer with each seed (camera shake, sensor noise,
flicker, textures), the one pipeline on each clip, frames within 1 % of the parameter ranges counted over the
judged frames (not at rest, no occluder, in view, not recovering), with fps and the machine's load.

    .venv/bin/python benchmarks/bench_ar_seeds.py --project examples/ar/cantilever/project.toml --seeds 0 1 2 3 4 5 6 7 8 9
"""
from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--project", type=Path, default=ROOT / "examples" / "ar" / "cantilever" / "project.toml")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(10)))
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "physar_seeds")
    args = ap.parse_args(argv)
    from physar.ar.project import load_project
    from physar.ar.project_pipeline import ProjectPipeline
    from physar.synth.render import render_project
    from physar.synth.scenario import load_scenario
    from physar.synth.score import read_columns, score
    from physar.vision.camera import Camera

    project = load_project(args.project)
    names = list(project.rom.names)
    ranges = {n: tuple(map(float, r)) for n, r in zip(names, project.rom.ranges)}
    base = load_scenario(args.project.parent / "scenario.toml", project)
    tot = {n: [0, 0] for n in names}
    worst = {n: 0.0 for n in names}
    print("| seed | " + " | ".join(f"{n}: within / judged, max abs error" for n in names) + " | fps | load |")
    print("|---|" + "---|" * len(names) + "---|---|")
    for seed in args.seeds:
        d = args.cache / f"{args.project.parent.name}_seed{seed}"
        if not (d / "truth.csv").is_file():
            render_project(project, base.model_copy(update={"seed": seed}), d)
        project.camera = Camera.load(d / "camera.toml")
        load0 = os.getloadavg()[0]
        with tempfile.TemporaryDirectory() as tmp:
            s = ProjectPipeline(project, overlay=False).run(d / "video.mp4", out_csv=Path(tmp) / "e.csv")
            sc = score(read_columns(d / "truth.csv"), read_columns(Path(tmp) / "e.csv"), ranges)
        cells = []
        for n in names:
            p = sc["parameters"][n]
            tot[n][0] += p["within"]
            tot[n][1] += p["judged"]
            worst[n] = max(worst[n], p["max_error"])
            cells.append(f"{p['within']}/{p['judged']}, {p['max_error']:.4g}")
        print(f"| {seed} | " + " | ".join(cells) + f" | {s['fps']:.1f} | {(load0 + os.getloadavg()[0]) / 2:.1f} |",
              flush=True)
    print("all: " + "; ".join(f"{n} {tot[n][0]}/{tot[n][1]} within 1 % of its range, worst {worst[n]:.4g}"
                              for n in names))


if __name__ == "__main__":
    main()
