"""Mesh denoising with the anisotropic Laplacian (AL) and multiscale AL (MSAL) of seed 001 §3.2.1.

A torus (an exact surface with positive and negative curvature) is triangulated, noise is added along the
vertex normals, and AL and MSAL move the vertices back; the error to the exact torus (vertex distance
and normal angle) is measured before and after, beside a Taubin smoother. Writes the noisy and denoised
meshes as PLY (read back to check), `denoise.png` and `denoise.json`.
"""

# %%
import json
import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from physar.geometry import (
    TriMesh,
    add_noise,
    anisotropic_laplacian,
    mean_edge_length,
    msal,
    read_mesh,
    taubin_smooth,
    vertex_normals,
    write_mesh,
)

QUICK = os.environ.get("PHYSAR_EXAMPLE_QUICK") == "1"
OUT = Path(os.environ.get("PHYSAR_EXAMPLE_OUT", "example_out"))
OUT.mkdir(parents=True, exist_ok=True)

# %% [markdown]
# ## A torus and its exact distance
# Radii R = 1 m (centre of the tube) and r = 0.4 m, on an nu × nv grid of the angles (u, v), two
# triangles per cell. The distance of a point p to the exact torus is |p - c(p)| - r with c(p) the
# nearest point of the centre circle, and the exact outward normal is (p - c(p)) / |p - c(p)|.

# %%
R, r = 1.0, 0.4
NU, NV = (96, 40) if QUICK else (240, 96)
u, v = np.meshgrid(np.arange(NU) * 2 * np.pi / NU, np.arange(NV) * 2 * np.pi / NV, indexing="ij")
points = np.stack([(R + r * np.cos(v)) * np.cos(u), (R + r * np.cos(v)) * np.sin(u), r * np.sin(v)], -1)
i, j = np.meshgrid(np.arange(NU), np.arange(NV), indexing="ij")
a, b = i * NV + j, (i + 1) % NU * NV + j
c, d = (i + 1) % NU * NV + (j + 1) % NV, i * NV + (j + 1) % NV
clean = TriMesh(points.reshape(-1, 3), np.r_[np.c_[a.ravel(), b.ravel(), c.ravel()], np.c_[a.ravel(), c.ravel(), d.ravel()]])


def torus_offset(p):
    """(signed distance to the exact torus [m], exact unit normal at the nearest surface point)."""
    centre = np.c_[p[:, :2] * (R / np.hypot(p[:, 0], p[:, 1]))[:, None], np.zeros(len(p))]
    dist = np.linalg.norm(p - centre, axis=1)
    return dist - r, (p - centre) / dist[:, None]


def errors(mesh):
    sd, n_exact = torus_offset(mesh.points)
    cosine = np.clip(np.einsum("ij,ij->i", vertex_normals(mesh), n_exact), -1, 1)
    return {"mean_distance": float(np.abs(sd).mean()), "rms_distance": float(np.sqrt((sd**2).mean())),
            "mean_signed_distance": float(sd.mean()), "normal_error_deg": float(np.degrees(np.arccos(cosine)).mean())}


# %% [markdown]
# ## Noise, then AL and MSAL
# `add_noise` moves each vertex along its normal by N(0, s²), s = 0.2 × mean edge length (what
# `physar noise --sigma 0.2` does). AL iterates q_i ← q_i + τ Δq_i with Δq_i the edge-stopped average
# of the one-ring heights (q_j - q_i)·n_i along n_i; MSAL uses τ = ξ^k and the fidelity λ_i ∝ σ_i pulling
# back towards the data (both with physar's defaults: shrinkage and volume corrections on). The seed's own
# MSAL parameters (ξ = 0.5, λ_i = σ_i/σ̄, 4 steps, no corrections) keep more of the data, aiming at texture.

