"""Stein's unbiased estimate of the face-tilt risk that chooses the default denoiser's amount of filtering
(physar.geometry.normal_filter.sure_tilt, issue 20).

Reference, independent of physar's smoother: a uniform-umbrella Taubin smoother written here (linear, so the
finite-difference divergence is exact), Gaussian noise N(0, σ² I) added to a sphere, and the true risk
mean |A(f(y) - x)|² computed against the clean sphere, A(d)_{f,ij} = n_f·(d_i - d_j) over the three edges of
every face with the clean face normals, written here too. Averaged over seeds, SURE must equal the true risk
(Stein 1981): E SURE = E risk.
"""

import numpy as np
import trimesh
from scipy import sparse

from physar.geometry.normal_filter import FaceTilt, sure_tilt


def smoother(faces: np.ndarray, n: int, steps: int):
    e = np.unique(np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    a = sparse.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), (n, n)).tocsr()
    w = sparse.diags(1.0 / np.asarray(a.sum(axis=1)).ravel()) @ a

    def f(y):
        q = y.copy()
        for _ in range(steps):
            q = q + 0.5 * (w @ q - q)
            q = q - 0.53 * (w @ q - q)
        return q
    return f


def tilt_ref(faces, normals, d):
    out = []
    for a, b in ((0, 1), (1, 2), (2, 0)):
        out.append(np.einsum("ij,ij->i", normals, d[faces[:, a]] - d[faces[:, b]]))
    return np.stack(out, axis=1).ravel()


def test_sure_is_unbiased_for_the_face_tilt_risk():
    """Mean over 200 noise draws of SURE vs of the true risk, for a light and a strong smoother: equal within
    4 standard errors (and the two smoothers ordered the same way). Mutants caught: the divergence term
    dropped or with the wrong sign, the noise term -σ² instead of -2σ² (each moves the mean by > 10
    standard errors), the tilt operator on vertex indices of one edge only."""
    s = trimesh.creation.icosphere(3)
    x, faces = np.asarray(s.vertices), np.asarray(s.faces)
    c = np.cross(x[faces[:, 1]] - x[faces[:, 0]], x[faces[:, 2]] - x[faces[:, 0]])
    nrm = c / np.linalg.norm(c, axis=1)[:, None]
    tilt = FaceTilt(faces, nrm)
    sigma = 0.02
    rng = np.random.default_rng(3)
    b = rng.normal(size=x.shape)
    np.testing.assert_allclose(np.sort(tilt(b)), np.sort(tilt_ref(faces, nrm, b)), rtol=1e-12, atol=1e-12)
    means = []
    for steps in (1, 10):
        f = smoother(faces, len(x), steps)
        est, true = [], []
        for seed in range(200):
            r = np.random.default_rng(100 + seed)
            y = x + sigma * r.normal(size=x.shape)
            probe = r.normal(size=x.shape)
            eps = 0.1 * sigma
            q = f(y)
            est.append(sure_tilt(tilt, y, q, f(y + eps * probe), tilt(probe), eps, sigma))
            true.append(np.mean(tilt_ref(faces, nrm, q - x) ** 2))
        est, true = np.array(est), np.array(true)
        se = np.std(est - true, ddof=1) / np.sqrt(len(est))
        assert abs(est.mean() - true.mean()) < 4 * se, (steps, est.mean(), true.mean(), se)
        means.append((est.mean(), true.mean()))
    assert (means[0][0] < means[1][0]) == (means[0][1] < means[1][1])
