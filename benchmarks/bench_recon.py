"""Benchmark of the PhysHO reconstruction pipeline (issue 8): end-to-end training time of a reduced
synthetic scene on this CPU (goal < 30 min); reconstruction / prediction / novel-action PSNR, SSIM and IoU
of physics vs the LBS-only and 4DGS-like baselines (and the Eq. 9 structure-preserving flow), on all frames
and on the large-deformation subsets; the ablations of seed Table 3 (without latents l_e, without the
residual law E_theta: expert law only), fitted by the same harness from the same stages 1-2; and the
identifiability of E (object motion of the reconstruction's simulator for scaled / swapped E fields vs the
fine ground truth, no learning involved).

    .venv/bin/python benchmarks/bench_recon.py [--config examples/recon_bench.toml] [--out /tmp/bench_recon]
        [--no-ablations] [--no-diagnostics] [--identifiability-only] [--oracle]
    .venv/bin/python benchmarks/bench_recon.py --scenes pillow,cpillow,bag      # examples/recon_<name>.toml
    .venv/bin/python benchmarks/bench_recon.py --config a.toml --config b.toml  # one block of tables per scene

With several scenes each one gets its own folder OUT/<config stem>/ and its own tables, printed one after the
other (the scenes run sequentially; the times are per scene).

``--oracle`` also learns E from the cell-averaged true 3-D trajectories (no images; L1 over the observed
frames, Adam on log E) with the voxel-grid field and with one value per particle: it separates the question
"is E in the data?" from "can the images / the Eq. 9 flow deliver it?".
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
import torch

from physar.recon.synth import generate, load_synth_config
from physar.recon.train import (
    Physics,
    Rig,
    cell_average_truth,
    fit,
    load_dataset,
    load_train_config,
    simulate_clip,
)


def identifiability(data_dir: Path, tcfg, scales=(0.25, 0.5, 0.7, 1.4, 2.0, 4.0), true_label: str = "true field",
                    from_poses: bool = False, residual: bool | None = None,
                    log=None) -> list[tuple[str, float, float]]:
    """Mean 3-D object error (mm, observed frames) of the reconstruction's simulator run with given E fields
    (true field mapped to its particles, ``scales`` times it, swapped halves, uniform), vs the cell-averaged
    truth; and the mean distance (mm) to the motion with the true field (the signal an E change leaves in the
    data). ``from_poses``: the rig finds the simulated bones from the clip's poses (an imported scene lists
    none); ``residual``: override the config's residual law; ``log``: called with one line per field."""
    from scipy.spatial import cKDTree

    ds = load_dataset(data_dir)
    upd = {"material_grid": (0, 0, 0)} | ({} if residual is None else {"residual": residual})
    rig = Rig(ds.meta, tcfg.model_copy(update=upd), **({"poses": (ds.rotations, ds.root_t)} if from_poses else {}))
    kin = rig.kinematics(ds.rotations, ds.root_t)
    gt = cell_average_truth(rig, ds.truth)
    Et = ds.truth["E"][cKDTree(ds.truth["rest_positions"]).query(rig.Xo)[1]]

    def run(E):
        ph = Physics.init(rig)
        ph.log_E = torch.log(torch.as_tensor(E, dtype=torch.float64))
        return {f: xo.numpy() for f, xo, *_ in simulate_clip(rig, ph, kin, ds.n_obs, grad=False)}

    ref = run(Et)
    fr = range(1, ds.n_obs)
    rows = []
    fields = [(true_label, Et)] + [(f"{s} x true", s * Et) for s in scales] + [
        ("soft/stiff swapped", Et.min() + Et.max() - Et), ("uniform E_init", np.full(rig.no, tcfg.E_init))]
    for name, E in fields:
        x = run(E)
        rows.append((name, float(np.mean([np.linalg.norm(x[f] - gt[f], axis=1).mean() for f in fr]) * 1e3),
                     float(np.mean([np.linalg.norm(x[f] - ref[f], axis=1).mean() for f in fr]) * 1e3)))
        if log is not None:
            log(f"identifiability {name}: {rows[-1][1]:.2f} mm")
    return rows


