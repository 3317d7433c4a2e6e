"""The gated PD force of seed 002 (Eq. 6-7, held over a frame as in Alg. 2) and the neural residual laws of
Eq. 8 (with the Eq. 12 truncation) in forward MLS-MPM cases small enough to write the expected result by hand.

References are closed forms, not physar: one free particle under a constant force (v_T = v_0 + T dt f/m,
x_T = x_0 + T dt v_0 + dt^2 f/m T (T + 1)/2 for the symplectic update of the G2P step), the exact momentum
balance of P2G/G2P for a few particles (sum_p m_p v_p changes by T dt sum_p f_p), and the APIC affine
velocity of one particle after one substep, C' = -(4 dt V / (m dx^2)) tau (quadratic B-splines: sum_i w_i
(x_i - x_p)(x_i - x_p)^T = dx^2/4 I), with tau = J (sigma_expert + sigma_theta) written out below; the
residual laws' frame indifference against a rotation applied by hand.
"""

import numpy as np
import pytest
import torch

from physar.mpm.model import Control, MPMModel, MPMSolver
from physar.mpm.neural import NeuralResidual
from physar.mpm.torch_bridge import Params, simulate, substep

KP, KD = 200.0, 20.0  # seed 002 App. A.3 gains (mass-scaled in physar: 1/s^2, 1/s)


def _model(n: int, T: int = 10, mass=0.3, E=1.0e3, dt=1.0e-3, res=8) -> MPMModel:
    z = np.zeros(n)
    return MPMModel(size=1.0, resolution=res, dt=dt, substeps=T, mass=np.full(n, mass), volume=np.full(n, 1e-3),
                    E=np.full(n, E), nu=np.full(n, 0.3), elastic=z, plastic=z, plastic_params=np.zeros((n, 4)),
                    body=z, gravity=(0.0, 0.0, 0.0))


def _free_particle_case():
    x0 = np.array([[0.52, 0.47, 0.51]])
    v0 = np.array([[0.05, -0.02, 0.01]])
    x_ref = np.array([[0.50, 0.49, 0.53]])
    v_ref = np.array([[0.10, 0.00, -0.03]])
    omega = 0.6
    return x0, v0, x_ref, v_ref, omega


def _expected_free_particle(T: int, dt: float):
    """Seed Eq. 6-7 evaluated by hand at the frame start, held over T substeps (Alg. 2 lines 2-8)."""
    x0, v0, x_ref, v_ref, omega = _free_particle_case()
    a = omega * (KP * (x_ref - x0) + KD * (v_ref - v0))  # f / m (the force is m omega f_PD in physar)
    v = v0 + T * dt * a
    x = x0 + T * dt * v0 + dt * dt * a * T * (T + 1) / 2
    return x, v


