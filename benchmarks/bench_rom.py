"""Reduced-model benchmark: offline PGD build time, online assimilation time per frame.

Linear P2 cantilever 1 x 0.1 x 0.1 m (20x2x2 cells), moving point load (seed 000 §5.1).
Run: .venv/bin/python benchmarks/bench_rom.py
"""
import time

import numpy as np

from physar.assimilation import assimilate, observation_matrix
from physar.fem import ElasticModel, FESpace, LinearElastic, LinearSolver, fixed_dofs, point_load, probe
from physar.geometry import box_mesh
from physar.rom.elastic import build_moving_load_pgd

L, W, H = 1.0, 0.1, 0.1
space = FESpace(box_mesh((L, W, H), (20, 2, 2)), "P2")
model = ElasticModel(space, LinearElastic(E=1e7, nu=0.3))
fixed = fixed_dofs(space, box=[[-1e-9, -1, -1], [1e-9, 1, 1]])
t0 = time.perf_counter()
rom, info = build_moving_load_pgd(model, fixed, [[0, W / 2, H], [L, W / 2, H]], points=101,
                                  load=(0, 0, -1.0), radius=0.08, max_modes=19, tol=1e-12)
t_build = time.perf_counter() - t0
pts = np.stack([np.linspace(0.05, 0.95, 30), np.zeros(30), np.full(30, H / 2)], 1)
rom.set_observation(matrix=observation_matrix(space, pts))
solver = LinearSolver(model, fixed)
rng = np.random.default_rng(0)
times, mu = [], None
for s in rng.uniform(0.2, 1.0, 200):
    y = probe(space, solver.solve(point_load(space, [s, W / 2, H], (0, 0, -1.0), 0.08)), pts).ravel()
    t = time.perf_counter()
    res = assimilate(rom, y, mu0=mu)
    times.append(time.perf_counter() - t)
    mu = res.params
print("| quantity | value |\n|---|---|")
print(f"| PGD build (19 modes, {space.n_dofs} dofs, 101 load positions) | {t_build:.2f} s |")
print(f"| online assimilation, 30 points, median per frame | {np.median(times) * 1e6:.0f} µs |")