def oracle_E(data_dir: Path, tcfg, grid, iters: int = 15, lr: float = 0.1,
             targets: np.ndarray | None = None, from_poses: bool = False, residual: bool = False,
             frames: str = "observed", displacement: bool = False,
             fitted: list | None = None) -> list[tuple[int, float, dict]]:
    """Learn log E from the true 3-D object trajectories (see the module docstring), or from ``targets``
    (F, No, 3) such as a run's Eq. 9 flow; per Adam step k = 1..iters, (k, L1 loss mm, material_error), both
    evaluated at the parameters *before* step k (k = 1: the initial guess).

    ``from_poses``: the rig finds the simulated bones from the clip's poses (an imported scene lists none);
    ``residual``: learn the residual laws and latents of seed Eq. 8 alongside E, at ``tcfg.net_lr``, with the
    Eq. 11 regulariser of the physics stage added to the loss (the L1 column stays the data term); omega, nu and
    the body's E stay at their initial values (the product's physics stage learns them too);
    ``frames``: "observed" or "all" (observed + predicted frames of the clip); ``displacement``: fit the true
    displacement added to the reconstruction's rest positions, X + (truth_f - truth_0), instead of the
    cell-averaged true positions, whose offset at rest (the fine truth resampled onto the reconstruction's
    particles: the 3-D error floor) the L1 loss would otherwise keep trying to close through E; ``fitted``: a
    list that receives (rig, Physics after the last step, kinematics)."""
    import math

    from physar.recon.train import Reconstruction, material_error, physics_regulariser

    if frames not in ("observed", "all"):
        raise ValueError(f"frames must be 'observed' or 'all', got {frames!r}")
    if targets is not None and displacement:
        raise ValueError("give targets or displacement=True, not both")
    ds = load_dataset(data_dir)
    rig = Rig(ds.meta, tcfg.model_copy(update={"material_grid": grid, "residual": residual}),
              **({"poses": (ds.rotations, ds.root_t)} if from_poses else {}))
    kin = rig.kinematics(ds.rotations, ds.root_t)
    if targets is None:
        g = cell_average_truth(rig, ds.truth)
        targets = rig.Xo + (g - g[0]) if displacement else g
    n = ds.n_obs if frames == "observed" else len(ds.rgb)
    if len(targets) < n:
        raise ValueError(f"targets cover {len(targets)} frames, frames={frames!r} needs {n}")
    gt = torch.as_tensor(targets)
    ph = Physics.init(rig)
    nets = ph.leaves()[len(ph.material_leaves()):]  # the residual networks and latents (none without residual)
    for t in [ph.log_E, *nets]:
        t.requires_grad_(True)
    opt = torch.optim.Adam([{"params": [ph.log_E], "lr": lr}] + ([{"params": nets, "lr": tcfg.net_lr}] if nets else []))
    rows = []
    for it in range(iters):
        loss = 0.0
        for f, xo, Fo, xh, Fh in simulate_clip(rig, ph, kin, n):
            loss = loss + (xo - gt[f]).abs().mean() / (n - 1)
        rows.append((it + 1, float(loss.detach()) * 1e3, material_error(Reconstruction(rig, None, [], ph), ds.truth)))
        total = loss + physics_regulariser(ph, rig, torch.cat([Fo, Fh])) if nets else loss
        opt.zero_grad()
        total.backward()
        opt.step()
        with torch.no_grad():
            ph.log_E.clamp_(math.log(tcfg.E_min), math.log(tcfg.E_max))
    if fitted is not None:
        fitted.append((rig, ph, kin))
    return rows


def grid_floor(data_dir: Path, tcfg, grid, from_poses: bool = False) -> float:
    """The E error (mean |log10 E / E_true| at the reconstruction's particles) of the best field the voxel grid
    ``grid`` can hold: log10 E_true fitted by least squares on the trilinear basis. No learning; the floor of the
    E error that the representation alone sets."""
    from scipy.spatial import cKDTree

    ds = load_dataset(data_dir)
    rig = Rig(ds.meta, tcfg.model_copy(update={"material_grid": grid}),
              **({"poses": (ds.rotations, ds.root_t)} if from_poses else {}))
    y = np.log10(ds.truth["E"][cKDTree(ds.truth["rest_positions"]).query(rig.Xo)[1]])
    if rig.material_W is None:
        return 0.0
    W = rig.material_W.to_dense().numpy() if rig.material_W.is_sparse else rig.material_W.numpy()
    c = np.linalg.lstsq(W, y, rcond=None)[0]
    return float(np.abs(W @ c - y).mean())


