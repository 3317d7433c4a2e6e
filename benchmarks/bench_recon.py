"""Benchmark of the PhysHO reconstruction pipeline (issue 8): end-to-end training time of a reduced
synthetic scene on this CPU (goal < 30 min), and reconstruction / prediction / novel-action PSNR, SSIM and
IoU of physics vs the LBS-only and 4DGS-like baselines, on all frames and on the large-deformation subsets.

    .venv/bin/python benchmarks/bench_recon.py [--config examples/recon_bench.toml] [--out /tmp/bench_recon]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from physar.recon.synth import generate, load_synth_config
from physar.recon.train import fit, load_train_config


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--config", default=str(Path(__file__).parents[1] / "examples" / "recon_bench.toml"))
    ap.add_argument("--out", default="/tmp/bench_recon")
    a = ap.parse_args()
    out = Path(a.out)
    scfg, tcfg = load_synth_config(a.config), load_train_config(a.config)
    t0 = time.perf_counter()
    generate(out / "data", scfg)
    t_gen = time.perf_counter() - t0
    t1 = time.perf_counter()
    rep = fit(out / "data", out / "run", tcfg, restart=True)
    t_fit = time.perf_counter() - t1
    print(f"scene: {scfg.image_size}px, {scfg.frames} frames ({scfg.n_obs} observed), {scfg.novel_frames} "
          f"novel-action frames; ground truth {scfg.gt_particles_per_cell} particles/cell, reconstruction "
          f"{tcfg.particles_per_cell}")
    print(f"generation {t_gen:.1f} s; fit (train {rep['train_seconds']:.1f} s + evaluation) {t_fit:.1f} s\n")
    print("| method | subset | PSNR | SSIM | IoU | frames |")
    print("|---|---|---|---|---|---|")
    for m, res in rep["methods"].items():
        for s, v in res.items():
            print(f"| {m} | {s} | {v['psnr']:.2f} | {v['ssim']:.4f} | {v['iou']:.4f} | {v['frames']} |")
    print("\nmaterial:", json.dumps(rep["material"]))
    print("omega:", json.dumps(rep["omega"]))
    print("LPIPS:", rep["lpips"])


if __name__ == "__main__":
    main()
