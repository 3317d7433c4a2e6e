"""Python-API input checks of :mod:`physar.gaussians` (probe findings):

* ``render`` of Gaussians with a NaN mean, a NaN opacity logit, a zero quaternion or log-scales whose exp()
  overflows returned an empty image (the Gaussian silently culled); NaN SH coefficients, colours or background a
  NaN image; ``colors`` (2, 3) for one Gaussian and ``eps2d < 0``, ``near <= 0`` or NaN ran; ``tile_size`` 0, a
  float64 ``F``/``cov3d``/``colors`` with float32 Gaussians, a (2,) background, ``pixel_chunk=-1`` ended in
  ZeroDivisionError / RuntimeError / ValueError deep in torch;
* ``Camera`` accepted fx = NaN or inf, cx = NaN, width 64.5, a NaN or non-rotation R, R and t of two dtypes
  (then a torch error in ``center``); ``look_at`` with fov 0 divided by zero, fov 180 gave fx = 4e-15;
* ``quat_to_rotmat`` / ``covariance`` of a zero quaternion returned NaN, ``rotmat_to_quat`` of a (3, 4) or a
  zero matrix returned the identity quaternion; wrong shapes/dtypes ended in unpack or matmul errors;
* ``Gaussians.from_values`` accepted NaN/inf means, scales, opacities and colours and zero quaternions; mixed
  dtypes, integer or NumPy tensors passed the constructor and failed later;
* ``eval_sh`` at a zero direction (a mean at the camera centre) returned NaN, K = 2 a KeyError;
* ``load_ply``: a vertex count beyond the file size ended in MemoryError, an ASCII file of 0 vertices was refused,
  a binary file with more vertex records than declared was read short silently, a property declared twice gave a
  misleading "missing property", a double beyond float32 loaded as inf, ``dtype=torch.int64`` truncated;
  ``save_ply`` of 0 Gaussians failed in a reshape, and values beyond float32 were written as inf.

Each now gives one :class:`PhysarError` naming the argument (and the Gaussian or vertex). Valid neighbours are
checked against closed forms: a single isotropic Gaussian on the optical axis has, with ``eps2d = 0``, peak alpha
= opacity at its centre pixel and exp(-1/2) of it one sigma (f s / z pixels) away.
"""
import math

import numpy as np
import pytest
import torch

from physar.errors import PhysarError
from physar.gaussians import (
    Camera,
    Gaussians,
    covariance,
    eval_sh,
    load_ply,
    project,
    quat_to_rotmat,
    rasterize_dense,
    rasterize_tiles,
    render,
    rotmat_to_quat,
    save_ply,
)
from physar.gaussians.ply import attribute_names
from physar.gaussians.sh import C0, C1

D = torch.float64
NAN, INF = math.nan, math.inf


def _cam(**kw):
    base = {"fx": 100.0, "fy": 100.0, "cx": 32.5, "cy": 32.5, "width": 64, "height": 64, "R": torch.eye(3, dtype=D),
                "t": torch.tensor([0.0, 0.0, 2.0], dtype=D)}
    return Camera(**{**base, **kw})


def _g(n=1, dtype=D, **kw):
    base = {"means": torch.zeros(n, 3, dtype=dtype), "scales": torch.full((n,), 0.1, dtype=dtype),
                "opacities": torch.full((n,), 0.8, dtype=dtype), "colors": torch.full((n, 3), 0.5, dtype=dtype)}
    return Gaussians.from_values(**{**base, **kw})


