"""The appearance refit of ``physar.recon.train.refit_appearances`` applied to finished runs (their physics as
learned), then ``evaluate``; plus the true-motion oracle (the fine truth's displacement averaged onto the
reconstruction's particles, body as simulated) with its own refit, on the reconstruction and prediction frames.

    .venv/bin/python benchmarks/bench_recon_refit.py DATA_DIR RUN_DIR [RUN_DIR ...] [--all] [--out JSON]

``--all``: refit opacities and scales too (the default refits the SH colours only, as ``fit`` does).
Written for issue 17 (benchmarks/RESULTS.md, "appearance refit"); prints one line per method and subset.
"""
import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).parent))
from bench_recon import cell_average_truth

from physar.recon.metrics import large_deformation_frames, sequence_metrics
from physar.recon.train import (
    Reconstruction,
    evaluate,
    load_dataset,
    refit_appearance,
    refit_appearances,
    render_scene,
    simulate_clip,
)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("data", type=Path)
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--all", action="store_true", help="refit opacities and scales too")
    ap.add_argument("--iters", type=int, default=150)
    ap.add_argument("--out", default="refit_eval.json")
    a = ap.parse_args()
    data, runs, iters, colours_only = a.data, a.runs, a.iters, not a.all
    ds = load_dataset(data)
    out = {}
    for run in runs:
        t0 = time.time()
        rec = Reconstruction.load(run)
        rig = rec.rig
        kin = rec.kinematics(ds.rotations, ds.root_t)
        rec.apps = refit_appearances(rec, ds, kin, iters, methods=("physics", "lbs", "4dgs"), colours_only=colours_only)
        t_refit = time.time() - t0
        rep = evaluate(rec, ds, methods=("physics", "lbs", "4dgs"))
        # oracle: true object motion (cell-averaged fine truth), body as simulated, its own refit on obs frames
        n, no = len(ds.rgb), ds.n_obs
        g = cell_average_truth(rig, ds.truth)
        gt = torch.as_tensor(rig.Xo + (g - g[0]))
        with torch.no_grad():
            sim = {f: (xh, Fh) for f, xo, Fo, xh, Fh in simulate_clip(rig, rec.phys, kin, n, grad=False)}
        mot = {f: (gt[f], rig.deformation_from_neighbours(gt[f]), *sim[f]) for f in range(1, n)}
        app = refit_appearance(rig, rec.app, {f: mot[f] for f in range(1, no)}, ds, kin, iters, colours_only)
        disp = ds.truth["dynamic_max_displacement"]
        orc = {}
        for label, a_ in (("oracle, canonical appearance", rec.app), ("oracle, own refit", app)):
            rgb, al = np.zeros_like(ds.rgb), np.zeros_like(ds.mask)
            with torch.no_grad():
                for f in range(1, n):
                    r = render_scene(rig, a_, *mot[f], kin["xb"][f], kin["A_b"][f])
                    rgb[f], al[f] = r.rgb.numpy(), r.alpha.numpy()
            res = {}
            for name, fr in (("recon", list(range(1, no))), ("pred", list(range(no, n)))):
                res[name] = sequence_metrics(rgb, al, ds.rgb, ds.mask, fr)
                res[name + "_large"] = sequence_metrics(rgb, al, ds.rgb, ds.mask, large_deformation_frames(disp, fr))
            orc[label] = res
        out[run] = {"report": rep, "oracle": orc, "refit_seconds": t_refit, "total_seconds": time.time() - t0}
        for m, r in rep["methods"].items():
            print(run, m, {k: (round(v["psnr"], 2), round(v["ssim"], 4), round(v["iou"], 4)) for k, v in r.items()}, flush=True)
        for m, r in orc.items():
            print(run, m, {k: (round(v["psnr"], 2), round(v["ssim"], 4), round(v["iou"], 4)) for k, v in r.items()}, flush=True)
        print(run, "seconds", t_refit, time.time() - t0, flush=True)
        with open(a.out, "w") as fh:  # rewritten after each run
            json.dump(out, fh, indent=1, default=float)


if __name__ == "__main__":
    main()
