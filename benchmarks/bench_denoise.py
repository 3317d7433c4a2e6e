"""Benchmark: mesh denoising under the normal-filtering literature's protocol (issue 20).

Protocol (Zheng et al. 2011, Zhang et al. 2015): Gaussian noise of std σ·ē (ē = mean edge length of the
clean mesh) along a uniformly random direction per vertex (`add_noise(direction="random")`), σ = 0.1, 0.2,
0.3, seed 0; error = mean angle between the face normals of the result and of the clean mesh (same faces),
plus the mean vertex-to-surface distance to the clean mesh (/ē) and the volume change against the clean mesh.

Every peer runs over a small grid of its parameters and is reported at its best (an oracle choice that needs
the clean mesh); physar's default `two-stage` runs once, with the parameters it picks from the noisy mesh alone.
Peers: pymeshlab Taubin, HC Laplacian and two-step smoothing, MeshLib's normal filter (`meshlib`, Mumford-Shah
denoising via normals; skipped if not installed), physar's own bilateral normal filter (BNF, Zheng 2011) and
MSAL (seed 001 §3.2.1, tuned as a peer).

Meshes: a sharp CAD part built here with gmsh OpenCASCADE ("fandisk-like": block with filleted and chamfered
edges, a V-groove, a through hole and a hollow boss; no fandisk file is installed) and the plate with a hole of
physar.geometry.tetra; real scans shipped in installed packages: pymeshlab's Stanford bunny (range-scan
reconstruction, 28k vertices) and its `rangemaps/face000.ply` (one raw range scan of a face, open, 85k).

Run:  .venv/bin/python benchmarks/bench_denoise.py [--quick] [--timing-only] [--quality-only] [--sigmas 0.2 0.3]
      [--default-only] (the default's rows only, no peers)
      .venv/bin/python benchmarks/bench_denoise.py --timing-only --sizes 1e4 1e5 1e6 [--search coarse exhaustive]
      (the default's CPU time per vertex and peak memory on noisy tori, one process per call)
      .venv/bin/python benchmarks/bench_denoise.py --calibrate [--simple-only | --detail-only]
      (constants of normal_filter, on other meshes; --no-ratio skips the σ_e / σ_n table)
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

from physar.geometry import denoise as D
from physar.geometry import quality as Q
from physar.geometry.mesh import TriMesh
from physar.geometry.tetra import _occ_surface, plate_with_hole_surface

QUICK = "--quick" in sys.argv


def load_sample(name: str) -> TriMesh | None:
    import pymeshlab

    p = Path(pymeshlab.__file__).parent / "tests" / "sample_meshes" / name
    if not p.exists():
        return None
    t = trimesh.load(p, process=True, force="mesh")
    t.merge_vertices()
    return TriMesh(np.asarray(t.vertices), np.asarray(t.faces), name=name)


def fandisk_like(size: float = 0.025) -> TriMesh:
    """Sharp CAD part (gmsh OCC): 1 x 0.6 x 0.4 block, two vertical edges filleted (r = 0.12), the top front
    edge chamfered (0.08), a V-groove cut at 26° from the top, a through hole (r = 0.08) and a hollow boss."""

    def build(occ):
        e = 1e-6

        def curves(x0, y0, z0, x1, y1, z1):
            return [t for _, t in occ.getEntitiesInBoundingBox(x0 - e, y0 - e, z0 - e, x1 + e, y1 + e, z1 + e, 1)]

        b = occ.addBox(0, 0, 0, 1.0, 0.6, 0.4)
        occ.synchronize()
        vol = occ.fillet([b], curves(1, 0.6, 0, 1, 0.6, 0.4) + curves(0, 0.6, 0, 0, 0.6, 0.4), [0.12])[0][1]
        occ.synchronize()
        cs = curves(0, 0, 0.4, 1, 0, 0.4)
        top = [t for _, t in occ.getEntitiesInBoundingBox(-e, -e, 0.4 - e, 1 + e, 0.6 + e, 0.4 + e, 2)]
        vol = occ.chamfer([vol], cs, top * len(cs), [0.08] * len(cs))[0][1]
        hole = occ.addCylinder(0.3, 0.3, -0.1, 0, 0, 0.7, 0.08)
        wedge = occ.addBox(0.6, -0.1, 0.28, 0.6, 0.9, 0.4)
        occ.rotate([(3, wedge)], 0.6, 0, 0.28, 0, 1, 0, -0.45)
        out, _ = occ.cut([(3, vol)], [(3, hole), (3, wedge)])
        boss = occ.addCylinder(0.3, 0.3, 0.35, 0, 0, 0.15, 0.16)
        ring = occ.addCylinder(0.3, 0.3, 0.3, 0, 0, 0.3, 0.08)
        out2, _ = occ.cut([(3, boss)], [(3, ring)])
        occ.fuse(out, out2)

    return _occ_surface(build, size, "fandisk-like")


def oriented(mesh: TriMesh) -> TriMesh:
    """Consistently outward-wound copy (trimesh.repair.fix_normals). A no-op on the gmsh CAD parts since
    tetra._occ_surface winds them consistently (same faces, checked); kept for pymeshlab's remeshed output."""
    t = trimesh.Trimesh(mesh.points, mesh.faces, process=False)
    trimesh.repair.fix_normals(t)
    return TriMesh(np.asarray(t.vertices), np.asarray(t.faces), name=mesh.name)