def pixel_fit_diagnostics(data_dir: Path, run_dir: Path, refit_iters: int = 150,
                          part: str = "recon") -> list[tuple[str, dict]]:
    """Is reconstruction PSNR a measure of 3-D accuracy here?  Metrics on the observed frames (all and the
    large-deformation subset) of the fitted appearance rendered with (a) the physics simulation, (b) the 4DGS-like
    per-frame positions, (c) the *true* object motion (the fine ground truth's displacement averaged onto the
    reconstruction's particles and added to their rest positions, F by least squares over lattice neighbours, the body as in (a): the truth stores no body motion) --
    the best any physical model at this
    particle resolution could move the object -- and (d, e) (a) and (b) after one shared refit of the canonical
    appearance (colours, opacities, scales; no per-frame parameters) on the observed frames with the motion
    fixed, applied to both methods alike.

    ``part="pred"``: the same on the prediction frames (after the observed ones), where the 4DGS-like fit holds
    its last observed positions (as ``recon eval`` scores it), the physics simulation runs on, and the refits
    (d, e) still use the observed frames only."""
    from physar.recon.metrics import large_deformation_frames, sequence_metrics
    from physar.recon.train import Reconstruction, refit_appearance, render_scene

    recon, ds = Reconstruction.load(run_dir), load_dataset(data_dir)
    rig = recon.rig
    kin = rig.kinematics(ds.rotations, ds.root_t)
    if part not in ("recon", "pred"):
        raise ValueError(f"part must be 'recon' or 'pred', got {part!r}")
    obs = list(range(1, ds.n_obs))
    n_all = len(ds.rgb)
    frames = obs if part == "recon" else list(range(ds.n_obs, n_all))
    sets = {part: frames,
            f"{part}_large": large_deformation_frames(ds.truth["dynamic_max_displacement"], frames)}
    g = cell_average_truth(rig, ds.truth)
    gt = torch.as_tensor(rig.Xo + (g - g[0]))  # the truth's displacement added to the canonical shape
    n_sim = ds.n_obs if part == "recon" else n_all
    with torch.no_grad():
        sim = {f: (xo, Fo, xh, Fh) for f, xo, Fo, xh, Fh in simulate_clip(rig, recon.phys, kin, n_sim, grad=False)}
    hold = lambda f: min(f, ds.n_obs - 1)  # the 4DGS-like fit has no positions after the observed frames
    per_frame = lambda xs: {f: (xs[hold(f)], rig.deformation_from_neighbours(xs[hold(f)]), kin["ref"][f],
                                kin["A_h"][f]) for f in obs + frames}  # render_scene applies the run's rule
    oracle = {f: (gt[f], rig.deformation_from_neighbours(gt[f]), sim[f][2], sim[f][3]) for f in frames}
    motions = {"physics simulation": sim, "4DGS-like per-frame positions": per_frame(recon.flow),
               "true object motion (oracle; body as simulated)": oracle}

    def score(app, motion):
        with torch.no_grad():
            rs = {f: render_scene(rig, app, *motion[f], kin["xb"][f], kin["A_b"][f]) for f in frames}
        rgb = np.zeros_like(ds.rgb)
        a = np.zeros_like(ds.mask)
        for f, r in rs.items():
            rgb[f], a[f] = r.rgb.numpy(), r.alpha.numpy()
        return {k: sequence_metrics(rgb, a, ds.rgb, ds.mask, fr) for k, fr in sets.items()}

    def refit(motion):  # every appearance parameter, on the observed frames
        return refit_appearance(rig, recon.app, {f: motion[f] for f in obs}, ds, kin, refit_iters,
                                colours_only=False, seed=0, lr=0.015)

    rows = [(name, score(recon.app, m)) for name, m in motions.items()]
    for name in ("physics simulation", "4DGS-like per-frame positions"):
        rows.append((f"{name}, appearance refit on the dynamic clip", score(refit(motions[name]), motions[name])))
    return rows


