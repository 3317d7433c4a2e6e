"""Reduced-model benchmarks (seed 000 §3-§5): offline build, online assimilation per frame, full model
in the loop, PGD vs POD, non-intrusive PGD with Dask.

Linear P2 cantilever 1 x 0.1 x 0.1 m (40x4x4 cells, 19,683 dofs, E = 1e7 Pa, nu = 0.3), clamped at x = 0, a point
load of 1 N (radius 0.08 m) moving along the top centre line (seed 000 §5.1); 30 observed points on
the side face y = 0, exact observations from full FE solves.

Run: .venv/bin/python benchmarks/bench_rom.py [--sections online,full,pod,patch,dask] [--cells 40,4,4]
"""
import argparse
import datetime
import os
import time

import numpy as np

from physar.assimilation import Assimilator, assimilate, observation_matrix
from physar.fem import ElasticModel, FESpace, LinearElastic, LinearSolver, fixed_dofs, point_load
from physar.geometry import box_mesh
from physar.rom.elastic import build_moving_load_pgd

L, W, H = 1.0, 0.1, 0.1
PATH = [[0, W / 2, H], [L, W / 2, H]]
LOAD, RADIUS = (0, 0, -1.0), 0.08


def setup(cells=(20, 2, 2)):
    space = FESpace(box_mesh((L, W, H), cells), "P2")
    model = ElasticModel(space, LinearElastic(E=1e7, nu=0.3))
    fixed = fixed_dofs(space, box=[[-1e-9, -1, -1], [1e-9, 1, 1]])
    pts = np.stack([np.linspace(0.05, 0.95, 30), np.zeros(30), np.full(30, H / 2)], 1)
    return space, model, fixed, pts


def row(name, value):
    print(f"| {name} | {value} |", flush=True)


def online(space, model, fixed, pts):
    t0 = time.perf_counter()
    rom, _ = build_moving_load_pgd(model, fixed, PATH, points=101, load=LOAD, radius=RADIUS,
                                      max_modes=19, tol=1e-12)
    row(f"PGD build ({rom.n_modes} modes, {space.n_dofs} dofs, 101 load positions)",
        f"{time.perf_counter() - t0:.2f} s")
    rom.set_observation(matrix=observation_matrix(space, pts))
    solver = LinearSolver(model, fixed)
    C = observation_matrix(space, pts)
    # load moving smoothly, 30 frames/s at 0.3 m/s (a video), and random jumps (worst case for warm start)
    s_video = 0.6 + 0.35 * np.sin(np.arange(300) * 0.3 / 30 / 0.35)
    s_random = np.random.default_rng(0).uniform(0.2, 1.0, 200)
    for label, seq in (("video (smooth path, warm start)", s_video), ("random jumps, warm start", s_random)):
        U = solver.solve(np.stack([point_load(space, [s, W / 2, H], LOAD, RADIUS) for s in seq], 1))
        Y = (C @ U).T
        assim = Assimilator(rom, restart_residual=None)
        assim.step(Y[0])
        times, its, errs = [], [], []
        for s, y in zip(seq, Y):
            t = time.perf_counter()
            res = assim.step(y)
            times.append(time.perf_counter() - t)
            its.append(res.iterations)
            errs.append(abs(res.params[0] - s))
        times = np.array(times) * 1e6
        row(f"online assimilation, 19 modes, 30 points, {label}: median / p95 per frame",
            f"{np.median(times):.0f} / {np.percentile(times, 95):.0f} µs "
            f"({np.mean(its):.1f} LM iterations, max error {max(errs) / L * 100:.3f} % of span)")
    return rom, solver, C