def meshes() -> list[tuple[str, TriMesh | None]]:
    out = [("fandisk-like CAD (gmsh)", oriented(fandisk_like()))]
    if not QUICK:
        out += [("plate with hole CAD (gmsh)", oriented(plate_with_hole_surface(0.2, 0.1, 0.03, 0.025, 0.006)))]
    out += [("bunny scan (pymeshlab)", load_sample("bunny.obj"))]
    if not QUICK:
        out += [("face range scan (pymeshlab face000)", load_sample("rangemaps/face000.ply"))]
    return out


def _pml(filt: str, per_call: bool, **kw):
    def f(mesh: TriMesh, it: int) -> TriMesh:
        import pymeshlab

        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(mesh.points, mesh.faces))
        if per_call:
            getattr(ms, filt)(stepsmoothnum=it, **kw)
        else:
            for _ in range(it):
                getattr(ms, filt)(**kw)
        return mesh.with_points(ms.current_mesh().vertex_matrix())
    return f


def _meshlib(normal_iters: int, beta: float, gamma: float):
    def f(mesh: TriMesh) -> TriMesh:
        import meshlib.mrmeshnumpy as mn
        import meshlib.mrmeshpy as mr

        m = mn.meshFromFacesVerts(mesh.faces.astype(np.int32), mesh.points.astype(np.float32))
        s = mr.DenoiseViaNormalsSettings()
        s.normalIters, s.beta, s.gamma = normal_iters, beta, gamma
        mr.meshDenoiseViaNormals(m, s)
        v = np.asarray(mn.getNumpyVerts(m), float)
        if v.shape != mesh.points.shape:
            raise RuntimeError("MeshLib changed the vertex count")
        return mesh.with_points(v)
    return f


