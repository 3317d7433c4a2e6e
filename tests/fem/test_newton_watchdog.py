"""Newton's non-monotone full steps (kept while |R| grows at most 1e3-fold: the elastica in 16-34 iterations)
must not wander off on a nearly incompressible material: the seal of examples/ar/seal (neo-Hookean, kappa =
200 C1, P1) with its top cuff turned by 45.5 deg in the project's 13 steps went to |R| ~ 1e16 N and failed at
every load cut; a watchdog returns to the best point once |R| exceeds 1e6 times it and goes on monotone.
Reference: equilibrium itself, |R_free(u)| evaluated here from the internal forces, at the rotation the
prescribed nodes must have. Mutant caught: no watchdog (SolverError), a watchdog that keeps the wandered
state, prescribed values not reached."""
from pathlib import Path

import numpy as np

SEAL = Path(__file__).resolve().parents[2] / "examples" / "ar" / "seal" / "rom.toml"


def test_seal_cuff_rotation_converges_with_defaults():
    from physar.rom.config import build_parametric_problem, build_problem, load_rom_config

    cfg = load_rom_config(SEAL)
    problem = build_problem(cfg)
    pp = build_parametric_problem(cfg, problem, str(SEAL))
    for theta in (45.5, 52.0):
        mu = np.array([theta])
        u = pp(mu)
        model = pp.model_at(mu)
        r = model.internal_force(u) - pp.force(mu, 1.0)
        assert np.linalg.norm(r[pp.free]) <= 1e-8 * np.linalg.norm(model.internal_force(u)), theta
        # the top cuff turned rigidly by theta about the y axis through the origin
        np.testing.assert_allclose(u[pp.fixed], pp.prescribed(mu, 1.0)[pp.fixed], atol=1e-12)
        X = problem.space.nodes
        c, s = np.cos(np.radians(theta)), np.sin(np.radians(theta))
        top = np.flatnonzero(X[:, 2] >= 0.0799)
        x = X[top] + u.reshape(-1, 3)[top]
        expect = np.c_[c * X[top, 0] + s * X[top, 2], X[top, 1], -s * X[top, 0] + c * X[top, 2]]
        np.testing.assert_allclose(x, expect, atol=1e-9)
