"""Why the residual laws of seed 002 Eq. 8 (and their latents) change nothing in the quick C-pillow ablations
(issue 17): diagnostics on a run of ``bench_recon_pillow.py --quick --ablations`` (its OUT/user/data and the
stages 1-2 of OUT/RUN).

``landscape``: is the physics loss (Eq. 10 image + mask terms; the 3-D flow term vs the Eq. 9 target) sensitive
to what the residual could express?  The reconstruction's own simulator (8 particles per cell) is run without
learning with (a) the uniform initial E, (b) the true E field (isotropic fixed-corotated, what the expert law can
express), (c) the true E *plus the truth's fibres and Hencky / von Mises plasticity* (the material a perfect
residual would have to reproduce), and (d) the fitted E fields of the run and its ablations; (e) the true object
motion itself (the cell-averaged fine truth, body as in (b)) is the floor of any material.  Per motion: the image
loss on the observed frames (what training sees), the 3-D error on the observed and the future frames.

``train``: the physics stage replicated with instrumentation (same loss, same optimiser groups; settings from
``--set key=value``), logging per iteration the gradient norms reaching log E, the latents and the residual
networks' parameters from the data term and from the Eq. 11 regulariser separately, the residual stress magnitude
vs the expert stress, the fraction of particles whose network output Eq. 12 would truncate, and the learned E error;
``--object-pixels PX`` restricts the image loss to the object's pixels (the generator's object label, dilated by PX):
does the body's rendering steer the object's E?

    .venv/bin/python benchmarks/diag_residual_pillow.py landscape --out /tmp/h43/rp --run s0
    .venv/bin/python benchmarks/diag_residual_pillow.py train --out /tmp/h43/rp --run s0 --set net_lr=1e-2
    .venv/bin/python benchmarks/diag_residual_pillow.py train --out OUT --run RUN --object-pixels 2 --tag obj
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import json
import math
import time
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import torch
from scipy.spatial import cKDTree

from physar.mpm.constitutive import ELASTIC_HENCKY, PLASTIC_VON_MISES
from physar.mpm.model import MPMModel
from physar.recon.flow import flow_target_loss
from physar.recon.train import (
    Physics,
    Reconstruction,
    Rig,
    _flow_selection,
    _load_stages,
    cell_average_truth,
    image_loss,
    load_dataset,
    material_error,
    physics_regulariser,
    render_scene,
    simulate_clip,
)

ROOT = Path(__file__).parents[1]


def bench():
    spec = importlib.util.spec_from_file_location("bench_recon_pillow", ROOT / "benchmarks" / "bench_recon_pillow.py")
    m = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(m)
    return m


def full_cfg(a):
    b = bench()
    from physar.recon.train import load_train_config

    cfg = load_train_config(a.config, {**b.QUICK_TRAIN, "seed": a.seed})
    return b.full_model(cfg).model_copy(update=b.parse_overrides(a.set or []))


def true_material_model(rig: Rig, truth: dict, yield_stress: float) -> MPMModel:
    """rig.model with the truth's fibres (nearest fine particle) and Hencky / von Mises plasticity on the object."""
    m, no = rig.model, rig.no
    idx = cKDTree(truth["rest_positions"]).query(rig.Xo)[1]
    n = m.n_particles
    fib, fE = np.zeros((n, 3)), np.zeros(n)
    fib[:no], fE[:no] = truth["fiber"][idx], truth["fiber_E"][idx]
    el, pl, pp = m.elastic.copy(), m.plastic.copy(), m.plastic_params.copy()
    el[:no], pl[:no], pp[:no, 0] = ELASTIC_HENCKY, PLASTIC_VON_MISES, yield_stress
    return MPMModel(size=m.size, resolution=m.resolution, dt=m.dt, substeps=m.substeps, mass=m.mass, volume=m.volume,
                    E=m.E, nu=m.nu, elastic=el, plastic=pl, plastic_params=pp, body=m.body, gravity=m.gravity,
                    walls=m.walls, friction=m.friction, pad=m.pad, colliders=m.colliders, fiber=fib, fiber_E=fE)


def gaussian_blur(img: torch.Tensor, sigma: float) -> torch.Tensor:
    """(H, W) or (H, W, C) image convolved with a normalised Gaussian of ``sigma`` px, kernel radius ceil(3 sigma),
    reflect-padded (OpenCV's GaussianBlur, BORDER_REFLECT_101; scoring only, no gradient)."""
    if sigma <= 0:
        return img
    r = max(1, math.ceil(3 * sigma))
    x = img.detach().cpu().numpy()
    y = cv2.GaussianBlur(x, (2 * r + 1, 2 * r + 1), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT_101)
    return torch.from_numpy(y.reshape(x.shape))