# ----------------------------------------------------------------------------------------------- closed form
def test_isotropic_gaussian_on_axis_peak_and_one_sigma():
    """Mean on the optical axis at z = 2 m, s = 0.1 m, f = 100 px: sigma = f s / z = 5 px; pixel (32, 32)'s centre
    (32.5, 32.5) is the principal point."""
    eta, rgb = 0.8, torch.tensor([[0.2, 0.6, 1.0]], dtype=D)
    g = _g(opacities=torch.tensor([eta], dtype=D), colors=rgb)
    for backend in ("torch", "dense"):
        out = render(g, _cam(), eps2d=0.0, backend=backend)
        a = out.alpha
        assert a[32, 32].item() == pytest.approx(eta, rel=1e-12)
        for j, i in ((32, 37), (32, 27), (37, 32), (27, 32)):
            assert a[j, i].item() == pytest.approx(eta * math.exp(-0.5), rel=1e-12)
        assert out.depth[32, 32].item() == pytest.approx(2.0, rel=1e-12)
        np.testing.assert_allclose(out.rgb[32, 32].numpy(), eta * rgb[0].numpy(), rtol=1e-12)


# ----------------------------------------------------------------------------------------------- render
def _bad_gaussians(field, value):
    g = _g(2)
    t = getattr(g, field).clone()
    t[1] = value
    return g.replace(**{field: t})


@pytest.mark.parametrize("field, value, words", [
    ("means", NAN, r"render: means\[1\] contains NaN"),
    ("opacity_logits", NAN, r"render: opacity_logits\[1\] contains NaN"),
    ("sh", INF, r"render: sh\[1\] contains NaN or infinite"),
    ("quats", 0.0, r"render: quats\[1\] is zero"),
    ("log_scales", 800.0, r"render: log_scales\[1\] .* overflows exp\(\)"),
])
def test_render_refuses_nonfinite_gaussians(field, value, words):
    with pytest.raises(PhysarError, match=words):
        render(_bad_gaussians(field, value), _cam())


@pytest.mark.parametrize("kwargs, words", [
    ({"tile_size": 0}, "tile_size must be a whole number >= 1"),
    ({"tile_size": 2.5}, "tile_size must be a whole number >= 1"),
    ({"eps2d": -1.0}, "eps2d must be a finite number >= 0"),
    ({"eps2d": NAN}, "eps2d must be a finite number >= 0"),
    ({"near": 0.0}, "near must be a finite number > 0"),
    ({"near": NAN}, "near must be a finite number > 0"),
    ({"max_elements": NAN}, "max_elements must be a number > 0"),
    ({"backend": "dense", "pixel_chunk": -1}, "pixel_chunk must be a whole number >= 1 or None"),
    ({"colors": torch.ones(2, 3, dtype=D)}, r"colors must have shape \(1, 3\), got \(2, 3\)"),
    ({"colors": torch.ones(1, 3, dtype=torch.float32)}, "colors is torch.float32, the means torch.float64"),
    ({"colors": torch.tensor([[NAN, 0.0, 0.0]], dtype=D)}, r"colors\[0\] contains NaN"),
    ({"F": torch.eye(3)[None]}, "F is torch.float32, the means torch.float64"),
    ({"F": np.eye(3)[None]}, "F must be a torch tensor, got ndarray"),
    ({"cov3d": torch.eye(3, dtype=D).expand(2, 3, 3)}, r"cov3d must have shape \(1, 3, 3\)"),
    ({"cov3d": -0.01 * torch.eye(3, dtype=D)[None]}, r"cov3d\[0\] is not a covariance"),
    ({"cov3d": torch.tensor([[[0.01, 0.005, 0], [0, 0.01, 0], [0, 0, 0.01]]], dtype=D)}, "not a covariance"),
    ({"background": torch.ones(2)}, r"background must have shape \(3,\) or \(64, 64, 3\)"),
    ({"background": [NAN, 0.0, 0.0]}, "background contains NaN"),
])
def test_render_refuses_bad_arguments(kwargs, words):
    with pytest.raises(PhysarError, match=words):
        render(_g(), _cam(), **kwargs)


def test_render_refuses_wrong_types():
    with pytest.raises(PhysarError, match="g must be physar.gaussians.Gaussians"):
        render(torch.zeros(1, 3), _cam())
    with pytest.raises(PhysarError, match="cam must be a physar.gaussians.Camera"):
        render(_g(), None)