def full_in_loop(space, model, fixed, pts, rom, C):
    """The same LM (bounded, Marquardt damping, same start and tolerance) with the full FE model:
    every evaluation of u(s) assembles K, factorises it and solves (what a black-box FOM code does);
    du/ds by direct differentiation K du/ds = df/ds, reusing the factorisation of the accepted point."""
    from physar.fem import factorize

    free = np.setdiff1d(np.arange(space.n_dofs), fixed)
    Cf = C[:, free]

    def load(s):
        return point_load(space, [s, W / 2, H], LOAD, RADIUS)[free]

    class FullModel:
        n_params, names, ranges = 1, ["s"], [(0.0, L)]
        solves = 0
        _cache = (None, None)

        def evaluate(self, mu, observed=True):
            FullModel.solves += 1
            fac = factorize(model.tangent_stiffness()[free][:, free])
            self._cache = (float(mu[0]), fac)
            return Cf @ fac.solve(load(float(mu[0])))

        def sensitivities(self, mu, observed=True):
            s = float(mu[0])
            if self._cache[0] != s:
                self.evaluate(mu)
            h = 1e-6 * L
            return (Cf @ self._cache[1].solve((load(s + h) - load(s - h)) / (2 * h)))[None]

    full = FullModel()
    solver = LinearSolver(model, fixed)
    rng = np.random.default_rng(1)
    t_full, t_red, solves = [], [], []
    for s in rng.uniform(0.3, 0.9, 3):
        y = C @ solver.solve(point_load(space, [s, W / 2, H], LOAD, RADIUS))
        mu0 = np.array([s + 0.03])  # a warm start one video frame away
        FullModel.solves = 0
        t = time.perf_counter()
        rf = assimilate(full, y, mu0=mu0, tol=1e-8)
        t_full.append(time.perf_counter() - t)
        solves.append(FullModel.solves)
        reps = 500
        t = time.perf_counter()
        for _ in range(reps):
            rr = assimilate(rom, y, mu0=mu0, tol=1e-8)
        t_red.append((time.perf_counter() - t) / reps)
        assert abs(rf.params[0] - s) < 1e-3 and abs(rr.params[0] - s) < 2e-3, (s, rf.params, rr.params)
    tf, tr = np.median(t_full), np.median(t_red)
    row(f"same assimilation, full FE model in the loop ({space.n_dofs} dofs, {np.mean(solves):.1f} "
        "assemble+factorise+solve per frame)", f"{tf * 1e3:.0f} ms per frame")
    row("same assimilation, reduced model (same start and tolerance)", f"{tr * 1e6:.0f} µs per frame")
    row("speed-up reduced vs full", f"{tf / tr:,.0f}x")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sections", default="online,full,pod,patch,dask")
    ap.add_argument("--cells", default="40,4,4", help="ROM/FOM mesh cells nx,ny,nz")
    args = ap.parse_args()
    sections = args.sections.split(",")
    print(f"bench_rom.py {datetime.date.today()}, load average {os.getloadavg()[0]:.2f} "
          f"on {os.cpu_count()} CPUs\n")
    print("| quantity | value |\n|---|---|")
    space, model, fixed, pts = setup(tuple(int(c) for c in args.cells.split(",")))
    rom, _, C = online(space, model, fixed, pts)
    if "full" in sections:
        full_in_loop(space, model, fixed, pts, rom, C)
    if "pod" in sections:
        pod_vs_pgd(space, model, fixed, rom)
    if "patch" in sections:
        patch_pgd_vs_pod()
    if "dask" in sections:
        dask_speedup()


def pod_vs_pgd(space, model, fixed, rom):
    """Relative L2 error max_s ||u_rom(s) - u_FE(s)|| / max_s ||u_FE(s)|| at 50 random s, both ROMs
    on the same 101-point grid of load positions; PGD truncated after n enrichments, POD with n modes."""
    from physar.rom.pod import build_moving_load_pod

    t0 = time.perf_counter()
    pod, _ = build_moving_load_pod(model, fixed, PATH, points=101, load=LOAD, radius=RADIUS, max_modes=19,
                                   tol=0.0)
    row(f"POD build (101 snapshots, {pod.n_modes} modes)", f"{time.perf_counter() - t0:.2f} s")
    ss = np.random.default_rng(5).uniform(0, L, 50)
    U = LinearSolver(model, fixed).solve(np.stack([point_load(space, [s, W / 2, H], LOAD, RADIUS) for s in ss], 1))
    ref = np.linalg.norm(U, axis=0).max()
    print("\n| modes | PGD error | POD error |\n|---|---|---|")
    for n in (1, 2, 4, 8, 12, 16, 19):
        errs = []
        for m in (rom, pod):
            if n > m.n_modes:
                errs.append("-")
                continue
            mt = m.truncated(n)
            e = np.linalg.norm(np.stack([mt.evaluate([s]) for s in ss], 1) - U, axis=0).max() / ref
            errs.append(f"{e:.2e}")
        print(f"| {n} | {errs[0]} | {errs[1]} |", flush=True)


