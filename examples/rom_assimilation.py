"""A PGD reduced model of a cantilever, and the load found from noisy displacements by Levenberg-Marquardt.

Seed 000: the separated representation u(x; s, P) = sum_i F_i(x) G_i(s) G_i^P(P) of Eq. (3), built by
the intrusive PGD of §3 (greedy rank-one enrichment, alternating fixed point); the inverse problem of
Eq. (2), mu* = argmin 1/2 ||u* - C u(mu)||^2, solved by Levenberg-Marquardt with the PGD sensitivities
of §4; the set-up of §5.1: a point load moving along the top of a clamped beam, observed at dots on its
side. The observations come from a finer FE mesh than the reduced model's (no inverse crime), with noise.

Run: ``python examples/rom_assimilation.py`` (``PHYSAR_EXAMPLE_QUICK=1``: coarser meshes, fewer
loads; files go to ``PHYSAR_EXAMPLE_OUT``, default ``example_out/``).
"""

# %%
import csv
import os
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from physar.assimilation import assimilate, observation_matrix
from physar.fem import ElasticModel, FESpace, LinearElastic, LinearSolver, fixed_dofs, point_load, probe
from physar.geometry import box_mesh
from physar.rom import build_moving_load_pgd

QUICK = os.environ.get("PHYSAR_EXAMPLE_QUICK") == "1"
OUT = Path(os.environ.get("PHYSAR_EXAMPLE_OUT", "example_out"))
OUT.mkdir(parents=True, exist_ok=True)
plt.switch_backend("Agg")

# %% [markdown]
# ## The full-order model
# The beam of `examples/rom_cantilever.toml`: 1 x 0.1 x 0.1 m, E = 10 MPa, nu = 0.3, clamped at x = 0,
# P2 tetrahedra. The load is a force P (N, downwards) at the point (s, W/2, H) of the top face, spread
# over a disk of radius 8 cm by a smooth bump (a regularised Dirac, `point_load`).

# %%
L, W, H, R = 1.0, 0.1, 0.1, 0.08


def beam(cells):
    space = FESpace(box_mesh((L, W, H), cells), "P2")
    model = ElasticModel(space, LinearElastic(E=1e7, nu=0.3))
    return space, model, LinearSolver(model, fixed_dofs(space, box=[[0, 0, 0], [0, W, H]]))


def load(space, s, P):
    return point_load(space, [s, W / 2, H], [0, 0, -P], R)


ROM_CELLS, REF_CELLS = ((30, 3, 3), (40, 4, 4)) if QUICK else ((40, 4, 4), (60, 6, 6))
space, model, solver = beam(ROM_CELLS)

# %% [markdown]
# ## Intrusive PGD (seed §3)
# `build_moving_load_pgd` (what `physar rom build` runs) samples the load on a grid of s, separates it
# exactly (an SVD of the load matrix), and solves K u = f(x; s) for all s at once as
# u = sum_i F_i(x) G_i(s), adding one mode at a time until its amplitude drops below 1e-5 of the first.
# For a linear material the magnitude is a second, exactly separated parameter: G^P(P) = P.

# %%
rom, info = build_moving_load_pgd(model, solver.fixed, [[0, W / 2, H], [L, W / 2, H]], points=61 if QUICK else 101,
                                  load=(0, 0, -1.0), radius=R, max_modes=25, tol=1e-5, magnitude_range=(0.2, 3.0))
n_modes = rom.n_modes
rom.save(OUT / "cantilever_rom.npz", space=space)  # for `physar rom eval` / `physar assimilate`

# ROM error against full solves on the same mesh at random (s, P): max_k |u_PGD - u_FE| / max_k |u_FE|
rom_errors, fe_norms, t_full = [], [], []
for s, P in np.random.default_rng(0).uniform([0.0, 0.2], [L, 3.0], (3 if QUICK else 8, 2)):
    t0 = time.perf_counter()
    u_fe = solver.solve(load(space, s, P))
    t_full.append(time.perf_counter() - t0)
    rom_errors.append(np.linalg.norm(rom.evaluate([s, P]) - u_fe))
    fe_norms.append(np.linalg.norm(u_fe))
rom_error = max(rom_errors) / max(fe_norms)