def test_render_valid_neighbours_of_refused_arguments():
    """A list background, an (H, W, 3) background image and a PSD cov3d pass and give the closed forms."""
    g, cam = _g(), _cam()
    out = render(g, cam, eps2d=0.0, background=[0.0, 0.0, 1.0])
    np.testing.assert_allclose(out.rgb[0, 0].numpy(), [0.0, 0.0, 1.0], atol=1e-15)   # far from the Gaussian
    out = render(g, cam, eps2d=0.0, cov3d=0.01 * torch.eye(3, dtype=D)[None], background=torch.zeros(64, 64, 3))
    assert out.alpha[32, 37].item() == pytest.approx(0.8 * math.exp(-0.5), rel=1e-12)


def test_project_and_rasterizers_refuse():
    m, c, o, col = torch.zeros(1, 3, dtype=D), 0.01 * torch.eye(3, dtype=D)[None], torch.full((1,), 0.5, dtype=D), \
        torch.ones(1, 3, dtype=D)
    with pytest.raises(PhysarError, match=r"opacities must lie in \[0, 1\]"):
        project(m, c, torch.full((1,), 1.5, dtype=D), col, _cam())
    with pytest.raises(PhysarError, match=r"project: cov3d must have shape \(1, 3, 3\)"):
        project(m, torch.eye(2, dtype=D)[None], o, col, _cam())
    with pytest.raises(PhysarError, match="project: means must be a floating tensor"):
        project(m.long(), c, o, col, _cam())
    pr = project(m, c, o, col, _cam())
    with pytest.raises(PhysarError, match="rasterize_tiles: width must be a whole number >= 1"):
        rasterize_tiles(pr, 0, 64)
    with pytest.raises(PhysarError, match="rasterize_dense: pixel_chunk must be"):
        rasterize_dense(pr, 64, 64, pixel_chunk=0)
    with pytest.raises(PhysarError, match="rasterize_tiles: pr must be the Projected"):
        rasterize_tiles(None, 64, 64)
    # valid: cov 0.01 I at z = 2 m, f = 100 -> sigma 5 px; eps2d 0.3 adds to the 2-D variance
    a = rasterize_tiles(pr, 64, 64).alpha
    assert a[32, 37].item() == pytest.approx(0.5 * math.exp(-0.5 * 25 / (25 + 0.3)), rel=1e-12)


# ----------------------------------------------------------------------------------------------- camera
@pytest.mark.parametrize("kwargs, words", [
    ({"fx": NAN}, "fx must be a finite number"),
    ({"fy": INF}, "fy must be a finite number"),
    ({"cx": NAN}, "cx must be a finite number"),
    ({"fx": 0.0}, "focal lengths must be positive"),
    ({"width": 64.5}, "width must be a positive whole number of pixels, got 64.5"),
    ({"height": "64"}, "height must be a positive whole number of pixels"),
    ({"width": 0}, "width must be a positive whole number"),
    ({"R": 2 * torch.eye(3, dtype=D)}, r"R is not a rotation matrix .* det 8"),
    ({"R": torch.diag(torch.tensor([1.0, 1.0, -1.0], dtype=D))}, r"R is not a rotation matrix .* det -1"),
    ({"R": torch.full((3, 3), NAN, dtype=D)}, "R contains NaN"),
    ({"t": torch.tensor([0.0, NAN, 0.0], dtype=D)}, "t contains NaN"),
    ({"t": torch.zeros(1, 3, dtype=D)}, r"t must have shape \(3,\), got \(1, 3\)"),
    ({"t": torch.zeros(3)}, r"R \(torch.float64\) and t \(torch.float32\) must have the same dtype"),
])
def test_camera_refuses(kwargs, words):
    with pytest.raises(PhysarError, match=words):
        _cam(**kwargs)


def test_camera_valid_neighbours():
    cam = _cam(width=64.0, R=np.eye(3), t=np.array([0.0, 0.0, 2.0]))   # integral float size, NumPy pose
    assert cam.width == 64 and isinstance(cam.width, int) and isinstance(cam.R, torch.Tensor)
    np.testing.assert_array_equal(cam.center.numpy(), [0.0, 0.0, -2.0])