# %%
noisy = add_noise(clean, sigma=0.2, seed=0, direction="normal")
MEAN_EDGE = mean_edge_length(clean)
results = {"noisy": noisy, "AL": anisotropic_laplacian(noisy), "MSAL": msal(noisy),
           "MSAL (seed form)": msal(noisy, 4, xi=0.5, fidelity=1.0, shrink_correction=0.0, preserve_volume=False),
           "Taubin (physar)": taubin_smooth(noisy)}
try:  # a peer smoother, if the optional trimesh is installed (its iterations alternate λ and μ)
    import trimesh

    peer = trimesh.Trimesh(noisy.points.copy(), noisy.faces.copy(), process=False)
    trimesh.smoothing.filter_taubin(peer, iterations=10)
    results["Taubin (trimesh)"] = noisy.with_points(np.asarray(peer.vertices))
except ImportError:
    pass
ERRORS = {name: errors(m) for name, m in results.items()}
REDUCTION = {name: ERRORS["noisy"]["mean_distance"] / e["mean_distance"] for name, e in ERRORS.items()}
# the denoisers applied to the exact (noise-free) mesh: how far they move it off the surface themselves
BIAS_ON_CLEAN = {"AL": errors(anisotropic_laplacian(clean))["mean_distance"], "MSAL": errors(msal(clean))["mean_distance"]}

# %% [markdown]
# ## Files: PLY meshes (read back), a figure, a JSON summary

# %%
FILES = {"noisy": OUT / "torus_noisy.ply", "AL": OUT / "torus_al.ply", "MSAL": OUT / "torus_msal.ply"}
for name, path in FILES.items():
    write_mesh(path, results[name])
    back = read_mesh(path, kind="tri")
    assert back.n_faces == clean.n_faces and np.allclose(back.points, results[name].points, atol=1e-6)

fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4))
for name in ("noisy", "AL", "MSAL", "Taubin (physar)"):
    sd = torus_offset(results[name].points)[0] / MEAN_EDGE
    ax0.hist(sd, bins=80, range=(-0.8, 0.8), histtype="step", label=name)
    ax1.plot(np.degrees(v[0]), sd[:NV], lw=1, label=name)  # the tube ring u = 0
ax0.set(xlabel="signed distance to the exact torus / mean edge", ylabel="vertices")
ax1.set(xlabel="tube angle v [deg] on the ring u = 0", ylabel="signed distance / mean edge")
ax0.legend(fontsize=8)
fig.tight_layout()
PLOT = OUT / "denoise.png"
fig.savefig(PLOT, dpi=110)
plt.close(fig)
JSON = OUT / "denoise.json"
JSON.write_text(json.dumps({"vertices": clean.n_points, "mean_edge": MEAN_EDGE, "errors": ERRORS,
                            "reduction": REDUCTION, "bias_on_clean": BIAS_ON_CLEAN}, indent=1))

# %% [markdown]
# The residual is mostly noise, not shape: AL and MSAL on the exact mesh move its vertices by only
# ~1 % of the noise level, and the mean signed distance stays near zero (no shrinkage). On this smooth
# surface more iterations of any smoother keep lowering the error; AL/MSAL's edge stopping pays off on
# sharp features (tests/geometry: the cube).

# %%
print(f"{clean.n_points} vertices, noise 0.2 x mean edge ({MEAN_EDGE:.4f} m)")
print(f"{'':<18}{'mean |d| [m]':>13}{'reduction':>10}{'normal err':>11}{'mean d [m]':>12}")
for name, e in ERRORS.items():
    print(f"{name:<18}{e['mean_distance']:>13.2e}{REDUCTION[name]:>9.2f}x{e['normal_error_deg']:>10.2f}°"
          f"{e['mean_signed_distance']:>12.1e}")
print("AL / MSAL applied to the exact mesh move it by " + " / ".join(
    f"{BIAS_ON_CLEAN[k] / ERRORS['noisy']['mean_distance']:.1%}" for k in ("AL", "MSAL")) + " of the noisy error")
print(f"wrote {', '.join(str(p) for p in FILES.values())}, {PLOT}, {JSON}")