EXAMPLES = Path(__file__).parents[1] / "examples"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--config", action="append", default=None,
                    help="scene + training TOML (repeatable; default examples/recon_bench.toml)")
    ap.add_argument("--scenes", default=None, help="comma-separated names: examples/recon_<name>.toml each "
                    "(e.g. pillow,cpillow,bag)")
    ap.add_argument("--out", default="/tmp/bench_recon")
    ap.add_argument("--no-ablations", action="store_true")
    ap.add_argument("--identifiability-only", action="store_true")
    ap.add_argument("--oracle", action="store_true")
    ap.add_argument("--no-diagnostics", action="store_true", help="skip the pixel-fit diagnostics (true object "
                    "motion rendered; shared appearance refit for physics and 4DGS-like)")
    ap.add_argument("--flow-run", default=None, help="with --oracle: also learn E (grid) from the Eq. 9 flow "
                    "and the 4DGS-like positions of this RUN_DIR (same scene)")
    a = ap.parse_args()
    configs = list(a.config or [])
    for name in (a.scenes.split(",") if a.scenes else []):
        p = EXAMPLES / f"recon_{name.strip()}.toml"
        if not p.exists():
            known = sorted(q.stem[6:] for q in EXAMPLES.glob("recon_*.toml"))
            raise SystemExit(f"--scenes: no {p} (known: {', '.join(known)})")
        configs.append(str(p))
    configs = configs or [str(EXAMPLES / "recon_bench.toml")]
    if a.flow_run and len(configs) > 1:
        raise SystemExit("--flow-run needs exactly one scene")
    for cfg_path in configs:
        out = Path(a.out) if len(configs) == 1 else Path(a.out) / Path(cfg_path).stem
        if len(configs) > 1:
            print(f"\n## scene {Path(cfg_path).stem} ({cfg_path})")
        run_scene(cfg_path, out, a)