@pytest.mark.parametrize("kwargs, words", [
    ({"fov_y_deg": 0.0}, r"fov_y_deg must be a number of degrees in \(0, 180\)"),
    ({"fov_y_deg": 180.0}, r"fov_y_deg must be a number of degrees in \(0, 180\)"),
    ({"eye": [NAN, 0.0, -2.0]}, "eye must be 3 finite numbers"),
    ({"eye": [0.0, -2.0]}, "eye must be 3 finite numbers"),
    ({"dtype": torch.int64}, "dtype must be a floating torch dtype"),
])
def test_look_at_refuses(kwargs, words):
    with pytest.raises(PhysarError, match=words):
        Camera.look_at(**{"eye": [0.0, 0.0, -2.0], "target": [0.0, 0.0, 0.0], **kwargs})


def test_look_at_valid_neighbour_focal_closed_form():
    cam = Camera.look_at([0.0, 0.0, -2.0], [0.0, 0.0, 0.0], fov_y_deg=90.0, height=100, width=80)
    assert cam.fy == pytest.approx(50.0, rel=1e-12)   # f = (h / 2) / tan(fov / 2)


# ----------------------------------------------------------------------------------------------- model
def test_quaternion_functions_refuse_and_closed_forms():
    with pytest.raises(PhysarError, match=r"quaternion 1 \(flattened\) is zero or not finite"):
        quat_to_rotmat(torch.tensor([[1.0, 0, 0, 0], [0, 0, 0, 0]]))
    with pytest.raises(PhysarError, match=r"quaternions must have shape \(\.\.\., 4\), got \(3,\)"):
        quat_to_rotmat(torch.ones(3))
    with pytest.raises(PhysarError, match="quaternions must be a floating tensor"):
        quat_to_rotmat(torch.tensor([1, 0, 0, 0]))
    with pytest.raises(PhysarError, match=r"r must have shape \(\.\.\., 3, 3\), got \(3, 4\)"):
        rotmat_to_quat(torch.zeros(3, 4))
    with pytest.raises(PhysarError, match="matrix 0 .* is not a rotation"):
        rotmat_to_quat(torch.zeros(3, 3))
    with pytest.raises(PhysarError, match="is not a rotation"):
        rotmat_to_quat(torch.full((3, 3), NAN))
    # valid: (w, x, y, z) = (cos th/2, 0, 0, sin th/2) is the rotation by th about z; a non-unit one too
    th = 0.7
    Rz = torch.tensor([[math.cos(th), -math.sin(th), 0], [math.sin(th), math.cos(th), 0], [0, 0, 1]], dtype=D)
    q = torch.tensor([math.cos(th / 2), 0, 0, math.sin(th / 2)], dtype=D)
    torch.testing.assert_close(quat_to_rotmat(3.0 * q), Rz, rtol=0, atol=1e-15)
    torch.testing.assert_close(rotmat_to_quat(Rz), q, rtol=0, atol=1e-15)


def test_covariance_refuses_and_closed_form():
    q = torch.tensor([[1.0, 0, 0, 0]] * 2, dtype=D)
    with pytest.raises(PhysarError, match=r"scales must have shape \(2, 3\)"):
        covariance(q, torch.ones(2, dtype=D))
    with pytest.raises(PhysarError, match=r"F must have shape \(2, 3, 3\)"):
        covariance(q, torch.ones(2, 3, dtype=D), torch.eye(3, dtype=D))
    with pytest.raises(PhysarError, match="F is torch.float32, quats torch.float64"):
        covariance(q, torch.ones(2, 3, dtype=D), torch.eye(3).expand(2, 3, 3))
    with pytest.raises(PhysarError, match=r"scales\[1\] contains NaN"):
        covariance(q, torch.tensor([[1.0, 1, 1], [1, NAN, 1]], dtype=D))
    s = torch.tensor([[0.1, 0.2, 0.3], [1.0, 2.0, 3.0]], dtype=D)
    torch.testing.assert_close(covariance(q, s), torch.diag_embed(s**2), rtol=0, atol=1e-15)


