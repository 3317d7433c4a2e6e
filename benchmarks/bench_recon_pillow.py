"""Benchmark of issue 17 part 4: the anny body presses a C-shaped pillow with both forearms and hands (truth:
anisotropic fibres + von Mises plasticity on 27 particles per cell, :mod:`physar.recon.synth_anny`), rendered by
the sphere renderer, exported as a user's files (MP4, label PNGs, SMPL npz in camera coordinates, object OBJ)
and read back through ``physar recon import`` (subprocess, the real user's route) and checked by ``physar recon
check``; then ``recon fit`` (:func:`physar.recon.train.fit`, which evaluates every method) and ``physar recon
predict`` of the novel action (subprocess).

Measured on the large-deformation subsets (frames whose true maximum object displacement is >= half the
subset's maximum): PSNR / SSIM / IoU of physics, LBS-only and the 4DGS-like per-frame fit for reconstruction,
prediction and the novel action; the mean 3-D object error (mm, vs the fine truth averaged onto the
reconstruction's particles; its floor, the error of the rest shape at frame 0, comes from resampling 27 onto 8
particles per cell) and the displacement error |(x_f - X) - (truth_f - truth_0)| (no floor) on the same frames
(LBS-only = the object at rest; 4DGS-like holds its last observed
frame in prediction and has no motion of its own for a novel action, so it is the object at rest there);
reconstruction PSNR of the fitted appearance rendered with the true object motion (the oracle of
``bench_recon.pixel_fit_diagnostics``); learned E error mean |log10 E / E_true| vs the initial guess's.

    .venv/bin/python benchmarks/bench_recon_pillow.py [--quick] [--config examples/recon_anny_cpillow.toml]
        [--out /tmp/bench_recon_pillow] [--no-diagnostics] [--ablations]

``--quick``: 96 px, 6 + 4 + 5 frames, fewer iterations (a few minutes); the full run is the TOML as written.
``--ablations`` (seed 002 Table 3): the full model switches on each ablated part the TOML leaves off (residual
laws with latents, the 3-D flow term at TrainConfig's default lambda_flow, the omega = 0 surface layer at its
default depth); after its fit, each variant refits only the physics stage on the full run's stages 1-2
(``fit(..., reuse=)``, as in bench_recon) into OUT/RUN_<variant>, and one table row per variant is printed.
``--variants`` picks a subset of the ablations; ``--set KEY=VALUE`` overrides any [train] field (TOML value) of
the full model and every variant; ``--stages RUN`` makes the full model reuse OUT/RUN's stages 1-2 too, so settings
are compared on the same appearance and Eq. 9 flow (see also ``diag_residual_pillow.py``).
``--oracle-e ITERS`` asks whether the learned-E goal is reachable at all: E learned from the true 3-D
displacements, no images (``bench_recon.oracle_E``), with the expert law alone, with the residual laws, and on a
control scene generated with the reconstruction's own law (isotropic fixed-corotated: no fibres, no yield).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from physar.errors import ConfigError
from physar.recon.metrics import large_deformation_frames
from physar.recon.synth_anny import (
    AnnySceneConfig,
    attach_truth,
    export_user_files,
    generate_anny,
    load_anny_config,
)
from physar.recon.train import (
    Reconstruction,
    TrainConfig,
    cell_average_truth,
    fit,
    load_dataset,
    load_train_config,
)

ROOT = Path(__file__).parents[1]
QUICK_SYNTH = {"image_size": 96, "frames": 6, "n_obs": 4, "novel_frames": 5, "spin_frames": 4}
QUICK_SYNTH_KEYED = {"image_size": 96, "spin_frames": 4}  # a scene with depth keyframes keeps its clip lengths
QUICK_TRAIN = {"appearance_iters": 40, "finetune_iters": 10, "flow_iters": 8, "spflow_iters": 30,
               "physics_iters": 10, "window_start": 3}
# seed 002 Table 3 ablations: (row, RUN_DIR suffix, TrainConfig update of the full model)
ABLATIONS = (("w/o latents l_e", "nolatents", {"latents": False}),
             ("w/o residual law E_theta", "noresidual", {"residual": False}),
             ("w/o 3-D flow (lambda_flow 0)", "noflow", {"lambda_flow": 0.0}),
             ("w/o omega = 0 layer", "nolayer", {"surface_layer": 0.0}))
PHYSAR = [sys.executable, "-c", "from physar.cli.main import main; main()"]


def log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')} load {os.getloadavg()[0]:.2f}] {msg}", flush=True)


def cli(*args) -> dict | None:
    r = subprocess.run([*PHYSAR, *map(str, args)], check=False, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"physar {' '.join(map(str, args[:2]))} failed ({r.returncode}): {r.stderr[-2000:]}")
    i = r.stdout.find("{")
    return json.loads(r.stdout[i:]) if i >= 0 else None


def errors_3d(recon: Reconstruction, ds, key: str, rotations, root_t, frames, hold_from: int | None) -> dict:
    """Mean 3-D object error (mm) over ``frames`` of physics, LBS-only (rest) and 4DGS-like (its per-frame
    positions while observed, then its last observed frame; rest when ``hold_from`` is None: a novel action)."""
    rig = recon.rig
    gt = cell_average_truth(rig, {"rest_positions": ds.truth["rest_positions"],
                                  "dynamic_object_positions": ds.truth[f"{key}_object_positions"]})
    objs: list = []
    recon.render_sequence(recon.kinematics(rotations, root_t), "physics", objects=objs)
    err = lambda x, f: float(np.linalg.norm(np.asarray(x) - gt[f], axis=1).mean() * 1e3)
    # displacement error: |(x_f - X) - (gt_f - gt_0)|, without the resampling floor (frame 0's error)
    derr = lambda x, f: float(np.linalg.norm(np.asarray(x) - rig.Xo - (gt[f] - gt[0]), axis=1).mean() * 1e3)
    fl = [x.numpy() for x in recon.flow]
    four = (lambda f: fl[min(f, len(fl) - 1)]) if hold_from is not None else (lambda f: rig.Xo)
    m = lambda fn: float(np.mean([fn(f) for f in frames])) if frames else float("nan")
    out = {"floor": err(rig.Xo, 0)}
    for name, pos in (("physics", lambda f: objs[f]), ("lbs", lambda f: rig.Xo), ("4dgs", four)):
        out[name] = m(lambda f, pos=pos: err(pos(f), f))
        out[name + "_disp"] = m(lambda f, pos=pos: derr(pos(f), f))
    return out


def subset_errors(recon: Reconstruction, ds, sub: dict) -> dict:
    """:func:`errors_3d` on the three large-deformation subsets."""
    no, nv = ds.n_obs, ds.novel
    return {"recon_large": errors_3d(recon, ds, "dynamic", ds.rotations, ds.root_t, sub["recon_large"], no),
            "pred_large": errors_3d(recon, ds, "dynamic", ds.rotations, ds.root_t, sub["pred_large"], no),
            "novel_large": errors_3d(recon, ds, "novel", nv["rotations"], nv["root_t"], sub["novel_large"], None)}


def parse_overrides(items: list[str], fields=TrainConfig.model_fields, flag: str = "--set",
                    section: str = "[train]") -> dict:
    """``--set key=value`` items -> a dict of [train] fields (``fields``); each value is read as TOML (``1e-2``,
    ``30``, ``true``, ``[3, 4, 4]``)."""
    import tomllib

    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or key.strip() not in fields:
            raise SystemExit(f"{flag} {item!r}: expected KEY=VALUE with KEY a {section} field")
        try:
            out[key.strip()] = tomllib.loads(f"v = {value.strip()}")["v"]
        except tomllib.TOMLDecodeError as exc:
            raise SystemExit(f"{flag} {item!r}: the value is not TOML ({exc})") from None
    return out


def residual_summary(run_dir: Path) -> dict | None:
    """Size of the learned residual laws of a run (None without them): mean |w| of each network's
    zero-initialised output layer and the mean |l| of its latents (initial 0.1 * N(0, 1): 0.080)."""
    d = np.load(run_dir / "model.npz")
    keys = [k for k in d.files if "l3.weight" in k or k in ("l_e", "l_p")]
    return {k: float(np.abs(d[k]).mean()) for k in keys} or None


def full_model(tcfg: TrainConfig) -> TrainConfig:
    """The full model of the ablations: every part an ablation removes switched on."""
    return tcfg.model_copy(update={
        "residual": True, "latents": True,
        "lambda_flow": tcfg.lambda_flow or TrainConfig.model_fields["lambda_flow"].default,
        "surface_layer": tcfg.surface_layer or None})  # None: half the particle spacing


def export_import(data: Path, user: Path) -> None:
    """A generated scene written as a user's files and read back through ``physar recon import`` (subprocess)
    into ``user/data`` and ``user/novel``, with the truth attached."""
    args = export_user_files(data, user)
    for key, dst in (("args", user / "data"), ("novel_args", user / "novel")):
        if dst.exists():
            shutil.rmtree(dst)
        cli("recon", "import", *args[key], "--out", dst, "--json")
    attach_truth(user / "data", user / "novel", data)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--config", default=str(ROOT / "examples" / "recon_anny_cpillow.toml"))
    ap.add_argument("--out", default="/tmp/bench_recon_pillow")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-diagnostics", action="store_true")
    ap.add_argument("--reuse-data", action="store_true", help="keep OUT/data and OUT/user (and OUT/control) when "
                    "present, whatever --synth-set generated them")
    ap.add_argument("--seed", type=int, default=None, help="[train] seed override (spread over runs)")
    ap.add_argument("--run", default="run", help="RUN_DIR name under OUT")
    ap.add_argument("--identifiability", action="store_true", help="also run bench_recon.identifiability on the "
                    "imported scene: the reconstruction's simulator with scaled / uniform E fields vs the truth")
    ap.add_argument("--oracle-e", type=int, default=0, metavar="ITERS",
                    help="also learn E from the true 3-D displacements (no images; bench_recon.oracle_E, all frames, "
                    "ITERS Adam steps: log E at physics_lr, the residual laws at net_lr with the Eq. 11 regulariser) "
                    "with the expert law alone and with the residual laws, and on a control scene whose truth has the "
                    "reconstruction's law (no fibres, no yield; generated into OUT/control and read back through "
                    "recon import like OUT/user)")
    ap.add_argument("--eval-only", action="store_true", help="reuse OUT/data, OUT/user and OUT/run (its "
                    "report.json): recompute the tables without fitting")
    ap.add_argument("--ablations", action="store_true", help="full model with every ablated part on, then "
                    "physics-only refits w/o latents, w/o residual law, w/o 3-D flow, w/o omega = 0 layer")
    ap.add_argument("--variants", default=",".join(s for _, s, _ in ABLATIONS),
                    help="with --ablations: comma-separated subset of " + ", ".join(s for _, s, _ in ABLATIONS))
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="[train] override (repeatable; a TOML value: 1e-2, 30, true, [3, 4, 4]), applied after "
                    "--quick and, with --ablations, to the full model and every variant")
    ap.add_argument("--synth-set", action="append", default=[], metavar="KEY=VALUE",
                    help="[synth] override of the scene (repeatable; a TOML value), e.g. fiber_E=0.0")
    ap.add_argument("--stages", default=None, metavar="RUN", help="take stages 1-2 (appearance, flows) of OUT/RUN "
                    "as they are (fit(..., reuse=)): only the physics stage is fitted")
    a = ap.parse_args()
    if a.oracle_e < 0:
        raise SystemExit(f"--oracle-e {a.oracle_e}: give a number of iterations >= 1 (0: off)")
    torch.set_num_threads(min(2, torch.get_num_threads()))
    synth_over = parse_overrides(a.synth_set, AnnySceneConfig.model_fields, "--synth-set", "[synth]")
    try:
        base = load_anny_config(a.config, synth_over)
        keyed = bool(base.depth_keys or base.novel_depth_keys)
        scfg = load_anny_config(a.config, {**((QUICK_SYNTH_KEYED if keyed else QUICK_SYNTH) if a.quick else {}),
                                           **synth_over})
    except ConfigError as exc:
        raise SystemExit(f"{exc}{' (with --synth-set ' + ' '.join(a.synth_set) + ')' if a.synth_set else ''}") from None
    tcfg = load_train_config(a.config, {**(QUICK_TRAIN if a.quick else {}),
                                        **({} if a.seed is None else {"seed": a.seed})})
    if scfg.gt_particles_per_cell <= tcfg.particles_per_cell:
        raise SystemExit("gt_particles_per_cell must exceed the reconstruction's particles_per_cell")
    if a.ablations:
        tcfg = full_model(tcfg)
    tcfg = tcfg.model_copy(update=parse_overrides(a.set))
    TrainConfig.model_validate(tcfg.model_dump())  # the overrides checked like a TOML's
    ablations = [x for x in ABLATIONS if x[1] in a.variants.split(",")] if a.ablations else []
    if a.ablations:
        for name, _, upd in ablations:  # each variant must differ from the full model in the config used
            if all(getattr(tcfg, k) == v for k, v in upd.items()):
                raise SystemExit(f"{name}: the full model already has {upd}")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    t_all = time.perf_counter()
    log(f"start: {a.config}{' --quick' if a.quick else ''}, {scfg.image_size} px, torch threads "
        f"{torch.get_num_threads()}")
    data, user = out / "data", out / "user"
    t0 = time.perf_counter()
    a.reuse_data = a.reuse_data or a.eval_only
    if not (a.reuse_data and (data / "truth.npz").exists()):
        step = {}

        def prog(k, i, n):
            if step.get(k, -1) < i * 4 // n:
                step[k] = i * 4 // n
                log(f"generate {k}: {i}/{n}")
        generate_anny(data, scfg, prog)
    t_gen = time.perf_counter() - t0
    log(f"generated in {t_gen:.0f} s")
    t0 = time.perf_counter()
    if not (a.reuse_data and (user / "data" / "truth.npz").exists()):
        export_import(data, user)
    chk = cli("recon", "check", user / "data", "--json")
    t_imp = time.perf_counter() - t0
    log(f"exported + imported in {t_imp:.0f} s; recon check problems: {chk['problems']}")
    t0 = time.perf_counter()
    step = {}

    def fprog(stage, i, n, loss):
        if step.get(stage, -1) < i * 4 // max(n, 1):
            step[stage] = i * 4 // max(n, 1)
            log(f"fit {stage}: {i}/{n} loss {loss:.4f}")
    if a.eval_only:
        rep = json.loads((out / a.run / "report.json").read_text())
    else:
        rep = fit(user / "data", out / a.run, tcfg, progress=fprog, restart=True,
                  reuse=out / a.stages if a.stages else None)
    t_fit = time.perf_counter() - t0
    log(f"fit + evaluation in {t_fit:.0f} s")
    if not a.eval_only:
        cli("recon", "predict", out / a.run, "--poses", user / "data" / "novel_poses.npz", "--out", out / "novel.mp4")
    ds = load_dataset(user / "data")
    recon = Reconstruction.load(out / a.run)
    n, no = len(ds.rgb), ds.n_obs
    disp = ds.truth["dynamic_max_displacement"]
    sub = {"recon_large": large_deformation_frames(disp, range(1, no)),
           "pred_large": large_deformation_frames(disp, range(no, n)),
           "novel_large": large_deformation_frames(ds.truth["novel_max_displacement"], range(1, len(ds.novel["rgb"])))}
    e3 = subset_errors(recon, ds, sub)
    abl = {}
    for name, suffix, upd in ablations:
        rd = out / f"{a.run}_{suffix}"
        t0 = time.perf_counter()
        if a.eval_only:
            r = json.loads((rd / "report.json").read_text())
        else:
            log(f"ablation {name}: physics stage on {out / (a.stages or a.run)}'s stages 1-2")
            r = fit(user / "data", rd, tcfg.model_copy(update=upd), progress=fprog, restart=True,
                    reuse=out / (a.stages or a.run))
        abl[name] = {"update": upd, "physics": r["methods"]["physics"], "material": r["material"],
                     "errors_3d_mm": {s: v["physics"] for s, v in subset_errors(Reconstruction.load(rd), ds,
                                                                                sub).items()},
                     "residual": residual_summary(rd), "fit_eval_s": time.perf_counter() - t0}
    oracle, ident = None, None
    spec = importlib.util.spec_from_file_location("bench_recon", ROOT / "benchmarks" / "bench_recon.py")
    br = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(br)
    if a.identifiability:
        log("E identifiability (the reconstruction's simulator, observed frames, no learning)")
        # with the simulated bones of the clip (an imported scene lists none: the rig finds the reaching bones
        # from the poses), no residual law, the true isotropic E (nearest fine particle)
        ident = br.identifiability(user / "data", tcfg, scales=(0.5, 2.0, 4.0), true_label="true isotropic field",
                                   from_poses=True, residual=False, log=log)
    oracle_e, floor_e = {}, None
    if a.oracle_e:
        floor_e = br.grid_floor(user / "data", tcfg, tuple(tcfg.material_grid), from_poses=True)
        control = out / "control"
        if not (a.reuse_data and (control / "user" / "data" / "truth.npz").exists()):
            log("control scene: the same clip with an isotropic fixed-corotated truth (fiber_E 0, yield_stress 0)")
            generate_anny(control / "data", scfg.model_copy(update={"fiber_E": 0.0, "yield_stress": 0.0}))
            export_import(control / "data", control / "user")
        for label, d, resid in (("truth as generated, expert law only", user / "data", False),
                                ("truth as generated, expert + residual laws", user / "data", True),
                                ("control truth (the expert law's own), expert law only", control / "user" / "data",
                                 False)):
            log(f"E oracle: {label}")
            oracle_e[label] = [(it, l1, m["mean_abs_log10_error"], m["E_soft_learned_geomean"],
                                m["E_stiff_learned_geomean"])
                               for it, l1, m in br.oracle_E(d, tcfg, tuple(tcfg.material_grid), iters=a.oracle_e,
                                                            lr=tcfg.physics_lr, from_poses=True, residual=resid,
                                                            frames="all", displacement=True)]
    if not a.no_diagnostics:
        log("pixel-fit diagnostics (true-motion oracle render)")
        oracle = br.pixel_fit_diagnostics(user / "data", out / a.run)
    mat = rep["material"]
    res = {"config": a.config, "quick": a.quick, "image_size": scfg.image_size, "subsets": sub, "errors_3d_mm": e3,
           "methods": rep["methods"], "material": mat, "simulated_bones": recon.rig.meta["body"]["simulated_bones"],
           "times_s": {"generate": t_gen, "export_import_check": t_imp, "fit_eval": t_fit,
                       "train": rep["train_seconds"], "total": time.perf_counter() - t_all},
           "oracle": oracle, "identifiability": ident, "oracle_E": oracle_e, "E_grid_floor": floor_e, "check_problems": chk["problems"],
           "load_end": os.getloadavg()[0],
           "ablations": abl, "residual": residual_summary(out / a.run), "overrides": a.set, "synth_overrides": a.synth_set,
           "stages": a.stages,
           "train_config": tcfg.model_dump(mode="json")}
    (out / f"results_{a.run}.json").write_text(json.dumps(res, indent=1, default=float))
    print(f"\nscene: anny + {scfg.object} ({scfg.action}), both forearms/hands ({len(res['simulated_bones'])} simulated bones), "
          f"{scfg.image_size} px, spin {scfg.spin_frames} / dynamic {scfg.frames} ({scfg.n_obs} observed) / novel "
          f"{scfg.novel_frames} frames; truth {scfg.gt_particles_per_cell}/cell"
          f"{f', fibres {scfg.fiber_E:g} Pa' if scfg.fiber_E > 0 else ', no fibres'}"
          f"{f', von Mises ({scfg.yield_stress:g} Pa)' if scfg.yield_stress > 0 else ', elastic'}"
          f"{f', passive body layer {1e3 * scfg.soft_layer:g} mm' if scfg.soft_layer > 0 else ''}"
          f", recon {tcfg.particles_per_cell}/cell")
    print(f"times: generate {t_gen:.0f} s, export+import+check {t_imp:.0f} s, fit+eval {t_fit:.0f} s (train "
          f"{rep['train_seconds']:.0f} s); load average at the end {os.getloadavg()[0]:.2f}\n")
    print(f"| subset (frames) | method | PSNR | SSIM | IoU | 3-D error (mm; floor {e3['recon_large']['floor']:.2f}) | "
          "displacement error (mm) |")
    print("|---|---|---|---|---|---|---|")
    for s in ("recon_large", "pred_large", "novel_large"):
        for m in ("physics", "lbs", "4dgs"):
            v = rep["methods"][m][s]
            print(f"| {s} ({','.join(map(str, sub[s]))}) | {m} | {v['psnr']:.2f} | {v['ssim']:.4f} | {v['iou']:.4f} | "
                  f"{e3[s][m]:.2f} | {e3[s][m + '_disp']:.2f} |")
    print(f"\nlearned E: mean |log10 E/E_true| {mat['mean_abs_log10_error']:.3f} (initial guess "
          f"{mat['initial_mean_abs_log10_error']:.3f}); soft/stiff geomean {mat['E_soft_learned_geomean']:.0f} / "
          f"{mat['E_stiff_learned_geomean']:.0f} Pa (true {mat['E_soft_true']:.0f} / {mat['E_stiff_true']:.0f})")
    if ident:
        print("\n| E field (reconstruction's simulator, no learning) | 3-D error vs truth (mm) | distance to the "
              "true-field motion (mm) |")
        print("|---|---|---|")
        for name, e, d in ident:
            print(f"| {name} | {e:.2f} | {d:.2f} |")
    if oracle_e:
        print(f"\nE learned from the true 3-D displacements (no images; all {n} frames, Adam: log E at "
              f"{tcfg.physics_lr:g}, residual laws at {tcfg.net_lr:g}; grid {tuple(tcfg.material_grid)}); initial E "
              f"error {mat['initial_mean_abs_log10_error']:.3f}, 2 x below it: "
              f"{mat['initial_mean_abs_log10_error'] / 2:.3f}; the grid's own floor (log10 E_true fitted by least "
              f"squares on it) {floor_e:.3f}; row k: the parameters after k - 1 steps")
        print("| truth / law learned | k | L1 (mm) | E error | soft / stiff geomean (Pa) |")
        print("|---|---|---|---|---|")
        for label, rows in oracle_e.items():
            best = min(rows, key=lambda r: r[2])
            for r in sorted({rows[i] for i in (0, 9, 19, 39, len(rows) - 1) if i < len(rows)} | {best}):
                print(f"| {label} | {r[0]}{' (lowest E error)' if r is best else ''} | {r[1]:.3f} | {r[2]:.3f} | "
                      f"{r[3]:.0f} / {r[4]:.0f} |")
    if oracle:
        print("\n| object motion rendered (observed frames) | recon PSNR | recon_large PSNR | recon_large IoU |")
        print("|---|---|---|---|")
        for name, m in oracle:
            print(f"| {name} | {m['recon']['psnr']:.2f} | {m['recon_large']['psnr']:.2f} | "
                  f"{m['recon_large']['iou']:.4f} |")
    if abl:
        full = {"physics": rep["methods"]["physics"], "material": mat,
                "errors_3d_mm": {s: v["physics"] for s, v in e3.items()}}
        print(f"\nablations (physics; full model: residual laws + latents, lambda_flow {tcfg.lambda_flow:g}, "
              f"surface layer {tcfg.surface_layer or 'default (half the particle spacing)'}; seed {tcfg.seed})")
        print("| variant | recon_large PSNR | recon_large IoU | pred_large PSNR | pred_large IoU | novel_large PSNR | "
              "novel_large IoU | 3-D error recon / pred / novel (mm) | E mean abs log10 err |")
        print("|---|---|---|---|---|---|---|---|---|")
        for name, v in {"full": full, **abl}.items():
            p, e = v["physics"], v["errors_3d_mm"]
            print(f"| {name} | " + " | ".join(f"{p[s]['psnr']:.2f} | {p[s]['iou']:.4f}" for s in sub) +
                  f" | {' / '.join(f'{e[s]:.2f}' for s in sub)} | {v['material']['mean_abs_log10_error']:.3f} |")
    log(f"done in {time.perf_counter() - t_all:.0f} s")


if __name__ == "__main__":
    main()
