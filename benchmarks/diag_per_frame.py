"""Per-frame 3-D error of the object for runs of ``bench_recon_pillow.py`` (issue 17): mean |x_f - truth_f| (mm)
of the reconstruction's object particles, simulated by each run's physics over the whole dynamic clip, against
the fine truth averaged onto them (``train.cell_average_truth``); and the mean height error of the object's top
30 % (mm, + = above the truth), which shows a plastic dent the simulation springs back from.

    .venv/bin/python benchmarks/diag_per_frame.py --out /tmp/sl/rel --runs a0,a0_nolayer

``--oracle ITERS``: also, for the first run's configuration, learn the physics from the true 3-D displacements of
the observed frames instead of images (``bench_recon.oracle_E``, ITERS Adam steps, expert law alone and with the
residual laws of seed Eq. 8), and print the same rows for those fits: whether the laws can express what the runs
miss (the plastic dent) when the supervision is perfect; ``--oracle-set KEY=VALUE`` changes a [train] field of
those fits (e.g. ``net_lr=1e-2``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from physar.errors import SolverError
from physar.recon.train import (
    Reconstruction,
    TrainConfig,
    _with_pre_option_defaults,
    cell_average_truth,
    load_dataset,
    simulate_clip,
)


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
    ap.add_argument("--oracle", type=int, default=0, metavar="ITERS", help="also fit from the true 3-D "
                    "displacements of the observed frames (ITERS Adam steps; 0: off)")
    ap.add_argument("--oracle-set", action="append", default=[], metavar="KEY=VALUE",
                    help="[train] override of the oracle fits (repeatable; a TOML value), e.g. net_lr=1e-2")
    ap.add_argument("--oracle-laws", choices=("both", "expert", "residual"), default="both",
                    help="the oracle fits to run: expert law alone, with the residual laws, or both")
    a = ap.parse_args()
    if a.oracle < 0 or (a.oracle_set and not a.oracle):
        raise SystemExit("--oracle ITERS: give ITERS >= 1 (0: off; --oracle-set needs it)")
    cfg = None
    if a.oracle:
        from bench_recon_pillow import parse_overrides  # sibling script: benchmarks/ is on sys.path when run

        over = parse_overrides(a.oracle_set, flag="--oracle-set")
        first = json.loads(str(np.load(Path(a.out) / a.runs.split(",")[0] / "model.npz")["config_json"]))
        try:
            cfg = TrainConfig.model_validate({**_with_pre_option_defaults(first), **over})
        except ValidationError as exc:
            raise SystemExit(f"--oracle-set {' '.join(a.oracle_set)}: {exc.errors()[0]['msg']}") from None
    ds = None
    for run in a.runs.split(","):
        ds, rc, rig, gt, kin = load_run(a.out, run, ds)
        report(run, rig, rc.phys, kin, gt)
    if a.oracle:
        from bench_recon import oracle_E

        for resid in {"both": (False, True), "expert": (False,), "residual": (True,)}[a.oracle_laws]:
            fitted = []
            rows = oracle_E(Path(a.out) / "user" / "data", cfg, tuple(cfg.material_grid), iters=a.oracle,
                            lr=cfg.physics_lr, from_poses=True, residual=resid, frames="observed",
                            displacement=True, fitted=fitted)
            orig, ph, okin = fitted[0]
            label = f"oracle {a.oracle} it, {'expert + residual' if resid else 'expert only'}"
            print(f"{label}: L1 loss (mm) at the initial guess {rows[0][1]:.3f}, before the last step "
                  f"{rows[-1][1]:.3f}")
            report(label, orig, ph, okin, cell_average_truth(orig, ds.truth))


def report(label: str, rig, phys, kin, gt) -> None:
    """Print the per-frame 3-D error and the top height error of ``phys`` simulated over the clip."""
    n = len(gt)
    try:
        sim = {f: xo.numpy() for f, xo, *_ in simulate_clip(rig, phys, kin, n, grad=False)}
    except SolverError as exc:  # e.g. residual laws freed of the Eq. 11 term for many steps
        print(f"{label}: {exc}", flush=True)
        return
    top = rig.Xo[:, 2] > np.percentile(rig.Xo[:, 2], 70)
    err = [1e3 * np.linalg.norm(sim[f] - gt[f], axis=1).mean() for f in range(1, n)]
    dz = [1e3 * (sim[f][top, 2] - gt[f][top, 2]).mean() for f in range(1, n)]
    print(f"{label}: 3-D error per frame 1-{n - 1} (mm): " + " ".join(f"{v:.2f}" for v in err))
    print(f"{label}: top height error (mm, + above):  " + " ".join(f"{v:+.1f}" for v in dz), flush=True)


if __name__ == "__main__":
    main()
