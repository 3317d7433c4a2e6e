"""PhysHO in miniature: a human presses a soft pillow; its physics is learned from one short video.

Seed 002, §4 (the pipeline) and §5.1 (synthetic scenes): a synthetic scene is simulated by MLS-MPM on a
FINER particle set (8 particles per cell, heterogeneous and anisotropic material) and rendered by a sphere
renderer (not the Gaussian rasteriser); physar then learns canonical Gaussians (§4.1), per-frame flows
(Eq. 9) and the object's Young's modulus and Poisson ratio through the differentiable MPM (§4.2-4.3, 1
particle per cell), and predicts a NOVEL action (a tilted press) that it never saw. The check: physics
beats the LBS-only baseline (the object does not deform) against the true frames and the true 3-D motion.
The settings are those of ``examples/recon_tiny.toml`` (the CLI example: ``physar recon synth|fit``).

Run: ``python examples/recon_tiny.py`` (``PHYSAR_EXAMPLE_QUICK=1``: the 32 px test scene; otherwise 48 px
and longer training; files go to ``PHYSAR_EXAMPLE_OUT``, default ``example_out/``).
"""

# %%
import json
import os
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from physar.gaussians import load_ply
from physar.recon.io import write_mp4
from physar.recon.synth import generate, load_synth_config
from physar.recon.train import Reconstruction, evaluate, fit, load_dataset, load_train_config

QUICK = os.environ.get("PHYSAR_EXAMPLE_QUICK") == "1"
OUT = Path(os.environ.get("PHYSAR_EXAMPLE_OUT", "example_out"))
OUT.mkdir(parents=True, exist_ok=True)
CONFIG = Path(__file__).resolve().with_name("recon_tiny.toml")
synth_over = {} if QUICK else {"image_size": 48, "frames": 8, "n_obs": 5, "novel_frames": 6, "spin_frames": 6}
train_over = {} if QUICK else {"appearance_iters": 150, "finetune_iters": 40, "flow_iters": 15,
                               "spflow_iters": 15, "physics_iters": 12, "window_start": 5}

# %% [markdown]
# ## 1. Synthesise the scene
# A spin clip (the human turns next to the object at rest: appearance), a dynamic clip (observed part, then
# a part to predict) and a novel action, with images, masks and poses; `truth.npz` is read only by the
# evaluation.

# %%
data = generate(OUT / "recon_scene", load_synth_config(CONFIG, synth_over))
ds = load_dataset(data)
print(f"scene: {ds.rgb.shape[0]} frames ({ds.n_obs} observed), novel action {ds.novel['rgb'].shape[0]} "
      f"frames, {ds.rgb.shape[1]} px")

# %% [markdown]
# ## 2. Fit
# Stage 1: canonical Gaussians from the spin clip, fine-tuned under the zero-stress deformation gradients
# of Alg. 1; stage 2: the 4DGS-like per-frame baseline and the structure-preserving flow of Eq. 9; stage 3:
# E and nu per particle and the actuation gate omega (0 on the object) through the differentiable MPM.

# %%
report = fit(data, OUT / "recon_run", load_train_config(CONFIG, train_over), restart=True)
rec = Reconstruction.load(OUT / "recon_run")

# %% [markdown]
# ## 3. Predict the novel action and evaluate
# `predict` renders a pose sequence with the learned physics or with LBS only; `evaluate` reports PSNR,
# SSIM and mask IoU against the true frames, the 3-D error against the fine MPM truth and the E error.

# %%
nov = ds.novel
rgb_phys, _ = rec.predict(nov["rotations"], nov["root_t"], "physics")
rgb_lbs, _ = rec.predict(nov["rotations"], nov["root_t"], "lbs")
ev = evaluate(rec, ds, methods=("physics", "lbs"))
psnr = {m: {k: ev["methods"][m][k]["psnr"] for k in ("recon", "pred", "novel")} for m in ("physics", "lbs")}
err3d = {m: ev["object_3d_error_mm"][m] for m in ("physics", "lbs")}
mat = ev["material"]
gaussians = load_ply(OUT / "recon_run" / "gaussians.ply")  # the canonical Gaussians, standard 3DGS PLY

# %%
frames = np.concatenate([nov["rgb"], rgb_phys, rgb_lbs], axis=2)  # truth | physics | LBS, side by side
write_mp4(OUT / "recon_novel.mp4", (np.clip(frames, 0, 1) * 255 + 0.5).astype(np.uint8), ds.meta["fps"])
f_last = len(frames) - 1
fig, ax = plt.subplots(1, 3, figsize=(9, 3.2))
for a_, img, title in zip(ax, (nov["rgb"][f_last], rgb_phys[f_last], rgb_lbs[f_last]),
                          ("truth (fine MPM, sphere renderer)", "learned physics", "LBS only"), strict=True):
    a_.imshow(np.clip(img, 0, 1))
    a_.set_title(title, fontsize=9)
    a_.axis("off")
fig.suptitle(f"novel action, last frame ({ds.rgb.shape[1]} px)")
fig.tight_layout()
fig.savefig(OUT / "recon_novel.png", dpi=100)
(OUT / "recon_tiny.json").write_text(json.dumps({"psnr": psnr, "object_3d_error_mm": err3d,
                                                 "material": mat}, indent=1))

# %%
print(f"{'':26s} {'physics':>9s} {'LBS only':>9s}")
for k, label in (("recon", "PSNR observed [dB]"), ("pred", "PSNR predicted [dB]"),
                 ("novel", "PSNR novel action [dB]")):
    print(f"{label:26s} {psnr['physics'][k]:9.2f} {psnr['lbs'][k]:9.2f}")
print(f"{'3-D error vs truth [mm]':26s} {err3d['physics']:9.2f} {err3d['lbs']:9.2f}")
print(f"E learned (soft / stiff part): {mat['E_soft_learned_geomean']:.0f} / {mat['E_stiff_learned_geomean']:.0f} "
      f"Pa, truth {mat['E_soft_true']:.0f} / {mat['E_stiff_true']:.0f} Pa (+ fibres {mat['fiber_E_true_max']:.0f} Pa)")