@pytest.mark.parametrize("kwargs, words", [
    ({"means": torch.tensor([[NAN, 0, 0]], dtype=D)}, r"means\[0\] contains NaN"),
    ({"scales": torch.tensor([INF], dtype=D)}, r"scales\[0\] contains NaN or infinite"),
    ({"scales": torch.ones(2, dtype=D)}, r"scales must have shape \(1,\) or \(1, 3\), got \(2,\)"),
    ({"opacities": torch.tensor([NAN], dtype=D)}, r"opacities\[0\] contains NaN"),
    ({"colors": torch.ones(2, 3, dtype=D)}, r"colors must have shape \(1, 3\), got \(2, 3\)"),
    ({"colors": torch.tensor([[NAN, 0, 0]], dtype=D)}, r"colors\[0\] contains NaN"),
    ({"quats": torch.zeros(1, 4, dtype=D)}, r"quats\[0\] is zero"),
    ({"sh_degree": 1.5}, "sh_degree must be 0..3, got 1.5"),
])
def test_from_values_refuses(kwargs, words):
    with pytest.raises(PhysarError, match="Gaussians.from_values: " + words):
        _g(**kwargs)


def test_constructor_refuses_types_and_mixed_dtypes():
    z = {"means": torch.zeros(1, 3), "quats": torch.tensor([[1.0, 0, 0, 0]]), "log_scales": torch.zeros(1, 3),
             "opacity_logits": torch.zeros(1), "sh": torch.zeros(1, 1, 3)}
    with pytest.raises(PhysarError, match="means must be a torch tensor, got ndarray"):
        Gaussians(**{**z, "means": np.zeros((1, 3))})
    with pytest.raises(PhysarError, match="means must be a floating tensor, got torch.int64"):
        Gaussians(**{**z, "means": torch.zeros(1, 3, dtype=torch.int64)})
    with pytest.raises(PhysarError, match="quats is torch.float64 on cpu, means torch.float32"):
        Gaussians(**{**z, "quats": z["quats"].double()})
    g = Gaussians(**z)
    with pytest.raises(PhysarError, match="rot is torch.float64, the Gaussians torch.float32"):
        g.transformed(torch.eye(3, dtype=D)[None], torch.zeros(1, 3))
    with pytest.raises(PhysarError, match=r"rot must have shape \(1, 3, 3\)"):
        g.transformed(torch.eye(3)[None].expand(2, 3, 3), torch.zeros(1, 3))
    moved = g.transformed(torch.eye(3), torch.tensor([1.0, 2.0, 3.0]))   # one motion for all: valid
    np.testing.assert_array_equal(moved.means.numpy(), [[1.0, 2.0, 3.0]])


def test_eval_sh_refuses_and_zero_direction_gives_dc():
    with pytest.raises(PhysarError, match=r"sh must have shape \(N, K, 3\) with K in"):
        eval_sh(torch.zeros(1, 2, 3), torch.ones(1, 3))
    with pytest.raises(PhysarError, match=r"dirs must have shape \(2, 3\)"):
        eval_sh(torch.zeros(2, 4, 3), torch.ones(3, 3))
    with pytest.raises(PhysarError, match="dirs contains NaN"):
        eval_sh(torch.zeros(1, 4, 3), torch.tensor([[NAN, 0, 0]]))
    sh = torch.tensor([[[0.3, 0.1, -0.2], [0.5, 0.5, 0.5], [0.7, -0.4, 0.2], [0.9, 0.9, 0.9]]], dtype=D)
    dc = C0 * sh[0, 0] + 0.5
    torch.testing.assert_close(eval_sh(sh, torch.zeros(1, 3, dtype=D))[0], dc, rtol=0, atol=1e-15)  # was NaN
    # valid neighbour: direction +z (any length): Y_1 = (-C1 y, C1 z, -C1 x) -> only the second band-1 term
    torch.testing.assert_close(eval_sh(sh, torch.tensor([[0.0, 0.0, 4.0]], dtype=D))[0], dc + C1 * sh[0, 2],
                               rtol=0, atol=1e-15)