def test_held_pd_force_moves_a_free_particle_as_the_closed_form():
    """Mutants caught: the force recomputed at every substep instead of held (Alg. 2), f_PD with the wrong sign
    (held or per-substep kernel), the k_d term dropped, omega dropped, the mass scaling dropped (m = 0.3 kg)."""
    T, dt = 10, 1.0e-3
    model = _model(1, T=T, dt=dt)
    x0, v0, x_ref, v_ref, omega = _free_particle_case()
    x_exp, v_exp = _expected_free_particle(T, dt)
    # NumPy solver
    st, scratch = model.state(x0, v0), model.state(x0, v0)
    st, _ = MPMSolver(model).simulate_frame(st, scratch, Control(np.array([omega]), x_ref, v_ref, KP, KD))
    d = st.numpy()
    np.testing.assert_allclose(d["v"], v_exp, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(d["x"], x_exp, rtol=1e-12, atol=1e-14)
    # differentiable path, fused and generic
    t = lambda a: torch.tensor(a, dtype=torch.float64)
    p = Params(E=t(model.E), nu=t(model.nu), omega=t([omega]), x_ref=t(x_ref), v_ref=t(v_ref), kp=KP, kd=KD)
    for fused in (True, False):
        _, (x, v, *_rest) = simulate(model, t(x0), t(v0), p, 1, fused=fused)
        np.testing.assert_allclose(v.numpy(), v_exp, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(x.numpy(), x_exp, rtol=1e-12, atol=1e-14)
    # the per-substep variant (hold=False, the synthetic truth's stiff tracking): Eq. 6-7 at every substep,
    # v_{k+1} = v_k + dt omega (k_p (x_ref - x_k) + k_d (v_ref - v_k)), x_{k+1} = x_k + dt v_{k+1}
    xk, vk = x0.copy(), v0.copy()
    for _ in range(T):
        vk = vk + dt * omega * (KP * (x_ref - xk) + KD * (v_ref - vk))
        xk = xk + dt * vk
    assert np.abs(vk - v_exp).max() > 1e-4  # the two laws differ measurably here
    p.hold = False
    st, scratch = model.state(x0, v0), model.state(x0, v0)
    st, _ = MPMSolver(model).simulate_frame(st, scratch, Control(np.array([omega]), x_ref, v_ref, KP, KD, hold=False))
    for fused in (True, False):
        _, (x, v, *_rest) = simulate(model, t(x0), t(v0), p, 1, fused=fused)
        for xx, vv in ((x.numpy(), v.numpy()), (st.x.numpy(), st.v.numpy())):
            np.testing.assert_allclose(vv, vk, rtol=1e-10, atol=1e-14)
            np.testing.assert_allclose(xx, xk, rtol=1e-12, atol=1e-14)


def test_held_pd_force_momentum_balance_of_a_few_particles():
    """Eight elastic particles (pre-stretched, E = 1 kPa), omega = 0 on two of them (the surface layer of seed
    §4.2 receives no force): the total momentum changes by exactly T dt sum_p m_p omega_p f_PD,p(s_n) and the
    ungated particles' reference has no effect.  Mutants caught: wrong sign, k_d dropped, force recomputed per
    substep, omega ignored (gated particles' references would add momentum)."""
    T, dt = 8, 1.0e-3
    model = _model(8, T=T, dt=dt, mass=0.05)
    g = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=np.float64)
    x0 = 0.45 + 0.06 * g
    rng = np.random.default_rng(3)
    v0 = 0.05 * rng.standard_normal((8, 3))
    x_ref = x0 + 0.01 * rng.standard_normal((8, 3))
    v_ref = 0.05 * rng.standard_normal((8, 3))
    omega = np.array([1.0, 0.5, 0.0, 1.5, 1.0, 0.0, 0.8, 1.2])
    F0 = np.tile(np.diag([1.05, 0.97, 1.02]), (8, 1, 1))
    m = model.mass
    f = (m * omega)[:, None] * (KP * (x_ref - x0) + KD * (v_ref - v0))  # Eq. 6-7 by hand, at s_n
    p_exp = (m[:, None] * v0).sum(0) + T * dt * f.sum(0)
    t = lambda a: torch.tensor(a, dtype=torch.float64)
    far = x_ref.copy()
    far[omega == 0] += 0.3  # references of gated-off particles must not matter
    for xr in (x_ref, far):
        p = Params(E=t(model.E), nu=t(model.nu), omega=t(omega), x_ref=t(xr), v_ref=t(v_ref), kp=KP, kd=KD)
        _, (_, v, _, F, _) = simulate(model, t(x0), t(v0), p, 1, F0=t(F0))
        mom = (m[:, None] * v.numpy()).sum(0)
        np.testing.assert_allclose(mom, p_exp, rtol=1e-10, atol=1e-12)
    assert np.abs(F.numpy() - F0).max() > 1e-5  # the elastic stress did act (internal forces sum to zero)


def _one_particle(F0):
    model = _model(1, T=1, mass=0.2, E=2.0e3, dt=1.0e-4)
    t = lambda a: torch.tensor(a, dtype=torch.float64)
    x = t([[0.53, 0.46, 0.51]])
    z3 = torch.zeros(1, 3, dtype=torch.float64)
    state = (x, z3.clone(), torch.zeros(1, 3, 3, dtype=torch.float64), t(F0)[None], torch.ones(1, dtype=torch.float64))
    return model, state


def _expert_tau(F0, E, nu):
    """Fixed-corotated Kirchhoff stress for a diagonal F = diag(s) > 0 (R = I): 2 mu (F - I) F + lambda (J-1) J I."""
    mu, la = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    s = np.diag(F0)
    J = np.prod(s)
    return np.diag(2 * mu * (s - 1) * s + la * (J - 1) * J), J


def _bias_net(b_e, b_p, stress_scale=50.0, F_scale=1e-3, objective=True):
    """Residual networks whose output is the constant bias (last layer weights zero): sigma_theta =
    stress_scale F sym(b_e) F^T / J, P_theta = F_scale F_trial sym(b_p) (objective=False: stress_scale sym(b_e),
    F_scale b_p)."""
    nets = NeuralResidual(latent_dim=8, stress_scale=stress_scale, F_scale=F_scale, objective=objective)
    with torch.no_grad():
        nets.elastic.l3.bias.copy_(torch.tensor(np.ravel(b_e), dtype=torch.float64))
        nets.plastic.l3.bias.copy_(torch.tensor(np.ravel(b_p), dtype=torch.float64))
    return nets


B_E = np.array([[0.3, -0.8, 0.1], [0.2, -0.4, 0.5], [0.6, 0.0, 0.9]])  # not symmetric: sym() matters
B_P = np.array([[0.5, 0.1, -0.2], [0.0, -0.7, 0.3], [0.4, 0.2, 0.1]])


def _sym(a):
    return 0.5 * (a + a.T)


@pytest.mark.parametrize("objective", [True, False])
def test_residual_stress_and_plastic_residual_in_one_substep(objective):
    """sigma = E(F, E, nu) + E_theta, F = P(F_trial) + P_theta (seed Eq. 8, identity plasticity P): C after one
    substep equals -(4 dt V/(m dx^2)) J (sigma_expert + sigma_theta) and F = F_trial + P_theta, F_trial =
    (I + dt C) F_0, with J sigma_theta = s F_0 sym(b_e) F_0^T and P_theta = s_F F_trial sym(b_p) (objective) or
    J s sym(b_e) and s_F b_p (the world-frame form kept for old models). Mutants caught: sign of the residual
    stress flipped, residual dropped, the J factor of tau = J sigma dropped, the symmetrisation dropped, the
    push-forward by F dropped, sign of the plastic residual flipped or the plastic residual dropped, F_0 in
    place of F_trial."""
    F0 = np.diag([1.10, 0.95, 1.03]) + np.array([[0, 0.04, 0], [0, 0, -0.03], [0.02, 0, 0]])  # not diagonal
    F0 = np.diag([1.10, 0.95, 1.03]) if not objective else F0
    model, (x, v, C, F, Jp) = _one_particle(F0)
    nets = _bias_net(B_E, B_P, objective=objective)
    p = Params(E=torch.tensor(model.E), nu=torch.tensor(model.nu))
    _, _, C1, F1, _ = substep(model, x, v, C, F, Jp, p, nets=nets)
    c = -4 * model.dt * model.volume[0] / (model.mass[0] * model.dx**2)
    if objective:  # the expert stress from the substep without residuals (its closed form is checked below)
        _, _, C_ex, _, _ = substep(model, x, v, C, F, Jp, p)
        tau_th = 50.0 * F0 @ _sym(B_E) @ F0.T
        C_exp = C_ex.detach().numpy()[0] + c * tau_th
    else:
        tau_ex, J = _expert_tau(F0, model.E[0], model.nu[0])
        tau_th = J * 50.0 * _sym(B_E)
        C_exp = c * (tau_ex + tau_th)
    np.testing.assert_allclose(C1.detach().numpy()[0], C_exp, rtol=1e-9, atol=1e-12)
    Ft = (np.eye(3) + model.dt * C_exp) @ F0
    F_exp = Ft + 1e-3 * (Ft @ _sym(B_P) if objective else B_P)
    np.testing.assert_allclose(F1.detach().numpy()[0], F_exp, rtol=1e-12, atol=1e-14)
    # the residual is not negligible here (a dropped residual would fail the checks above)
    assert np.abs(c * tau_th).max() > 0.05 * np.abs(C_exp).max()


def test_plastic_residual_acts_on_the_trial_state_after_a_return_map():
    """With an expert return map that changes F (Hencky + von Mises, a yield stress far below the stress here),
    Eq. 8 gives F = P(F_trial) + s_F F_trial sym(b_p): the residual is taken of F_trial, not of the projected
    F. P(F_trial) is the same substep's F without residual laws (the elastic residual is zero, so F_trial is
    unchanged). Mutant caught: the residual evaluated on P(F_trial)."""
    from physar.mpm.constitutive import ELASTIC_HENCKY, PLASTIC_VON_MISES

    F0 = np.diag([1.10, 0.95, 1.03]) + np.array([[0, 0.04, 0], [0, 0, -0.03], [0.02, 0, 0]])
    model = _model(1, T=1, mass=0.2, E=2.0e3, dt=1.0e-4)
    model = MPMModel(**{**{k: getattr(model, k) for k in ("size", "resolution", "dt", "substeps", "mass", "volume",
                                                         "E", "nu", "body", "gravity")},
                        "elastic": np.array([ELASTIC_HENCKY]), "plastic": np.array([PLASTIC_VON_MISES]),
                        "plastic_params": np.array([[5.0, 0.0, 0.0, 0.0]])})
    _, (x, v, C, F, Jp) = _one_particle(F0)
    p = Params(E=torch.tensor(model.E), nu=torch.tensor(model.nu))
    _, _, C0, P0, _ = substep(model, x, v, C, F, Jp, p)
    _, _, C1, F1, _ = substep(model, x, v, C, F, Jp, p, nets=_bias_net(np.zeros((3, 3)), B_P, F_scale=0.05))
    np.testing.assert_allclose(C1.detach().numpy(), C0.detach().numpy(), rtol=0, atol=0)
    Ft = (np.eye(3) + model.dt * C0.detach().numpy()[0]) @ F0
    P = P0.detach().numpy()[0]
    assert np.abs(P - Ft).max() > 1e-3  # the return map is active
    np.testing.assert_allclose(F1.detach().numpy()[0], P + 0.05 * Ft @ _sym(B_P), rtol=1e-10, atol=1e-12)


def test_eq12_truncation_zeroes_small_outputs_at_inference():
    """Seed Eq. 12: O = 0 where ||O||_Fro < eps (1e-3), only when truncating (inference).  Mutants caught:
    truncation never applied, applied to every output, or applied during training."""
    F0 = np.diag([1.10, 0.95, 1.03])
    model, (x, v, C, F, Jp) = _one_particle(F0)
    p = Params(E=torch.tensor(model.E), nu=torch.tensor(model.nu))
    tau_ex, _ = _expert_tau(F0, model.E[0], model.nu[0])
    c = -4 * model.dt * model.volume[0] / (model.mass[0] * model.dx**2)
    for norm, kept in ((0.9e-3, False), (1.1e-3, True)):
        b_e, b_p = B_E / np.linalg.norm(B_E) * norm, B_P / np.linalg.norm(B_P) * norm
        nets = _bias_net(b_e, b_p, stress_scale=5.0e4, F_scale=10.0)
        tau_th = 5.0e4 * F0 @ _sym(b_e) @ F0.T
        for truncate in (False, True):
            _, _, C1, F1, _ = substep(model, x, v, C, F, Jp, p, nets=nets, truncate=truncate)
            on = kept or not truncate
            C_exp = c * (tau_ex + (tau_th if on else 0.0))
            Ft = (np.eye(3) + model.dt * C_exp) @ F0
            F_exp = Ft + (10.0 * Ft @ _sym(b_p) if on else 0.0)
            np.testing.assert_allclose(C1.detach().numpy()[0], C_exp, rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(F1.detach().numpy()[0], F_exp, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("with_plastic", [False, True])
def test_regulariser_is_eq11_by_hand(with_plastic):
    """R = lam_law (||E_theta||_2 + ||P_theta||_2) + lam_omega ||omega||_2 + lam_feat (||l_e||_2 + ||l_p||_2)
    (seed Eq. 11 and App. A) for constant network outputs.  Mutants caught: a term dropped or a weight swapped."""
    from physar.mpm.neural import regulariser

    n = 5
    nets = _bias_net(B_E, B_P, stress_scale=2.0, F_scale=3.0)
    if not with_plastic:
        nets.plastic = None
    F = torch.tensor(np.tile(np.diag([1.1, 0.9, 1.0]), (n, 1, 1)))
    g = torch.Generator().manual_seed(0)
    l_e = 0.1 * torch.randn(n, 8, dtype=torch.float64, generator=g)
    l_p = 0.2 * torch.randn(n, 8, dtype=torch.float64, generator=g)
    omega = torch.tensor([0.0, 0.5, 1.0, 1.5, 0.2], dtype=torch.float64)
    # the latents enter the hidden layer, not the output (last layer weights are zero): outputs stay the biases
    r = regulariser(nets, omega, F=F, l_e=l_e, F_trial=F, l_p=l_p, lam_law=10.0, lam_omega=0.1, lam_feat=1.0)
    F1 = np.diag([1.1, 0.9, 1.0])
    sig = 2.0 * F1 @ _sym(B_E) @ F1 / np.linalg.det(F1)  # the Cauchy residual, objective form
    exp = 10.0 * np.sqrt(n) * np.linalg.norm(sig) + 0.1 * np.linalg.norm(omega.numpy())
    exp += np.linalg.norm(l_e.numpy())
    if with_plastic:
        exp += 10.0 * np.sqrt(n) * np.linalg.norm(3.0 * F1 @ _sym(B_P)) + np.linalg.norm(l_p.numpy())
    assert float(r.detach()) == pytest.approx(exp, rel=1e-12)


def _random_net(rest_free: bool, seed: int = 3):
    """Residual networks with every layer random (the last one too), so the output depends on F and the latent."""
    torch.manual_seed(seed)
    nets = NeuralResidual(latent_dim=8, stress_scale=50.0, F_scale=1e-3, rest_free=rest_free)
    with torch.no_grad():
        for mlp in (nets.elastic, nets.plastic):
            mlp.l3.weight.normal_(0.0, 0.5)
            mlp.l3.bias.normal_(0.0, 0.5)
    return nets


def test_rest_free_residual_leaves_undeformed_material_alone():
    """``rest_free`` (undeformed-state equilibrium, issue 17): O(F, l) - O(I, l), so a particle with F = I at rest
    stays at C = 0 and F = I after a substep (the expert stress is 0 there), while the same networks without the
    option stress it; away from I the stress and the F residual are the plain networks' minus their values at
    I.  Mutants caught: the option ignored (C != 0 at rest), the value at I taken with another latent or not
    subtracted from the plastic residual (F drifts from I)."""
    g = torch.Generator().manual_seed(1)
    l_e = 0.3 * torch.randn(1, 8, dtype=torch.float64, generator=g)
    l_p = 0.3 * torch.randn(1, 8, dtype=torch.float64, generator=g)
    model, (x, v, C, F, Jp) = _one_particle(np.eye(3))
    p = Params(E=torch.tensor(model.E), nu=torch.tensor(model.nu), l_e=l_e, l_p=l_p)
    _, _, C1, F1, _ = substep(model, x, v, C, F, Jp, p, nets=_random_net(True))
    assert np.abs(C1.detach().numpy()).max() < 1e-12
    np.testing.assert_allclose(F1.detach().numpy()[0], np.eye(3), atol=1e-14)
    _, _, C1, F1, _ = substep(model, x, v, C, F, Jp, p, nets=_random_net(False))
    assert np.abs(C1.detach().numpy()).max() > 1e-6 and np.abs(F1.detach().numpy()[0] - np.eye(3)).max() > 1e-6
    rf, plain = _random_net(True), _random_net(False)
    Fd = torch.tensor(np.diag([1.10, 0.95, 1.03]))[None]
    sv = torch.tensor([[1.10, 0.95, 1.03]], dtype=torch.float64)
    I, one = torch.eye(3, dtype=torch.float64)[None], torch.ones(1, 3, dtype=torch.float64)
    with torch.no_grad():
        J = torch.linalg.det(Fd)[:, None, None]  # the value at I is pushed forward by F like the rest
        np.testing.assert_allclose(rf.stress(Fd, sv, l_e),
                                   plain.stress(Fd, sv, l_e) - Fd @ plain.stress(I, one, l_e) @ Fd.mT / J,
                                   rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(rf.deformation(Fd, sv, l_p),
                                   plain.deformation(Fd, sv, l_p) - Fd @ plain.deformation(I, one, l_p), rtol=1e-12,
                                   atol=1e-15)
        assert torch.linalg.matrix_norm(plain.stress(I, one, l_e)).item() > 1.0  # the subtracted part matters


def _rotation(axis, angle):
    k = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def test_residual_laws_are_frame_indifferent():
    """Turning a deformed particle rigidly (F -> Q F, Q a rotation written out by Rodrigues' formula) turns the
    residual laws' outputs with it: sigma_theta(QF) = Q sigma_theta(F) Q^T and P_theta(QF) = Q P_theta(F), for
    random networks and latents (NCLaw's physics-aware modules, which seed §4.3 builds on). Mutants caught: the
    world-frame form physar had before 2026-11-29 (kept as objective=False: fails here, checked), the
    push-forward by F^T dropped on either side."""
    g = torch.Generator().manual_seed(5)
    l_e = 0.3 * torch.randn(4, 8, dtype=torch.float64, generator=g)
    l_p = 0.3 * torch.randn(4, 8, dtype=torch.float64, generator=g)
    rng = np.random.default_rng(0)
    F = torch.tensor(np.eye(3) + 0.15 * rng.standard_normal((4, 3, 3)))
    Q = torch.tensor(_rotation([0.3, -0.5, 0.8], 0.9))
    sv = torch.linalg.svdvals
    with torch.no_grad():
        for objective, holds in ((True, True), (False, False)):
            nets = _random_net(False)
            nets.objective = objective
            s, s_rot = nets.stress(F, sv(F), l_e), nets.stress(Q @ F, sv(Q @ F), l_e)
            d, d_rot = nets.deformation(F, sv(F), l_p), nets.deformation(Q @ F, sv(Q @ F), l_p)
            ok_s = torch.allclose(s_rot, Q @ s @ Q.T, rtol=1e-9, atol=1e-9 * float(s.abs().max()))
            ok_d = torch.allclose(d_rot, Q @ d, rtol=1e-9, atol=1e-9 * float(d.abs().max()))
            assert (ok_s, ok_d) == (holds, holds), (objective, ok_s, ok_d)
            assert float(s.abs().max()) > 1.0 and float(d.abs().max()) > 1e-4  # not trivially zero


def test_residual_on_a_subset_leaves_the_others_to_the_expert_law():
    """``Params.residual_on``: the residual laws act on the listed particles only. Three particles in cells far
    apart (no shared grid node) with distinct latents and deformed F, Hencky + von Mises with an active return
    map, residuals on particles [2, 0]: particles 2 and 0 end the substep as with the residuals on every particle
    (each with its own latent row), particle 1 as with the expert law alone (no networks); NumPy indices through
    simulate() give the same. Mutants caught: the subset ignored (particle 1 changes), the latent rows taken in
    order 0, 1 instead of by index (particles 2 and 0 change), the residual added to the wrong rows, the plastic
    residual of the subset taken of the projected F instead of F_trial."""
    from physar.mpm.constitutive import ELASTIC_HENCKY, PLASTIC_VON_MISES

    model = _model(3, T=1, mass=0.2, E=2.0e3, dt=1.0e-4, res=16)
    model = MPMModel(**{**{k: getattr(model, k) for k in ("size", "resolution", "dt", "substeps", "mass", "volume",
                                                         "E", "nu", "body", "gravity")},
                        "elastic": np.full(3, ELASTIC_HENCKY), "plastic": np.full(3, PLASTIC_VON_MISES),
                        "plastic_params": np.tile([5.0, 0.0, 0.0, 0.0], (3, 1))})
    t = lambda a: torch.tensor(a, dtype=torch.float64)
    x = t([[0.21, 0.23, 0.22], [0.52, 0.46, 0.51], [0.78, 0.76, 0.77]])  # B-spline stencils 2 nodes apart
    rng = np.random.default_rng(1)
    F = t(np.eye(3) + 0.1 * rng.standard_normal((3, 3, 3)))
    z = lambda *sh: torch.zeros(*sh, dtype=torch.float64)
    g = torch.Generator().manual_seed(2)
    l_e = torch.randn(3, 8, dtype=torch.float64, generator=g)
    l_p = torch.randn(3, 8, dtype=torch.float64, generator=g)
    nets = _random_net(False)
    run = lambda on, nets: substep(model, x, z(3, 3), z(3, 3, 3), F, torch.ones(3, dtype=torch.float64),
                                   Params(E=t(model.E), nu=t(model.nu), l_e=l_e, l_p=l_p, residual_on=on),
                                   nets=nets)
    with torch.no_grad():
        _, _, C_sub, F_sub, _ = run(torch.tensor([2, 0]), nets)
        _, _, C_all, F_all, _ = run(None, nets)
        _, _, C_ex, F_ex, _ = run(None, None)
        p = Params(E=t(model.E), nu=t(model.nu), l_e=l_e, l_p=l_p, residual_on=np.array([2, 0]))
        _, (_, _, C_np, F_np, _) = simulate(model, x, z(3, 3), p, 1, nets=nets, F0=F)
    np.testing.assert_allclose(F_np.numpy(), F_sub.numpy(), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(C_np.numpy(), C_sub.numpy(), rtol=1e-12, atol=1e-12)
    for i, (C_ref, F_ref) in enumerate(((C_all, F_all), (C_ex, F_ex), (C_all, F_all))):
        np.testing.assert_allclose(C_sub[i].numpy(), C_ref[i].numpy(), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(F_sub[i].numpy(), F_ref[i].numpy(), rtol=1e-12, atol=1e-14)
    # the residuals matter here, and the latent rows differ in effect
    assert float((C_all - C_ex).abs().max()) > 0.05 * float(C_ex.abs().max())
    assert float((F_all - F_ex).abs().max()) > 1e-5


@pytest.mark.parametrize("on, why", [([0, 0], "index 0 2 times"), ([3], "index 3, outside"),
                                     ([-1], "index -1, outside"), ([[0]], "shape"),
                                     (torch.tensor([0], dtype=torch.uint8), "dtype uint8"),
                                     (torch.tensor([0.0]), "dtype float32")])
def test_residual_on_refuses_bad_indices(on, why):
    """A repeated, out-of-range, non-1-D or non-integer ``residual_on`` is one ConfigError naming the field and
    what is wrong (uint8 would be read by torch as a mask)."""
    from physar.errors import ConfigError

    model = _model(3, T=1)
    t = lambda a: torch.tensor(a, dtype=torch.float64)
    x = t([[0.21, 0.23, 0.22], [0.52, 0.46, 0.51], [0.78, 0.76, 0.77]])
    p = Params(E=t(model.E), nu=t(model.nu), residual_on=torch.as_tensor(on))
    with pytest.raises(ConfigError, match=f"params.residual_on .*{why}"):
        simulate(model, x, torch.zeros(3, 3, dtype=torch.float64), p, 1, nets=_random_net(False))
