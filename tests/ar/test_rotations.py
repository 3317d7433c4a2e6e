"""The batched Rodrigues map of the project pipeline's Gauss-Newton step against OpenCV's, one vector at a time."""
import cv2
import numpy as np

from physar.ar.project_pipeline import _rotations


def test_rotations_match_opencv_rodrigues():
    """Large angles, the finite-difference steps (1e-6 rad) the Jacobian takes, zero, the series' edge (1e-4)
    and pi: every matrix within 1e-14 of cv2.Rodrigues and orthonormal. Catches: W transposed (R^T), the
    (1 - cos)/theta^2 term dropped (first order only: 0.5 error at 1 rad) or sin/theta replaced by 1."""
    rng = np.random.default_rng(7)
    w = np.vstack([rng.normal(size=(40, 3)) * 1.5, rng.normal(size=(20, 3)) * 1e-6, np.zeros((1, 3)),
                   [[1e-4, 0, 0], [0, 1.0001e-4, 0], [0, 0, np.pi], [0.3, -2.0, 0.9]]])
    R = _rotations(w)
    ref = np.array([cv2.Rodrigues(v.reshape(3, 1))[0] for v in w])
    np.testing.assert_allclose(R, ref, atol=1e-14)
    np.testing.assert_allclose(np.einsum("kji,kjl->kil", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-13)
