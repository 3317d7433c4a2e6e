"""Which part of the Eq. 9 flow target is worth comparing in the Eq. 10 term (issue 17, ``TrainConfig.flow_target``)?

For a run of ``bench_recon_pillow.py`` (its OUT/user/data with the truth, and OUT/RUN's model): per observed frame f,
the displacement error |(x_f - X) - (truth_f - truth_0)| (mm, no resampling floor; truth = the fine particles
averaged onto the reconstruction's) of the Eq. 9 target x'_f and of the run's physics, on the particles visible in
frame f - 1 (those whose motion into frame f the optical flow saw; ``train._visible_at``) and on the hidden ones,
whole and across the camera rays (the component a 2-D flow measures).  The part of the target that beats the
simulator is the part the Eq. 10 term should compare.

    .venv/bin/python benchmarks/diag_flow_target.py --out /tmp/fl/rel --run s0_noflow
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from diag_per_frame import load_run  # a sibling script: benchmarks/ is on sys.path when run

from physar.recon import scene as S
from physar.recon.train import _visible_at, simulate_clip


def errors(x: np.ndarray, X: np.ndarray, gt: np.ndarray, gt0: np.ndarray, ray: np.ndarray, m: np.ndarray):
    """(mean |displacement error|, mean |its part across the rays|) in mm over the particles m."""
    d = (x[m] - X[m]) - (gt[m] - gt0[m])
    a = (d * ray[m]).sum(1, keepdims=True)
    return 1e3 * np.linalg.norm(d, axis=1).mean(), 1e3 * np.linalg.norm(d - a * ray[m], axis=1).mean()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="OUT of bench_recon_pillow.py (OUT/user/data, OUT/RUN)")
    ap.add_argument("--run", required=True, help="RUN_DIR under OUT whose physics and Eq. 9 target are scored")
    a = ap.parse_args()
    ds, rc, rig, gt, kin = load_run(a.out, a.run)
    K, R, t = (torch.as_tensor(v) for v in S.camera_matrices(rig.meta))
    centre = (-(R.T @ t)).numpy()
    sim = {f: xo.numpy() for f, xo, *_ in simulate_clip(rig, rc.phys, kin, ds.n_obs, grad=False)}
    X = np.asarray(rig.Xo, dtype=np.float64)
    print("| frame | visible particles | target, visible (whole / across the rays, mm) | physics, visible | target, hidden | physics, hidden |")
    print("|---|---|---|---|---|---|")
    for f in range(1, ds.n_obs):
        vis = _visible_at(rig, rc.app, kin, f - 1, torch.as_tensor(rc.spflow[f - 1]), K, R, t).numpy()
        ray = gt[f] - centre
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        cells = [errors(np.asarray(x), X, gt[f], gt[0], ray, m) for m in (vis, ~vis) for x in (rc.spflow[f], sim[f])]
        print(f"| {f} | {int(vis.sum())} / {len(vis)} | " + " | ".join(f"{w:.2f} / {c:.2f}" for w, c in cells) + " |")


if __name__ == "__main__":
    main()