def run_scene(config: str, out: Path, a) -> None:
    scfg, tcfg = load_synth_config(config), load_train_config(config)
    if scfg.gt_particles_per_cell <= tcfg.particles_per_cell:
        raise SystemExit(f"{config}: gt_particles_per_cell ({scfg.gt_particles_per_cell}) must exceed the "
                         f"reconstruction's particles_per_cell ({tcfg.particles_per_cell}): no inverse crime")
    print(f"load average at start: {os.getloadavg()[0]:.2f} (2 shared cores)")
    t0 = time.perf_counter()
    generate(out / "data", scfg)
    t_gen = time.perf_counter() - t0
    ds = load_dataset(out / "data")
    px = 2 * ds.meta["camera"]["cx"] / ds.meta["camera"]["fx"] * 0.75 / scfg.image_size  # m per px at the object
    print(f"\nE identifiability (no learning; 1 px ~ {px * 1e3:.1f} mm at the object):")
    print("| E field | 3-D error vs truth (mm) | distance to the true-field motion (mm) |")
    print("|---|---|---|")
    for name, e, d in identifiability(out / "data", tcfg):
        print(f"| {name} | {e:.2f} | {d:.2f} |")
    if a.oracle:
        print("\nE learned from the true 3-D trajectories (oracle supervision, no images):")
        print("| E parameterisation | iteration | L1 (mm) | mean abs log10 E error | soft / stiff geomean (Pa) | "
              "stiff/soft |")
        print("|---|---|---|---|---|---|")
        for grid in () if a.flow_run else (tuple(tcfg.material_grid), (0, 0, 0)):
            label = "per particle" if grid == (0, 0, 0) else f"voxel grid {grid}"
            for it, l1, m in oracle_E(out / "data", tcfg, grid):
                if it in (1, 5, 10, 15):
                    print(f"| {label} | {it} | {l1:.3f} | {m['mean_abs_log10_error']:.3f} | "
                          f"{m['E_soft_learned_geomean']:.0f} / {m['E_stiff_learned_geomean']:.0f} | "
                          f"{m['stiff_soft_ratio_learned']:.2f} |")
        if a.flow_run:
            with np.load(Path(a.flow_run) / "model.npz") as m:
                flows = {"Eq. 9 flow (spflow)": m["spflow"], "4DGS-like positions": m["flow"]}
            for label, tg in flows.items():
                for it, l1, m in oracle_E(out / "data", tcfg, tuple(tcfg.material_grid), targets=tg):
                    if it in (1, 5, 10, 15):
                        print(f"| grid, targets = {label} | {it} | {l1:.3f} | {m['mean_abs_log10_error']:.3f} | "
                              f"{m['E_soft_learned_geomean']:.0f} / {m['E_stiff_learned_geomean']:.0f} | "
                              f"{m['stiff_soft_ratio_learned']:.2f} |")
    if a.identifiability_only:
        return
    variants = [("full", {})]
    if tcfg.residual and not a.no_ablations:
        variants += [("w/o latents l_e", {"latents": False}), ("w/o residual law E_theta", {"residual": False})]
    reports = {}
    for name, upd in variants:
        t1 = time.perf_counter()
        cfg = tcfg.model_copy(update=upd)
        rep = fit(out / "data", out / ("run" if name == "full" else "run_" + name.split()[1]), cfg, restart=True,
                  reuse=None if name == "full" else out / "run")
        reports[name] = (rep, time.perf_counter() - t1)
    rep, t_fit = reports["full"]
    print(f"\nscene: {scfg.object} + {scfg.action}, {scfg.image_size}px, spin clip {scfg.spin_frames} frames, "
          f"{scfg.frames} dynamic frames ({scfg.n_obs} observed), {scfg.novel_frames} novel-action frames; ground truth "
          f"{scfg.gt_particles_per_cell} particles/cell, reconstruction {tcfg.particles_per_cell}")
    print(f"generation {t_gen:.1f} s; full model: train {rep['train_seconds']:.1f} s (fit + evaluation "
          f"{t_fit:.1f} s); load average now {os.getloadavg()[0]:.2f}\n")
    print("| method | subset | PSNR | SSIM | IoU | frames |")
    print("|---|---|---|---|---|---|")
    for m, res in rep["methods"].items():
        for s, v in res.items():
            print(f"| {m} | {s} | {v['psnr']:.2f} | {v['ssim']:.4f} | {v['iou']:.4f} | {v['frames']} |")
    print("\nobject 3-D error (mm, observed frames):", json.dumps(rep["object_3d_error_mm"]))
    print("canonical (spin clip PSNR):", json.dumps(rep["canonical"]))
    print("omega:", json.dumps(rep["omega"]))
    print("LPIPS:", rep["lpips"])
    print("\n| variant | recon PSNR | recon IoU | recon_large PSNR | recon_large IoU | pred PSNR | pred IoU | "
          "novel PSNR | novel IoU | 3-D err (mm) | E mean abs log10 err | stiff/soft (true "
          f"{rep['material']['stiff_soft_ratio_true']:.0f}) | physics stage s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, (r, _) in reports.items():
        p = r["methods"]["physics"]
        mat = r["material"]
        print(f"| {name} | {p['recon']['psnr']:.2f} | {p['recon']['iou']:.4f} | {p['recon_large']['psnr']:.2f} | "
              f"{p['recon_large']['iou']:.4f} | {p['pred']['psnr']:.2f} | {p['pred']['iou']:.4f} | "
              f"{p['novel']['psnr']:.2f} | {p['novel']['iou']:.4f} | {r['object_3d_error_mm']['physics']:.2f} | "
              f"{mat['mean_abs_log10_error']:.3f} (init {mat['initial_mean_abs_log10_error']:.3f}) | "
              f"{mat['stiff_soft_ratio_learned']:.2f} | "
              f"{r['train_seconds'] - r['canonical'].get('stages_seconds', 0.0):.0f} |")
    if not a.no_diagnostics:
        print("\nPixel-fit diagnostics (observed frames; same fitted appearance unless refit):")
        print("| object motion rendered | recon PSNR | recon IoU | recon_large PSNR | recon_large IoU |")
        print("|---|---|---|---|---|")
        for name, m in pixel_fit_diagnostics(out / "data", out / "run"):
            print(f"| {name} | {m['recon']['psnr']:.2f} | {m['recon']['iou']:.4f} | {m['recon_large']['psnr']:.2f} | "
                  f"{m['recon_large']['iou']:.4f} |")


if __name__ == "__main__":
    main()