# %% [markdown]
# ## Synthetic observations from a finer mesh
# 90 dots on the side face y = 0 (3 rows of 30), their displacements computed by a full FE solve on a
# finer mesh at a known (s_true, P_true), plus Gaussian noise of 0.1 % of the largest displacement.
# `observation_matrix` is C of Eq. (2) for the reduced model's mesh; `set_observation` precomputes C F^T.

# %%
dots = np.array([[x, 0.0, z] for z in (0.2 * H, 0.5 * H, 0.8 * H) for x in np.linspace(0.05, 0.95, 30)])
rom.set_observation(matrix=observation_matrix(space, dots))
ref_space, _, ref_solver = beam(REF_CELLS)
s_true = np.array([0.3, 0.5, 0.7, 0.9]) if QUICK else np.linspace(0.25, 0.9, 8)
P_true = np.resize([1.5, 0.8, 2.0, 1.2], len(s_true))
NOISE, noise_rng = 1e-3, np.random.default_rng(1)

# %% [markdown]
# ## Levenberg-Marquardt on the reduced model (seed §4)
# Start at the centre of the ranges; a coarse multi-start runs only if the fit fails a statistical test
# (chi-square at a false-alarm rate of 1e-3, the noise estimated from the residual). The standard deviations are the Gauss-Newton ones, sigma^2 (J^T J)^-1: they account for the
# noise, not for the small bias of the coarser mesh (0.05-0.15 % of the span on s, 0.3-0.6 % on P here).

# %%
results = []
for s, P in zip(s_true, P_true):
    y = probe(ref_space, ref_solver.solve(load(ref_space, s, P)), dots).ravel()
    y_obs = y + noise_rng.normal(0.0, NOISE * np.abs(y).max(), y.shape)
    res = assimilate(rom, y_obs)
    results.append({"s_true": s, "P_true": P, "s": res.params[0], "P": res.params[1], "s_std": res.std[0],
                    "P_std": res.std[1], "iterations": res.iterations, "time_us": res.time_us})
# the last case as an OBS.csv: `physar assimilate example_out/cantilever_rom.npz example_out/observations.csv`
np.savetxt(OUT / "observations.csv", np.column_stack([dots, y_obs.reshape(-1, 3)]), delimiter=",",
           header="x,y,z,ux,uy,uz", comments="")
with open(OUT / "estimates.csv", "w", newline="") as fh:
    writer = csv.DictWriter(fh, fieldnames=list(results[0]))
    writer.writeheader()
    writer.writerows(results)
t_assim_us = float(np.mean([r["time_us"] for r in results]))

fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(9.5, 4))
x = np.array([r["s_true"] for r in results])
ax1.errorbar(x, [1e3 * (r["s"] - r["s_true"]) for r in results], yerr=[2e3 * r["s_std"] for r in results],
             fmt="o", capsize=3, label="estimate - truth ± 2 std")
ax1.axhspan(-1e3 * 0.01 * L, 1e3 * 0.01 * L, color="g", alpha=0.1, label="1 % of the span")
ax1.set_ylabel("load position error [mm]")
ax2.errorbar(x, [100 * (r["P"] / r["P_true"] - 1) for r in results],
             yerr=[200 * r["P_std"] / r["P_true"] for r in results], fmt="o", capsize=3)
ax2.set_ylabel("load magnitude error [%]")
for ax in (ax1, ax2):
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xlabel("true load position s [m]")
ax1.legend()
fig.suptitle(f"Load from {len(dots)} noisy dots, PGD model with {n_modes} modes")
fig.tight_layout()
fig.savefig(OUT / "estimate_vs_truth.png", dpi=120)
plt.close(fig)

# %%
print(f"PGD: {n_modes} modes on {space.n_dofs} dofs (last/first amplitude "
      f"{info['amplitudes'][-1] / info['amplitudes'][0]:.0e}), error vs full FE {rom_error:.1e}; "
      f"one full solve (factorised K) {1e3 * np.mean(t_full):.1f} ms, one assimilation {t_assim_us:.0f} µs")
print(f"{'s_true':>7} {'s estimate':>17} {'|err|/L':>8} {'P_true':>7} {'P estimate':>15} {'LM it':>6}")
for r in results:
    print(f"{r['s_true']:7.3f} {r['s']:8.4f} ± {r['s_std']:.4f} {abs(r['s'] - r['s_true']) / L:8.2%} "
          f"{r['P_true']:7.2f} {r['P']:7.3f} ± {r['P_std']:.3f} {r['iterations']:6d}")