def scoring_loss(res, rgb_gt, mask_gt, cfg, blur: float = 0.0) -> torch.Tensor:
    """The training loss of :func:`image_loss`, or with ``blur`` > 0 the same L1 terms after a Gaussian low-pass of
    ``blur`` px on render and target alike (does the loss rank motions right once the appearance model's
    pixel-scale texture mismatch is filtered out?)."""
    if blur <= 0:
        return image_loss(res, rgb_gt, mask_gt, cfg)
    low = SimpleNamespace(rgb=gaussian_blur(res.rgb, blur), alpha=gaussian_blur(res.alpha, blur))
    return image_loss(low, gaussian_blur(rgb_gt.to(res.rgb.dtype), blur), gaussian_blur(mask_gt.to(res.alpha.dtype), blur),
                      cfg)


def landscape(a) -> None:
    out = Path(a.out)
    cfg = full_cfg(a)
    ds = load_dataset(out / "user" / "data")
    rig = Rig(ds.meta, cfg, poses=(ds.rotations, ds.root_t))
    kin = rig.kinematics(ds.rotations, ds.root_t)
    st = _load_stages(out / a.run, rig, cfg)
    from physar.recon.train import Appearance

    app = Appearance(*[t.detach() for t in st.app.params()])
    n, no = len(ds.rgb), ds.n_obs
    gt = cell_average_truth(rig, ds.truth)
    Et = ds.truth["E"][cKDTree(ds.truth["rest_positions"]).query(rig.Xo)[1]]
    sj = out / "data" / "scene.json"  # the generator's scene (the imported one does not carry the yield stress)
    yield_stress = float(json.loads(sj.read_text())["synth_config"]["yield_stress"])
    rgb, mask = torch.as_tensor(ds.rgb), torch.as_tensor(ds.mask)
    iso = rig.model

    def iso_phys(E=None, nu=None):
        c = cfg.model_copy(update={"residual": False, "material_grid": (0, 0, 0)})
        r2 = Rig(ds.meta, c, poses=(ds.rotations, ds.root_t))
        ph = Physics.init(r2)
        if E is not None:
            ph.log_E = torch.log(torch.as_tensor(E, dtype=torch.float64))
        return r2, ph

    def sim(r2, ph, model=None):
        r2.model = model or r2.model
        with torch.no_grad():
            return {f: (xo, Fo, xh, Fh) for f, xo, Fo, xh, Fh in simulate_clip(r2, ph, kin, n, grad=False)}

    exact = copy.copy(rig)  # renders the object's F as given (rows that name their F)
    exact.cfg = rig.cfg.model_copy(update={"render_deformation": "state"})

    fsel = _flow_selection(rig, app, kin, st.spflow, rig.cfg.flow_target)  # the Eq. 10 term as fit compares it

    def score(name, motion, as_given=False):
        """Rows render under the run's rule (render_deformation) unless as_given (the F in the motion)."""
        r = exact if as_given else rig
        with torch.no_grad():
            il = [float(scoring_loss(render_scene(r, app, *motion[f], kin["xb"][f], kin["A_b"][f]), rgb[f], mask[f],
                                     score_cfg, a.score_blur)) for f in range(1, n)]
            fl = [float(flow_target_loss(motion[f][0], st.spflow[f], *fsel[f])) for f in range(1, no)]
        e3 = [float(np.linalg.norm(np.asarray(motion[f][0]) - gt[f], axis=1).mean() * 1e3) for f in range(1, n)]
        row = {"name": name, "img_obs": float(np.mean(il[:no - 1])), "img_obs_frames": il[:no - 1],
               "img_pred": float(np.mean(il[no - 1:])), "flow_l1_mm": float(np.mean(fl)) * 1e3,
               "e3_obs": float(np.mean(e3[:no - 1])), "e3_pred": float(np.mean(e3[no - 1:])), "e3_frames": e3}
        print(f"| {name} | {row['img_obs']:.5f} | {row['img_pred']:.5f} | {row['flow_l1_mm']:.2f} | "
              f"{row['e3_obs']:.2f} | {row['e3_pred']:.2f} | {' / '.join(f'{e:.2f}' for e in e3)} |", flush=True)
        return row

    print(f"observed frames 1..{no - 1}, future {no}..{n - 1}; image loss = lambda_rgb L1 + lambda_mask L1 (mean per "
          "frame); flow = the Eq. 10 term's distance to the Eq. 9 target (flow_target of the config; mm); 3-D error mm (floor "
          f"{np.linalg.norm(rig.Xo - gt[0], axis=1).mean() * 1e3:.2f})")
    print("| motion | image loss obs | image loss pred | flow L1 obs (mm) | 3-D err obs | 3-D err pred | per frame |")
    print("|---|---|---|---|---|---|---|")
    score_cfg = cfg.model_copy(update=bench().parse_overrides(a.score_set or []))  # e.g. lambda_rgb=0: masks
    rows, fitted = [], None
    if not a.only_truth:
        r2, ph = iso_phys()
        rows.append(score("uniform E_init, isotropic", sim(r2, ph)))
        r2, ph = iso_phys(Et)
        rows.append(score("true E, isotropic (expert law)", sim(r2, ph)))
        r2, ph = iso_phys(Et)
        tl = sim(r2, ph, true_material_model(r2, ds.truth, yield_stress))
        rows.append(score("true E + fibres + Hencky/von Mises (truth's law, 8/cell)", tl))
        if yield_stress > 0:  # the simulator's F is the elastic part F_e; the material's shape follows F_e F_p
            rows.append(score("truth's law, Gaussians deformed by the total F (from neighbours)",
                              {f: (xo, rig.deformation_from_neighbours(xo), xh, Fh) for f, (xo, _, xh, Fh)
                               in tl.items()}, as_given=True))
        r2, ph = iso_phys(Et)
        m2 = true_material_model(r2, ds.truth, 0.0)
        m2.plastic[:] = 0
        m2.elastic[:] = iso.elastic
        m2._wp = None
        rows.append(score("true E + fibres (elastic fixed-corotated)", sim(r2, ph, m2)))
        for suffix in [""] + [f"_{s}" for s in a.variants]:
            rd = out / f"{a.run}{suffix}"
            if (rd / "model.npz").exists():
                rec = Reconstruction.load(rd)
                with torch.no_grad():
                    mo = {f: (xo, Fo, xh, Fh) for f, xo, Fo, xh, Fh in simulate_clip(rec.rig, rec.phys, kin, n,
                                                                                      grad=False)}
                rows.append(score(f"fitted {a.run}{suffix}", mo))
                fitted = fitted if suffix else mo
    g = torch.as_tensor(rig.Xo + (gt - gt[0]))
    base = sim(*iso_phys(Et))
    true_o = {f: (g[f], rig.deformation_from_neighbours(g[f])) for f in range(1, n)}
    rows.append(score("true object motion (body as true-E sim)", {f: (*true_o[f], *base[f][2:]) for f in true_o}))
    rows.append(score("true object motion, Gaussians deformed by F from neighbours (seed Eq. 4)",
                      {f: (*true_o[f], *base[f][2:]) for f in true_o}, as_given=True))
    eye = torch.eye(3, dtype=torch.float64).expand(rig.no, 3, 3)
    rows.append(score("true object motion, Gaussians not deformed (F = I: the truth renders rigid spheres)",
                      {f: (g[f], eye, *base[f][2:]) for f in true_o}, as_given=True))
    if fitted is not None:  # which of object and body makes the fitted motion's loss lower than the truth's
        rows.append(score(f"true object motion, body of fitted {a.run}", {f: (*true_o[f], *fitted[f][2:])
                                                                          for f in true_o}))
        rows.append(score(f"object of fitted {a.run}, body as true-E sim", {f: (*fitted[f][:2], *base[f][2:])
                                                                             for f in true_o}))
        rows.append(score(f"fitted {a.run}, Gaussians deformed by F from neighbours",
                          {f: (fitted[f][0], rig.deformation_from_neighbours(fitted[f][0]), *fitted[f][2:])
                           for f in true_o}, as_given=True))
        rows.append(score(f"fitted {a.run}, Gaussians not deformed (F = I)", {f: (fitted[f][0], eye, *fitted[f][2:])
                                                                               for f in true_o}, as_given=True))
    tag = "" if a.tag == "default" else f"_{a.tag}"
    (out / f"landscape_{a.run}{tag}.json").write_text(json.dumps(rows, indent=1))


