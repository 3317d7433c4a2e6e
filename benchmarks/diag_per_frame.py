"""Per-frame 3-D error of the object for runs of ``bench_recon_pillow.py`` (issue 17): mean |x_f - truth_f| (mm)
of the reconstruction's object particles, simulated by each run's physics over the whole dynamic clip, against
the fine truth averaged onto them (``train.cell_average_truth``); and the mean height error of the object's top
30 % (mm, + = above the truth), which shows a plastic dent the simulation springs back from.

    .venv/bin/python benchmarks/diag_per_frame.py --out /tmp/sl/rel --runs a0,a0_nolayer
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from physar.recon.train import Reconstruction, cell_average_truth, load_dataset, simulate_clip


def load_run(out: Path, run: str, ds=None):
    """(dataset, Reconstruction, rig, truth averaged onto the rig's object particles, kinematics) of OUT/RUN,
    OUT/user/data read once (``ds``) for several runs."""
    ds = ds or load_dataset(Path(out) / "user" / "data")
    rc = Reconstruction.load(Path(out) / run)
    return ds, rc, rc.rig, cell_average_truth(rc.rig, ds.truth), rc.kinematics(ds.rotations, ds.root_t)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="OUT of bench_recon_pillow.py (OUT/user/data, OUT/RUN)")
    ap.add_argument("--runs", required=True, help="comma-separated RUN_DIR names under OUT")
    a = ap.parse_args()
    ds = None
    for run in a.runs.split(","):
        ds, rc, rig, gt, kin = load_run(a.out, run, ds)
        n = len(gt)
        sim = {f: xo.numpy() for f, xo, *_ in simulate_clip(rig, rc.phys, kin, n, grad=False)}
        top = rig.Xo[:, 2] > np.percentile(rig.Xo[:, 2], 70)
        err = [1e3 * np.linalg.norm(sim[f] - gt[f], axis=1).mean() for f in range(1, n)]
        dz = [1e3 * (sim[f][top, 2] - gt[f][top, 2]).mean() for f in range(1, n)]
        print(f"{run}: 3-D error per frame 1-{n - 1} (mm): " + " ".join(f"{v:.2f}" for v in err))
        print(f"{run}: top height error (mm, + above):  " + " ".join(f"{v:+.1f}" for v in dz))


if __name__ == "__main__":
    main()