def peers() -> dict[str, list[tuple[str, callable]]]:
    """name -> [(parameter label, mesh -> mesh)]: each peer's grid."""
    grid = {
        "Taubin (pymeshlab)": [(f"{it} it", lambda m, it=it: _pml("apply_coord_taubin_smoothing", True)(m, it))
                               for it in (1, 2, 5, 10, 20, 50, 100, 200)],
        "HC Laplacian (pymeshlab)": [(f"{it} it", lambda m, it=it: _pml("apply_coord_hc_laplacian_smoothing",
                                                                        False)(m, it)) for it in (1, 2, 3, 5, 10, 20)],
        "two-step (pymeshlab)": [(f"{it} it, {th}°", lambda m, it=it, th=th: _pml(
            "apply_coord_two_steps_smoothing", True, normalthr=th)(m, it)) for it in (1, 2, 3, 5, 10) for th in (20, 40, 60)],
        "BNF (physar, Zheng 2011)": [(f"{it} it, σr {sr}", lambda m, it=it, sr=sr: D.bilateral_normal_filter(
            m, it, sigma_r=sr)) for it in (2, 5, 10, 20, 40) for sr in (0.2, 0.35, 0.5)],
        "MSAL (physar, seed 001)": [(f"{it} it, κ {k}", lambda m, it=it, k=k: D.msal(m, it, kappa=k))
                                    for it in (4, 8, 16, 32) for k in (1.0, 1.5, 3.0)],
    }
    try:
        import meshlib.mrmeshpy  # noqa: F401

        grid["MeshLib normal filter"] = [(f"{ni} it, β {b}, γ {g}", _meshlib(ni, b, g))
                                         for ni in (5, 10, 20) for b in (0.001, 0.01) for g in (5.0, 20.0)]
    except ImportError:
        print("meshlib not installed: MeshLib normal filter skipped", file=sys.stderr)
    return grid


def measure(out: TriMesh, clean: TriMesh, closed: bool) -> dict:
    ebar = Q.mean_edge_length(clean)
    return {"ang": Q.normal_angle_error(out, clean),
            "dist": float(Q.point_to_surface_distance(out.points, clean).mean()) / ebar,
            "vol": Q.volume_change(out, clean) if closed else float("nan")}