def train(a) -> None:
    out = Path(a.out)
    cfg = full_cfg(a)
    ds = load_dataset(out / "user" / "data")
    torch.manual_seed(cfg.seed)
    rig = Rig(ds.meta, cfg, poses=(ds.rotations, ds.root_t))
    kin = rig.kinematics(ds.rotations, ds.root_t)
    st = _load_stages(out / a.run, rig, cfg)
    from physar.recon.train import Appearance

    app = Appearance(*[t.detach() for t in st.app.params()])
    rgb, mask = torch.as_tensor(ds.rgb), torch.as_tensor(ds.mask)
    ph = Physics.init(rig)
    leaves = ph.leaves()
    for t in leaves:
        t.requires_grad_(True)
    k = len(ph.material_leaves())
    if not cfg.learn_omega:  # as fit does
        ph.omega_logit.requires_grad_(False)
    opt = torch.optim.Adam([{"params": [t for t in leaves[:k] if t.requires_grad], "lr": cfg.physics_lr}] +
                           ([{"params": leaves[k:], "lr": cfg.net_lr}] if len(leaves) > k else []))
    lo_E, hi_E = math.log(cfg.E_min), math.log(cfg.E_max)
    named = {"log_E": ph.log_E, "l_e": ph.l_e, "l_p": ph.l_p}
    if ph.nets is not None:
        named.update({f"net.{n}": p for n, p in ph.nets.named_parameters()})
    named = {k_: v for k_, v in named.items() if v is not None}
    frame_loss, log = None, []
    obj_w = None
    if a.object_pixels is not None:  # the generator's label PNGs (OUT/data/labels/dynamic; object id 2)
        import cv2

        from physar.recon.masks import read_label_png

        if a.object_pixels < 0:
            raise SystemExit(f"--object-pixels {a.object_pixels}: give a dilation >= 0 pixels")
        ksz = 2 * a.object_pixels + 1
        labs = [read_label_png(out / "data" / "labels" / "dynamic" / f"{f:04d}.png") for f in range(len(ds.rgb))]
        obj_w = torch.as_tensor(np.stack([cv2.dilate((lab == 2).astype(np.uint8), np.ones((ksz, ksz), np.uint8))
                                          for lab in labs]).astype(np.float64))
        if obj_w.shape[1:] != mask.shape[1:]:
            raise SystemExit(f"labels {tuple(obj_w.shape[1:])} vs images {tuple(mask.shape[1:])}: regenerate")
    print("settings: " + ", ".join(f"{k_}={getattr(cfg, k_)}" for k_ in (
        "physics_iters", "physics_lr", "net_lr", "lambda_flow", "lambda_law", "lambda_feat", "residual", "latents",
        "window_start", "window_grow_every", "seed")), flush=True)
    fsel = _flow_selection(rig, app, kin, st.spflow, cfg.flow_target) if cfg.lambda_flow > 0 else {}
    t0 = time.perf_counter()
    for it in range(cfg.physics_iters):
        W = min(ds.n_obs, cfg.window_start + it // cfg.window_grow_every)
        wts = np.ones(W)
        if cfg.loss_balanced and frame_loss is not None and len(frame_loss) >= W - 1:
            fl = np.asarray(frame_loss[:W - 1])
            wts[1:] = fl / max(fl.mean(), 1e-12)
        total, per, img = 0.0, [], 0.0
        for f, xo, Fo, xh, Fh in simulate_clip(rig, ph, kin, W):
            res = render_scene(rig, app, xo, Fo, xh, Fh, kin["xb"][f], kin["A_b"][f])
            if obj_w is None:
                lf = image_loss(res, rgb[f], mask[f], cfg)
            else:  # the same L1 terms, averaged over the object's pixels only
                w = obj_w[f]
                lf = (cfg.lambda_rgb * ((res.rgb - rgb[f]).abs().mean(-1) * w).sum()
                      + cfg.lambda_mask * ((res.alpha - mask[f]).abs() * w).sum()) / w.sum().clamp_min(1.0)
            img += float(lf.detach()) / (W - 1)
            if cfg.lambda_flow > 0 and f < len(st.spflow):
                lf = lf + cfg.lambda_flow * flow_target_loss(xo, st.spflow[f], *fsel[f])
            per.append(float(lf.detach()))
            total = total + wts[f] * lf / (W - 1)
        Fall = torch.cat([Fo, Fh])
        reg = physics_regulariser(ph, rig, Fall)
        # the regulariser's own gradient on the networks / latents (F detached: its path into the simulation is
        # tiny next to the data term's); data gradient = full gradient - this
        gr = torch.autograd.grad(physics_regulariser(ph, rig, Fall.detach()), list(named.values()), allow_unused=True)
        opt.zero_grad()
        (total + reg).backward()
        g_reg = {k_: float(g.norm()) if g is not None else 0.0 for k_, g in zip(named, gr)}
        g_data = {k_: float((v.grad - (g if g is not None else 0)).norm()) if v.grad is not None else 0.0
                  for (k_, v), g in zip(named.items(), gr)}
        opt.step()
        with torch.no_grad():
            ph.log_E.clamp_(lo_E, hi_E)
            if ph.log_E_human is not None:
                ph.log_E_human.clamp_(lo_E, hi_E)
        frame_loss = per + list(frame_loss or [])[len(per):]
        row = {"it": it + 1, "W": W, "data": float(total.detach()), "img": img, "reg": float(reg.detach()),
               "g_data": g_data, "g_reg": g_reg,
               "E_error": material_error(Reconstruction(rig, None, [], ph), ds.truth)["mean_abs_log10_error"]}
        if ph.nets is not None:
            with torch.no_grad():
                from physar.mpm.neural import invariant_features
                from physar.mpm.torch_bridge import _sv_op, _WarpOp

                Fr = Fall.detach()[:rig.no] if cfg.residual_on == "object" else Fall.detach()  # where it acts
                (sv,) = _WarpOp.apply(_sv_op, rig.model, Fall.detach())
                sv = sv[:len(Fr)]
                el = ph.nets.elastic
                h = el.l1(invariant_features(Fr, sv)) + (ph.l_e if ph.l_e is not None else 0)
                raw = el.l3(el.act(el.l2(el.act(h)))).reshape(-1, 3, 3)
                on = torch.linalg.matrix_norm(raw)
                sig = ph.nets.stress(Fr, sv, ph.l_e)
                row.update({"w3_mean_abs": float(ph.nets.elastic.l3.weight.abs().mean()),
                            "sigma_theta_obj_mean_Pa": float(torch.linalg.matrix_norm(sig[:rig.no]).mean()),
                            "frac_truncated": float((on < ph.nets.eps).double().mean()),
                            "out_norm_median": float(on.median())})
        log.append(row)
        gd, grg = row["g_data"], row["g_reg"]
        print(f"it {it + 1:3d} W {W} data {row['data']:.5f} img {img:.5f} reg {row['reg']:.5f} E err "
              f"{row['E_error']:.3f} | |g_data| logE "
              f"{gd['log_E']:.2e} l_e {gd.get('l_e', 0):.2e} net.elastic.l3.w {gd.get('net.elastic.l3.weight', 0):.2e}"
              f" net.plastic.l3.w {gd.get('net.plastic.l3.weight', 0):.2e} | |g_reg| l3.w "
              f"{grg.get('net.elastic.l3.weight', 0):.2e} l_e {grg.get('l_e', 0):.2e}"
              + (f" | w3 {row['w3_mean_abs']:.2e} sigma_theta {row['sigma_theta_obj_mean_Pa']:.1f} Pa trunc "
                 f"{row['frac_truncated']:.2f}" if "w3_mean_abs" in row else "")
              + f" [{time.perf_counter() - t0:.0f} s]", flush=True)
    (out / f"diag_train_{a.run}_{a.tag}.json").write_text(json.dumps(log, indent=1))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("what", choices=("landscape", "train"))
    ap.add_argument("--config", default=str(ROOT / "examples" / "recon_anny_cpillow.toml"), help="the TOML "
                    "whose [train] the data run used")
    ap.add_argument("--out", default="/tmp/h43/rp")
    ap.add_argument("--run", default="s0")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", action="append", help="[train] override key=value (repeatable)")
    ap.add_argument("--score-set", action="append", help="landscape: override of the scoring loss only, e.g. "
                    "lambda_rgb=0 (the mask term alone; repeatable)")
    ap.add_argument("--score-blur", type=float, default=0.0, metavar="SIGMA", help="landscape: score with the L1 "
                    "terms after a Gaussian low-pass of SIGMA px on render and target")
    ap.add_argument("--tag", default="default", help="names this variant's output file (OUT/diag_train_RUN_TAG.json; "
                    "landscape: OUT/landscape_RUN_TAG.json, OUT/landscape_RUN.json for the default)")
    ap.add_argument("--variants", nargs="*", default=["nolatents", "noresidual", "noflow", "nolayer"])
    ap.add_argument("--object-pixels", type=int, default=None, metavar="PX", help="train: the image loss on the "
                    "object's pixels only (the generator's object label, dilated by PX pixels), not the whole image")
    ap.add_argument("--only-truth", action="store_true", help="landscape: only the true-motion row")
    a = ap.parse_args()
    if a.score_blur < 0:
        ap.error(f"--score-blur must be >= 0 px (got {a.score_blur})")
    torch.set_num_threads(1)
    landscape(a) if a.what == "landscape" else train(a)


if __name__ == "__main__":
    main()
