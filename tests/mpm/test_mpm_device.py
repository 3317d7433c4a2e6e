"""The MPM's Warp device (``MPMModel.device``): validation, the scene-file route, where the arrays live, and the
zero-copy CPU path of the torch bridge.

Mutants caught: dropping the check in ``MPMModel.__post_init__`` (a bad device would only fail at the first
launch, with Warp's message), an error that does not name the value or Warp's devices, the scene's ``device``
not passed to the model, a torch bridge that copies CPU tensors (``.clone()`` / ``.cpu().numpy()`` round trips
in ``_to_wp`` / ``adjoint._wp``), arrays allocated off the model's device.
"""

import numpy as np
import pytest
import torch
import warp as wp

from physar.errors import ConfigError
from physar.mpm.colliders import Collider
from physar.mpm.model import Control, MPMModel, MPMSolver, resolve_device
from physar.mpm.scene import build_model, load_scene, parse_scene

BODY = {"shape": "box", "min": [0.4, 0.4, 0.4], "max": [0.6, 0.6, 0.6]}


def _model(**kw) -> MPMModel:
    n = 8
    return MPMModel(size=1.0, resolution=8, dt=1e-3, substeps=2, mass=np.ones(n), volume=np.full(n, 1e-3),
                    E=np.full(n, 1e4), nu=np.full(n, 0.3), elastic=np.zeros(n), plastic=np.zeros(n),
                    plastic_params=np.zeros((n, 4)), body=np.zeros(n), **kw)


def _cuda_count() -> int:
    return sum(d.is_cuda for d in wp.get_devices())


@pytest.mark.parametrize("bad", ["cuda:7", "tpu", "CPU", "cuda:", 0, None])
def test_unknown_device_is_a_config_error_naming_it_and_warps_devices(bad):
    if bad == "cuda:7" and _cuda_count() > 7:
        pytest.skip("this machine has a cuda:7")
    with pytest.raises(ConfigError) as e:
        _model(device=bad)
    msg = str(e.value)
    assert repr(bad) in msg and "\n" not in msg
    assert "Warp has " + ", ".join(d.alias for d in wp.get_devices()) in msg


@pytest.mark.skipif(_cuda_count() > 0, reason="needs a machine without CUDA")
def test_cuda_without_a_gpu_is_a_config_error():
    with pytest.raises(ConfigError, match=r"MPM device 'cuda' is not available: Warp has cpu"):
        resolve_device("cuda")


def test_default_device_is_cpu_and_every_array_lives_there():
    m = _model(colliders=[Collider(center=(0.5, 0.5, 0.1))])
    assert m.device == "cpu" and _model(device="cpu").device == "cpu"
    arrays = dict(m.warp_arrays())
    col = arrays.pop("colliders")
    arrays.update({f"collider.{k}": getattr(col, k) for k in ("kind", "size", "axis", "bc", "friction", "center",
                                                             "velocity")})
    solver = MPMSolver(m)
    arrays.update({k: getattr(solver, k) for k in ("tau", "F_trial", "grid_mv", "grid_m", "grid_v")})
    st = m.state(np.full((8, 3), 0.5))
    arrays.update({f"state.{k}": getattr(st, k) for k in ("x", "v", "C", "F", "Jp")})
    arrays.update({f"copy.{k}": getattr(st.copy(), k) for k in ("x", "v", "C", "F", "Jp")})
    ctrl = Control(np.ones(8), np.zeros((8, 3)), np.zeros((8, 3)))
    arrays.update({f"control.{i}": a for i, a in enumerate(ctrl.warp(m.device))})
    assert {k: str(a.device) for k, a in arrays.items()} == {k: "cpu" for k in arrays}


def test_scene_device_key(tmp_path):
    sc = parse_scene({"body": [BODY], "grid": {"resolution": 8}})
    assert sc.device == "cpu" and build_model(sc)[0].device == "cpu"
    p = tmp_path / "scene.toml"
    p.write_text('device = "tpu"\n[[body]]\nshape = "box"\nmin = [0.4, 0.4, 0.4]\nmax = [0.6, 0.6, 0.6]\n')
    with pytest.raises(ConfigError, match=r"scene.toml: \[device\] 'tpu' is not a device: use 'cpu'"):
        load_scene(p)
    if _cuda_count() <= 7:  # a well-formed name that Warp does not have: the model's error
        sc = parse_scene({"device": "cuda:7", "body": [BODY], "grid": {"resolution": 8}})
        with pytest.raises(ConfigError, match=r"MPM device 'cuda:7' is not available: Warp has "):
            build_model(sc)


def test_synth_config_device_key():
    from physar.recon.synth import load_synth_config

    assert load_synth_config(None).device == "cpu"
    with pytest.raises(ConfigError, match=r"\[synth.device\] 'gpu' is not a device"):
        load_synth_config(None, {"device": "gpu"})


def test_cpu_path_is_zero_copy():
    """A CPU model wraps CPU tensors in place and hands its results back aliased (no copies on the CPU)."""
    from physar.mpm import adjoint, torch_bridge

    t = torch.arange(12, dtype=torch.float64).reshape(4, 3)
    cpu = torch_bridge._torch_device(_model())
    assert cpu == torch.device("cpu")
    a = torch_bridge._to_wp(t, False, cpu)
    assert a.ptr == t.data_ptr() and str(a.device) == "cpu"
    assert adjoint._wp(t, wp.vec3d, "cpu").ptr == t.data_ptr()
    back = torch_bridge._from_wp(a, cpu)
    assert back.data_ptr() == t.data_ptr()
    assert torch_bridge._from_wp(a, cpu, copy=True).data_ptr() != t.data_ptr()  # a gradient is copied out