def is_closed(mesh: TriMesh) -> bool:
    e = np.sort(mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return bool((np.unique(e, axis=0, return_counts=True)[1] == 2).all())


def evaluate(clean: TriMesh, sigma: float, grid: dict) -> list[dict]:
    noisy = Q.add_noise(clean, sigma, 0, "random")
    closed = is_closed(clean)
    rows = [{"method": "noisy input", "params": "", **measure(noisy, clean, closed), "s_per_vertex": 0.0}]
    from physar.geometry.normal_filter import normal_filter_denoise

    t0 = time.process_time()
    info = {}
    out = normal_filter_denoise(noisy, info=info)  # what D.denoise(noisy) runs, with the choice reported
    dt = time.process_time() - t0
    rows.append({"method": "physar two-stage, automatic default",
                 "params": f"from the noisy mesh: σr {info.get('sigma_r')}, {info.get('normal_iterations')} it",
                 **measure(out, clean, closed), "s_per_vertex": dt / clean.n_points})
    for name, variants in grid.items():
        best = None
        for label, fn in variants:
            t0 = time.process_time()
            try:
                out = fn(noisy)
            except Exception as exc:  # noqa: BLE001 - a peer that fails on this mesh is reported, not fatal
                print(f"  {name} {label}: failed ({exc})", file=sys.stderr)
                continue
            dt = time.process_time() - t0
            a = Q.normal_angle_error(out, clean)
            if best is None or a < best[0]:
                best = (a, label, out, dt)
        if best is not None:
            rows.append({"method": name, "params": best[1], **measure(best[2], clean, closed),
                         "s_per_vertex": best[3] / clean.n_points})
    return rows


def quality_tables(sigmas: list[float]) -> None:
    grid = {} if "--default-only" in sys.argv else peers()  # --default-only: the peers' code is not timed/rerun
    print("| mesh | vertices | σ/ē | method | best parameters | normal error (°) | mean dist / ē | volume change % | "
          "CPU µs / vertex |")
    print("|---|---|---|---|---|---|---|---|---|")
    summary = []
    for label, clean in meshes():
        if clean is None:
            print(f"| {label} | not installed | | | | | | | |")
            continue
        for sigma in sigmas:
            rows = evaluate(clean, sigma, grid)
            for r in rows:
                vol = "–" if np.isnan(r["vol"]) else f"{100 * r['vol']:+.2f}"
                print(f"| {label} | {clean.n_points} | {sigma} | {r['method']} | {r['params']} | {r['ang']:.2f} | "
                      f"{r['dist']:.3f} | {vol} | {1e6 * r['s_per_vertex']:.1f} |", flush=True)
            if len(rows) > 2:
                summary.append((label, sigma, rows[1], min(rows[2:], key=lambda r: r["ang"])))
    if not summary:
        return
    print("\n| mesh | σ/ē | physar default: normal error (°) | best peer (its best parameters) | ratio | "
          "default volume change % |")
    print("|---|---|---|---|---|---|")
    for label, sigma, ours, peer in summary:
        vol = "–" if np.isnan(ours["vol"]) else f"{100 * ours['vol']:+.2f}"
        print(f"| {label} | {sigma} | {ours['ang']:.2f} | {peer['ang']:.2f} {peer['method']} ({peer['params']}) | "
              f"{ours['ang'] / peer['ang']:.2f} | {vol} |")


def remeshed(points: np.ndarray, faces: np.ndarray, length: float, name: str) -> TriMesh:
    """Irregular triangulation (pymeshlab isotropic remeshing, features above 30° kept), outward oriented."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.asarray(points, float), np.asarray(faces)))
    ms.meshing_isotropic_explicit_remeshing(iterations=10, targetlen=pymeshlab.PureValue(length), featuredeg=30)
    m = ms.current_mesh()
    return oriented(TriMesh(m.vertex_matrix(), m.face_matrix(), name=name))


def calibration_meshes() -> list[TriMesh]:
    """Meshes for the constants of physar.geometry.normal_filter, none of them a benchmark mesh: a remeshed
    sphere and torus (smooth), a remeshed box and cylinder (sharp 90° edges), and pymeshlab's cow, bone and
    airplane (organic and man-made detail)."""
    s = trimesh.creation.icosphere(5)
    t = torus(120)
    b = trimesh.creation.box(extents=(1, 0.7, 0.5))
    c = trimesh.creation.cylinder(radius=0.4, height=1, sections=96)
    return [remeshed(s.vertices, s.faces, 0.03, "sphere"), remeshed(t.points, t.faces, 0.03, "torus"),
            remeshed(b.vertices, b.faces, 0.03, "box"), remeshed(c.vertices, c.faces, 0.03, "cylinder")] + [
        m for m in (load_sample("cow.obj"), load_sample("bone.ply"), load_sample("airplane.obj")) if m is not None]


def calibrate() -> None:
    """MAD_RATIO = σ_e / σ_n on the calibration meshes (both noise conventions), then SURE_NOISE_FACTOR:
    normal error of `two-stage` (SURE rule) at each factor, and of the previous discrepancy rule, against the
    best over fixed (σ_r, stage-1 iteration count) pairs (oracle)."""
    from physar.geometry import normal_filter as NF

    ms = calibration_meshes()
    if "--detail-only" in sys.argv:
        ms = ms[4:]
    if "--simple-only" in sys.argv:
        ms = ms[:4]
    print("| mesh | noise | σ/ē | σ_e / σ_n (3 seeds) |\n|---|---|---|---|")
    for m in [] if "--no-ratio" in sys.argv else ms:
        for d in ("random", "normal"):
            for sg in (0.1, 0.2, 0.3):
                sn = sg * Q.mean_edge_length(m) / (np.sqrt(3) if d == "random" else 1.0)
                r = np.mean([NF.noise_scale(Q.add_noise(m, sg, seed, d)) / sn for seed in range(3)])
                print(f"| {m.name} | {d} | {sg} | {r:.3f} |")
    factors = (0.85, 0.92, 1.0)
    print("\n| mesh | σ/ē | oracle best (σr, k) | " + " | ".join(f"SURE, noise factor {f}" for f in factors)
          + " | discrepancy 0.95 (previous default) |")
    print("|---|---|---|" + "---|" * (len(factors) + 1))
    ratios = {f: [] for f in (*factors, "disc")}
    for m in ms:
        for sg in (0.2, 0.3):
            noisy = Q.add_noise(m, sg, 0, "random")
            orc = min((Q.normal_angle_error(NF.normal_filter_denoise(noisy, NF.NormalFilterSettings(
                sigma_r=sr, normal_iterations=k)), m), sr, k) for sr in (0.2, 0.35)
                for k in (1, 2, 3, 5, 8, 12, 20, 30, 50, 100))
            errs = []
            for f in factors:
                NF.SURE_NOISE_FACTOR, keep = f, NF.SURE_NOISE_FACTOR
                errs.append(Q.normal_angle_error(NF.normal_filter_denoise(noisy), m))
                NF.SURE_NOISE_FACTOR = keep
                ratios[f].append(errs[-1] / orc[0])
            errs.append(Q.normal_angle_error(NF.normal_filter_denoise(noisy, NF.NormalFilterSettings(
                rule="discrepancy", sigma_r=0.35)), m))
            ratios["disc"].append(errs[-1] / orc[0])
            print(f"| {m.name} | {sg} | {orc[0]:.2f} ({orc[1]}, {orc[2]}) | " + " | ".join(f"{e:.2f}" for e in errs)
                  + " |", flush=True)
    print("\n| rule | geometric mean of error / oracle | worst |\n|---|---|---|")
    for f, r in ratios.items():
        name = "discrepancy 0.95" if f == "disc" else f"SURE, noise factor {f}"
        print(f"| {name} | {np.exp(np.mean(np.log(r))):.3f} | {max(r):.2f} |")


def torus(n: int) -> TriMesh:
    """Closed torus grid with n x n vertices (R = 1, r = 0.4)."""
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, n, endpoint=False), np.linspace(0, 2 * np.pi, n, endpoint=False),
                       indexing="ij")
    pts = np.stack([(1 + 0.4 * np.cos(v)) * np.cos(u), (1 + 0.4 * np.cos(v)) * np.sin(u), 0.4 * np.sin(v)], -1)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * n + j).ravel()
    b = (((i + 1) % n) * n + j).ravel()
    c = (((i + 1) % n) * n + (j + 1) % n).ravel()
    d = (i * n + (j + 1) % n).ravel()
    return TriMesh(pts.reshape(-1, 3), np.r_[np.c_[a, b, c], np.c_[a, c, d]], name=f"torus{n}")


def timing_table() -> None:
    """CPU seconds per vertex for one whole denoising call (defaults) vs vertex count (single-threaded)."""
    sizes = [100, 316] if QUICK else [100, 316, 1000]
    load = os.getloadavg()
    print(f"\nload average before timing (1/5/15 min): {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; {os.cpu_count()} CPUs")
    print("\n| vertices (torus) | two-stage default: CPU s (µs / vertex) | MSAL 8 it: CPU s | Taubin 20 it (pymeshlab): "
          "CPU s | two-stage / Taubin |")
    print("|---|---|---|---|---|")
    for n in sizes:
        m = Q.add_noise(torus(n), 0.2, 0, "random")
        res = {}
        for name, fn in [("two-stage", lambda m=m: D.denoise(m)), ("msal", lambda m=m: D.msal(m)),
                         ("taubin", lambda m=m: _pml("apply_coord_taubin_smoothing", True)(m, 20))]:
            t0 = time.process_time()
            fn()
            res[name] = time.process_time() - t0
        print(f"| {n * n} | {res['two-stage']:.2f} ({1e6 * res['two-stage'] / n**2:.1f}) | {res['msal']:.2f} | "
              f"{res['taubin']:.2f} | {res['two-stage'] / res['taubin']:.1f} |", flush=True)
    load = os.getloadavg()
    print(f"\nload average after timing: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")


def timing_one(n: int, search: str) -> None:
    """One default call on a noisy n x n torus (0.2 ē, random direction, seed 0) in this process; prints one
    JSON line: CPU and wall seconds, the choice, peak resident memory (ru_maxrss) before and after the call."""
    import json
    import resource

    from physar.geometry import normal_filter as NF

    m = Q.add_noise(torus(n), 0.2, 0, "random")
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    load = os.getloadavg()[0]
    info: dict = {}
    t0, w0 = time.process_time(), time.perf_counter()
    NF.normal_filter_denoise(m, NF.NormalFilterSettings(search=search), info=info)
    cpu, wall = time.process_time() - t0, time.perf_counter() - w0
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"vertices": m.n_points, "cpu_s": cpu, "wall_s": wall, "peak_mib": rss1, "before_mib": rss0,
                      "load_before": load, "load_after": os.getloadavg()[0], "sigma_r": info.get("sigma_r"),
                      "k": info.get("normal_iterations"), "evaluations": len(info.get("risk", []))}))


def timing_sizes(sizes: list[float], searches: list[str]) -> None:
    """Time per vertex of the default (`two-stage`, SURE) on noisy tori of about `sizes` vertices, each call in
    a fresh process (so the peak resident memory is that call's); `--search exhaustive` times the previous
    search (every checkpoint) for comparison."""
    import json
    import subprocess

    print(f"\n{os.cpu_count()} CPUs; noisy torus (0.2 ē, random direction, seed 0); CPU time of one "
          "`normal_filter_denoise` call (the default of `physar denoise`); peak RSS of its process\n")
    print("| vertices | search | choice (σr, k) | SURE evaluations | CPU s | CPU µs / vertex | wall s | peak RSS MiB "
          "(before the call) | load before / after |")
    print("|---|---|---|---|---|---|---|---|---|")
    for size in sizes:
        n = round(float(np.sqrt(size)))
        for search in searches:
            out = subprocess.run([sys.executable, __file__, "--timing-one", str(n), search], capture_output=True,
                                 text=True, check=True).stdout.strip().splitlines()[-1]
            r = json.loads(out)
            print(f"| {r['vertices']} | {search} | σr {r['sigma_r']}, {r['k']} it | {r['evaluations']} | "
                  f"{r['cpu_s']:.1f} | {1e6 * r['cpu_s'] / r['vertices']:.0f} | {r['wall_s']:.1f} | "
                  f"{r['peak_mib']:.0f} ({r['before_mib']:.0f}) | {r['load_before']:.2f} / {r['load_after']:.2f} |",
                  flush=True)


if __name__ == "__main__":
    if "--timing-one" in sys.argv:  # child process of timing_sizes
        i = sys.argv.index("--timing-one")
        timing_one(int(sys.argv[i + 1]), sys.argv[i + 2])
        sys.exit(0)
    sig = [0.2] if QUICK else [0.1, 0.2, 0.3]
    if "--sigmas" in sys.argv:
        i = sys.argv.index("--sigmas") + 1
        sig = [float(x) for x in sys.argv[i:] if not x.startswith("--")]
    print(f"# bench_denoise.py {time.strftime('%Y-%m-%d %H:%M')} {'(quick)' if QUICK else ''}")
    if "--calibrate" in sys.argv:
        calibrate()
        sys.exit(0)
    if "--sizes" in sys.argv:  # --timing-only --sizes 1e4 1e5 1e6 [--search coarse exhaustive]
        i = sys.argv.index("--sizes") + 1
        sizes = []
        while i < len(sys.argv) and not sys.argv[i].startswith("--"):
            sizes.append(float(sys.argv[i]))
            i += 1
        searches = ["coarse"]
        if "--search" in sys.argv:
            i = sys.argv.index("--search") + 1
            searches = []
            while i < len(sys.argv) and not sys.argv[i].startswith("--"):
                searches.append(sys.argv[i])
                i += 1
        timing_sizes(sizes, searches)
        sys.exit(0)
    if "--timing-only" not in sys.argv:
        quality_tables(sig)
    if "--quality-only" not in sys.argv:
        timing_table()