# ----------------------------------------------------------------------------------------------- PLY
_NAMES0 = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
           "rot_0", "rot_1", "rot_2", "rot_3"]


def _ascii(tmp_path, rows, n=None, names=_NAMES0, kind="float", name="a.ply"):
    head = f"ply\nformat ascii 1.0\nelement vertex {len(rows) if n is None else n}\n"
    head += "".join(f"property {kind} {a}\n" for a in names) + "end_header\n"
    p = tmp_path / name
    p.write_text(head + "".join(" ".join(map(str, r)) + "\n" for r in rows))
    return p


def test_load_ply_refusals(tmp_path):
    p = tmp_path / "g.ply"
    save_ply(p, _g(3, dtype=torch.float32))
    raw = p.read_bytes()
    hdr, body = raw.split(b"end_header\n", 1)
    per = len(body) // 3
    cases = {
        "count.ply": (hdr.replace(b"vertex 3", b"vertex 2") + b"end_header\n" + body, "the vertex count in the header"),
        "huge.ply": (hdr.replace(b"vertex 3", b"vertex 99999999999") + b"end_header\n" + body, "truncated PLY body"),
        "dup.ply": (hdr.replace(b"property float y\n", b"property float x\n") + b"end_header\n" + body,
                    "property 'x' declared twice in element 'vertex'"),
    }
    for name, (content, words) in cases.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(PhysarError, match=words):
            load_ply(tmp_path / name)
    with pytest.raises(PhysarError, match="load_ply needs a floating dtype"):
        load_ply(p, dtype=torch.int64)
    cloud = _ascii(tmp_path, [[0, 0, 0]], names=["x", "y", "z"], name="cloud.ply")
    with pytest.raises(PhysarError, match="missing properties 'f_dc_0', .*'rot_3' .*point-cloud"):
        load_ply(cloud)
    big = _ascii(tmp_path, [[1e39, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0]], kind="double", name="big.ply")
    with pytest.raises(PhysarError, match="means of vertex 0 is beyond the range of torch.float32"):
        load_ply(big)
    assert load_ply(big, dtype=D).means[0, 0].item() == 1e39          # valid neighbour: float64
    # valid neighbour of a wrong count: less than one record of trailing bytes is tolerated
    (tmp_path / "pad.ply").write_bytes(raw + b"\0" * (per - 1))
    g = load_ply(tmp_path / "pad.ply")
    torch.testing.assert_close(g.means, torch.zeros(3, 3), rtol=0, atol=0)


def test_ply_empty_and_hand_values(tmp_path):
    e = load_ply(_ascii(tmp_path, [], n=0, name="empty.ply"))       # refused before
    assert len(e) == 0 and e.sh.shape == (0, 1, 3)
    p = save_ply(tmp_path / "e0.ply", _g(0, sh_degree=2))           # failed in a reshape before
    g0 = load_ply(p)
    assert len(g0) == 0 and g0.sh.shape == (0, 9, 3)
    row = [1.5, -2, 0.25, 0.1, 0.2, 0.3, 2.0, math.log(0.5), 0, -1, 2, 0, 0, 0]
    g = load_ply(_ascii(tmp_path, [row]), dtype=D)
    np.testing.assert_allclose(g.scales[0].numpy(), [0.5, 1.0, math.exp(-1)], rtol=1e-7)
    assert g.opacities[0].item() == pytest.approx(1 / (1 + math.exp(-2.0)), rel=1e-7)
    np.testing.assert_allclose(g.rotations[0].numpy(), np.eye(3), atol=0)


def test_save_ply_refusals(tmp_path):
    with pytest.raises(PhysarError, match="save_ply needs physar.gaussians.Gaussians, got NoneType"):
        save_ply(tmp_path / "n.ply", None)
    g = _g(2)
    g.means[1, 0] = 1e39
    with pytest.raises(PhysarError, match="beyond float32 .* not written"):
        save_ply(tmp_path / "big.ply", g)
    assert not (tmp_path / "big.ply").exists()
    assert attribute_names(0) == ["x", "y", "z", "nx", "ny", "nz"] + _NAMES0[3:]
