"""POD baseline vs full solves and vs a closed-form two-parameter field."""
import numpy as np

from physar.fem import ElasticModel, FESpace, LinearElastic, LinearSolver, fixed_dofs, point_load
from physar.geometry import box_mesh
from physar.rom.pod import build_moving_load_pod, pod_from_snapshots

L, W, H = 1.0, 0.1, 0.1


def test_pod_cantilever_matches_full_solves():
    space = FESpace(box_mesh((L, W, H), (16, 2, 2)), "P1")
    model = ElasticModel(space, LinearElastic(E=1e7, nu=0.3))
    fixed = fixed_dofs(space, box=[[-1e-9, -1, -1], [1e-9, 1, 1]])
    rom, info = build_moving_load_pod(model, fixed, [[0, W / 2, H], [L, W / 2, H]], points=81,
                                      load=(0, 0, -1.0), radius=0.08, max_modes=20, tol=1e-7)
    assert rom.n_modes <= 20 and np.all(np.diff(info["singular_values"]) <= 0)
    solver = LinearSolver(model, fixed)
    ss = np.random.default_rng(0).uniform(0, L, 30)
    U = solver.solve(np.stack([point_load(space, [s, W / 2, H], (0, 0, -1.0), 0.08) for s in ss], 1))
    err = np.linalg.norm(np.stack([rom.evaluate([s]) for s in ss], 1) - U, axis=0)
    assert err.max() / np.linalg.norm(U, axis=0).max() < 1e-3


def test_pod_two_parameters_separated():
    x = np.linspace(0, 1, 200)
    g1, g2 = np.linspace(0, 1, 41), np.linspace(1, 2, 31)
    field = lambda a, b: np.exp(-((x - a) / 0.3) ** 2) * b + np.sin(3 * x) * a * b**2
    S = np.array([[field(a, b) for b in g2] for a in g1]).transpose(2, 0, 1)
    rom, _ = pod_from_snapshots(S, [g1, g2], ["a", "b"], max_modes=30, tol=1e-10)
    rng = np.random.default_rng(1)
    for a, b in rng.uniform([0, 1], [1, 2], (20, 2)):
        ref = field(a, b)
        assert np.linalg.norm(rom.evaluate([a, b]) - ref) / np.linalg.norm(ref) < 1e-4
        # analytic sensitivity vs central difference of the closed form
        h = 1e-6
        fd = (field(a, b + h) - field(a, b - h)) / (2 * h)
        assert np.linalg.norm(rom.sensitivities([a, b])[1] - fd) / np.linalg.norm(fd) < 1e-3