def patch_pgd_vs_pod():
    """Two parameters: the load point on a 1 x 0.2 m patch of the top face (s along the beam, lateral
    offset t), plate 1 x 0.3 x 0.1 m, P2 16x5x2; intrusive PGD and POD on the same 41 x 11 grid, error
    max over 30 random (s, t) of ||u_rom - u_FE|| / max ||u_FE||."""
    from physar.rom.pod import pod_from_snapshots

    Wp = 0.3
    space = FESpace(box_mesh((L, Wp, H), (16, 5, 2)), "P2")
    model = ElasticModel(space, LinearElastic(E=1e7, nu=0.3))
    fixed = fixed_dofs(space, box=[[-1e-9, -1, -1], [1e-9, 1, 1]])
    path = [[0, Wp / 2, H], [L, Wp / 2, H]]
    t0 = time.perf_counter()
    rom, _ = build_moving_load_pgd(model, fixed, path, points=41, load=LOAD, radius=RADIUS, max_modes=40,
                                      tol=1e-7, offset_range=(-0.1, 0.1), offset_dir=(0, 1, 0), offset_points=11)
    row(f"two-parameter PGD build (patch load, {rom.n_modes} modes, {space.n_dofs} dofs, 41 x 11 grid)",
        f"{time.perf_counter() - t0:.2f} s")
    s, t = rom.grids
    solver = LinearSolver(model, fixed)
    t0 = time.perf_counter()
    Ug = solver.solve(np.stack([point_load(space, [a, Wp / 2 + b, H], LOAD, RADIUS) for a in s for b in t], 1))
    row("POD snapshots for the same grid (451 solves)", f"{time.perf_counter() - t0:.2f} s")
    mus = np.random.default_rng(7).uniform([0, -0.1], [L, 0.1], (30, 2))
    U = solver.solve(np.stack([point_load(space, [a, Wp / 2 + b, H], LOAD, RADIUS) for a, b in mus], 1))
    ref = np.linalg.norm(U, axis=0).max()
    print("\n| modes (patch, 2 parameters) | PGD error | POD error |\n|---|---|---|")
    for n in (2, 5, 10, 20, 30, 40):
        errs = []
        if n <= rom.n_modes:
            mt = rom.truncated(n)
            errs.append(f"{max(np.linalg.norm(mt.evaluate(m) - U[:, k]) for k, m in enumerate(mus)) / ref:.2e}")
        else:
            errs.append("-")
        pod, _ = pod_from_snapshots(Ug.reshape(-1, s.size, t.size), [s, t], ["s", "t"], max_modes=n, tol=0.0)
        errs.append(f"{max(np.linalg.norm(pod.evaluate(m) - U[:, k]) for k, m in enumerate(mus)) / ref:.2e}")
        print(f"| {n} | {errs[0]} | {errs[1]} |", flush=True)
    print()


def dask_speedup():
    """Non-intrusive PGD snapshots (St.VK beam, P2 16x2x2, Newton with 4 load steps): serial
    in-process vs a LocalCluster of 2 single-threaded workers (BLAS threads = 1)."""
    from physar.fem import StVK
    from physar.rom.nonintrusive import MovingLoadProblem, SnapshotRunner, build_moving_load_nonintrusive

    space = FESpace(box_mesh((L, W, H), (16, 2, 2)), "P2")
    fixed = fixed_dofs(space, box=[[-1e-9, -1, -1], [1e-9, 1, 1]])
    model = ElasticModel(space, StVK(E=1e7, nu=0.3))
    bb = MovingLoadProblem(model, fixed, PATH, (0, 0, -60.0), 0.1)
    pts = [(s,) for s in np.linspace(0, L, 12)]
    load0 = os.getloadavg()[0]
    serial = SnapshotRunner(bb).run(pts[:1])  # warm the caches of the black box
    runners = {"serial": SnapshotRunner(bb)}
    starts = {}
    for n in (1, 2):
        t = time.perf_counter()
        runners[n] = SnapshotRunner(bb, workers=n, min_parallel=1)
        runners[n].run(pts[: 2 * n])  # start the cluster, import physar on the workers, ship the black box
        starts[n] = time.perf_counter() - t
    # the machine is shared: alternate the three modes twice and keep each one's best time
    best = {k: np.inf for k in runners}
    try:
        for _ in range(2):
            for k, runner in runners.items():
                t = time.perf_counter()
                out = runner.run(pts)
                best[k] = min(best[k], time.perf_counter() - t)
                if k == "serial":
                    serial = out
                else:
                    assert max(np.abs(a - b).max() for a, b in zip(serial, out)) < 1e-12
    finally:
        for runner in runners.values():
            runner.close()
    load1 = os.getloadavg()[0]
    row(f"non-intrusive snapshots, St.VK beam {space.n_dofs} dofs, 12 Newton solves, serial in-process "
        "(best of 2)", f"{best['serial']:.2f} s")
    for n in (1, 2):
        row(f"same on a LocalCluster, {n} worker(s) x 1 BLAS thread (best of 2, startup excluded)",
            f"{best[n]:.2f} s (cluster start {starts[n]:.1f} s)")
    row("Dask speed-up, 2 workers vs 1 worker / vs serial",
        f"{best[1] / best[2]:.2f}x / {best['serial'] / best[2]:.2f}x (load average {load0:.1f} -> "
        f"{load1:.1f} on {os.cpu_count()} CPUs)")
    t = time.perf_counter()
    rom, info = build_moving_load_nonintrusive(model, fixed, PATH, load=(0, 0, -60.0), radius=0.1, tol=2e-3)
    row(f"non-intrusive PGD build, St.VK beam, serial ({info['n_solves']} solves, {rom.n_modes} modes)",
        f"{time.perf_counter() - t:.1f} s, error estimate {info['error_estimate']:.1e}")


if __name__ == "__main__":
    main()
