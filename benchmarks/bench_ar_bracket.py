"""The new example object (examples/ar/bracket: PLA L-bracket from an STL, curved load path + offset, markers on
three planes) through the general project pipeline on clips of the general test-data renderer (physar.synth,
truth on the STL meshed again and refined, see below), 1280x720, over scenario seeds: accuracy of the load
position against the truth (1 % of the path = 1.28 mm), fps end to end (decode, estimate, overlay, H.264
ultrafast encode) and per-stage latency, with the machine's load average written beside it.

    .venv/bin/python benchmarks/bench_ar_bracket.py --seeds 0 1 2 --cache /tmp/physar_bracket

--project FILE runs another project file of the example on the same clips (e.g. project_features.toml: the
dots plus the arm's texture features); both ``--project project.toml project_features.toml`` run one after the
other on each clip, so that the two are compared under the same load.

--model-mesh SIZE runs the pipeline with a copy of the example whose [mesh] size is SIZE (m) (its model built in
the copy); --truth-mesh SIZE renders the clips with the scenario's [truth] mesh_size = SIZE (the surface meshed
again at SIZE, then refined 2x: independent of the model's mesh). The default is the example's scenario: the
2.5 mm model against the truth of the 3.5 mm mesh refined 2x (1.75 mm, 410k dofs, 7.1 GB, about 3 min per clip
on this machine). Clips are cached under CACHE/truth-<SIZE>mm-crf<CRF>/seed<N>;
--crf renders them at another H.264 crf than the scenario's (crf 12: 16.5-17.5 Mbit/s; crf 18: 2.4 Mbit/s).
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EX = ROOT / "examples" / "ar" / "bracket"


def _copy(size: float, dest: Path, name: str = "project.toml") -> Path:
    """A copy of the example in ``dest`` with [mesh] size = ``size`` (the camera file by absolute path)."""
    dest.mkdir(parents=True, exist_ok=True)
    for f in ("bracket.stl", "scenario.toml"):
        shutil.copy(EX / f, dest / f)
    rom = (EX / "rom.toml").read_text()
    new = re.sub(r"(?m)^size = [0-9.e-]+", f"size = {size!r}", rom)
    if new == rom and f"size = {size!r}" not in rom:
        raise SystemExit("rom.toml: no [mesh] size line to change")
    (dest / "rom.toml").write_text(new)
    cam = (EX.parent.parent / "camera_720p.toml").resolve()
    (dest / name).write_text((EX / name).read_text().replace(
        'file = "../../camera_720p.toml"', f'file = "{cam}"'))
    return dest / name


def main(argv=None):
    from physar.ar.project import load_project
    from physar.ar.project_pipeline import ProjectPipeline
    from physar.synth import load_scenario, render_project
    from physar.synth.score import read_columns, score

    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "physar_bracket")
    ap.add_argument("--model-mesh", type=float, default=None, help="[mesh] size of the model (m; default: the "
                                                                     "example's)")
    ap.add_argument("--truth-mesh", type=float, default=None, help="[truth] mesh_size: the surface meshed again "
                                                                     "at this size, refined 2x (m; default: the "
                                                                     "scenario's)")
    ap.add_argument("--crf", type=int, default=None, choices=range(52), metavar="0-51", help="H.264 crf of the rendered clips (default: the "
                                                           "scenario's [video] crf)")
    ap.add_argument("--project", nargs="+", default=["project.toml"], help="project file(s) of the example")
    a = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="bench_bracket_"))
    projects = {n: load_project(EX / n if a.model_mesh is None else _copy(a.model_mesh, work / "model", n))
                for n in a.project}
    p = next(iter(projects.values()))
    ranges = {n: tuple(map(float, r)) for n, r in zip(p.rom.names, p.rom.ranges)}
    base = load_scenario(EX / "scenario.toml", p)
    truth = base.truth if a.truth_mesh is None else base.truth.model_copy(update={"mesh_size": a.truth_mesh})
    crf = base.video.crf if a.crf is None else a.crf
    base = base.model_copy(update={"video": base.video.model_copy(update={"crf": crf})})
    cache = a.cache / ((f"truth-{truth.mesh_size * 1e3:g}mm" if truth.mesh_size else f"truth-model-r{truth.refine}")
                       + f"-crf{crf}")
    rows = {n: [] for n in projects}
    for seed in a.seeds:
        d = cache / f"seed{seed}"
        if not (d / "truth.csv").is_file():
            sc = base.model_copy(update={"seed": seed, "truth": truth})
            render_project(load_project(EX / "project.toml"), sc, d)
        for name, pr in projects.items():
            with tempfile.TemporaryDirectory() as tmp:
                load = os.getloadavg()[0]
                summ = ProjectPipeline(pr).run(d / "video.mp4", Path(tmp) / "aug.mp4", Path(tmp) / "est.csv")
                res = score(read_columns(d / "truth.csv"), read_columns(Path(tmp) / "est.csv"), ranges)
            s, o = res["parameters"]["s"], res["parameters"]["o"]
            st = summ["stages_ms_median"]
            rows[name].append((s["within"], s["judged"], s["max_error"], s["mean_error"], o["mean_error"],
                               summ["fps"], o["median_error"]))
            print(f"{name} seed {seed}: s {s['within']}/{s['judged']} within 1.28 mm, max {s['max_error'] * 1e3:.2f} "
                  f"mm, mean {s['mean_error'] * 1e3:.2f} mm, median {s['median_error'] * 1e3:.2f} mm | offset |err| "
                  f"mean {o['mean_error'] * 1e3:.2f} mm, median {o['median_error'] * 1e3:.2f} mm | {summ['fps']:.1f} "
                  f"fps, latency median {summ['latency_ms_median']:.2f} ms, stages "
                  + ", ".join(f"{k} {v:.2f}" for k, v in st.items()) + f" ms | load {load:.2f}", flush=True)
    for name, rr in rows.items():
        w = sum(r[0] for r in rr)
        j = sum(r[1] for r in rr)
        print(f"{name}: {w}/{j} judged frames within 1 % of the path, worst {max(r[2] for r in rr) * 1e3:.2f} mm, "
              f"mean {np.mean([r[3] for r in rr]) * 1e3:.2f} mm; offset mean |err| "
              f"{np.mean([r[4] for r in rr]) * 1e3:.2f} mm; fps {min(r[5] for r in rr):.1f}-{max(r[5] for r in rr):.1f}")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
