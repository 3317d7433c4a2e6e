"""The new example object (examples/ar/bracket: PLA L-bracket from an STL, curved load path + offset, markers on
three planes) through the general project pipeline on clips of the general test-data renderer (physar.synth,
truth on a mesh 8x finer), 1280x720, over scenario seeds: accuracy of the load position against the truth (1 %
of the path = 1.28 mm), fps end to end (decode, estimate, overlay, H.264 ultrafast encode) and per-stage
latency, with the machine's load average written beside it.

    .venv/bin/python benchmarks/bench_ar_bracket.py --seeds 0 1 2 --cache /tmp/physar_bracket
"""
from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EX = ROOT / "examples" / "ar" / "bracket"


def main(argv=None):
    from physar.ar.project import load_project
    from physar.ar.project_pipeline import ProjectPipeline
    from physar.synth import load_scenario, render_project
    from physar.synth.score import read_columns, score

    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "physar_bracket")
    a = ap.parse_args(argv)
    p = load_project(EX / "project.toml")
    ranges = {n: tuple(map(float, r)) for n, r in zip(p.rom.names, p.rom.ranges)}
    base = load_scenario(EX / "scenario.toml", p)
    rows = []
    for seed in a.seeds:
        d = a.cache / f"seed{seed}"
        if not (d / "truth.csv").is_file():
            sc = base.model_copy(update={"seed": seed})
            render_project(p, sc, d)
        with tempfile.TemporaryDirectory() as tmp:
            load = os.getloadavg()[0]
            summ = ProjectPipeline(p).run(d / "video.mp4", Path(tmp) / "aug.mp4", Path(tmp) / "est.csv")
            res = score(read_columns(d / "truth.csv"), read_columns(Path(tmp) / "est.csv"), ranges)
        s, o = res["parameters"]["s"], res["parameters"]["o"]
        st = summ["stages_ms_median"]
        rows.append((s["within"], s["judged"], s["max_error"], s["mean_error"], o["mean_error"], summ["fps"]))
        print(f"seed {seed}: s {s['within']}/{s['judged']} within 1.28 mm, max {s['max_error'] * 1e3:.2f} mm, mean "
              f"{s['mean_error'] * 1e3:.2f} mm, median {s['median_error'] * 1e3:.2f} mm | offset mean |err| "
              f"{o['mean_error'] * 1e3:.2f} mm | {summ['fps']:.1f} fps, latency median {summ['latency_ms_median']:.2f} ms, "
              f"stages " + ", ".join(f"{k} {v:.2f}" for k, v in st.items()) + f" ms | load {load:.2f}", flush=True)
    w = sum(r[0] for r in rows)
    j = sum(r[1] for r in rows)
    print(f"all: {w}/{j} judged frames within 1 % of the path, worst {max(r[2] for r in rows) * 1e3:.2f} mm, "
          f"mean {np.mean([r[3] for r in rows]) * 1e3:.2f} mm; fps {min(r[5] for r in rows):.1f}-{max(r[5] for r in rows):.1f}")


if __name__ == "__main__":
    main()
