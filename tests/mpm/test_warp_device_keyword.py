"""Every Warp allocation and launch in physar names its device (``device=``).

Without it Warp uses its default device, ``cuda:0`` on any machine with a CUDA GPU, while the torch bridge
wraps CPU tensors as CPU arrays: the MPM then fails with Warp's "trying to launch on device='cuda:0', but input
array ... is on device=cpu" (or copies silently).  The development machines have no GPU, so only a static
check catches the regression.  This test failed on the code before the device change (commit 25b754e: 92
calls without ``device=`` in physar/mpm/{model,colliders,torch_bridge,adjoint}.py); any new call without
``device=`` fails it again, naming file:line.
"""

import ast
from pathlib import Path

import pytest

import physar

CALLS = ("launch", "zeros", "empty", "array", "full", "clone", "zeros_like", "empty_like")
ROOT = Path(physar.__file__).resolve().parent


def _warp_aliases(tree: ast.Module) -> set[str]:
    """Names under which the module imported warp (``import warp as wp``)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.asname or a.name for a in node.names if a.name == "warp")
    return names


def missing_device(source: str, filename: str = "<src>") -> list[str]:
    """``file:line wp.NAME(...)`` for every call of ``wp.NAME`` (NAME in CALLS) without a ``device=`` keyword.

    ``wp.array(dtype=...)`` with no positional argument is a kernel annotation (a type), not an allocation;
    a call with ``**kwargs`` cannot be checked and counts as missing."""
    tree = ast.parse(source, filename)
    aliases = _warp_aliases(tree)
    out = []
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                and isinstance(node.func.value, ast.Name) and node.func.value.id in aliases
                and node.func.attr in CALLS):
            continue
        if node.func.attr == "array" and not node.args and all(k.arg == "dtype" for k in node.keywords):
            continue  # wp.array(dtype=wp.vec3d): a kernel argument type
        if not any(k.arg == "device" for k in node.keywords):
            out.append(f"{filename}:{node.lineno} {ast.unparse(node.func)}(...)")
    return out


def test_every_warp_allocation_and_launch_names_its_device():
    bad = []
    for path in sorted(ROOT.rglob("*.py")):
        bad += missing_device(path.read_text(), str(path.relative_to(ROOT.parent)))
    assert not bad, "Warp calls without device= (Warp's default device is cuda:0 on a GPU machine):\n" + \
        "\n".join(bad)


@pytest.mark.parametrize("src, n", [
    ("import warp as wp\nwp.zeros(3, dtype=wp.float64)\n", 1),
    ("import warp as wp\nwp.launch(k, 3, inputs=[a])\n", 1),
    ("import warp\nwarp.empty_like(a)\n", 1),
    ("import warp as wp\nwp.array(x, dtype=wp.vec3d)\n", 1),
    ("import warp as wp\nwp.zeros(3, dtype=wp.float64, device=d)\nwp.launch(k, 3, inputs=[a], device=d)\n", 0),
    ("import warp as wp\ndef f(x: wp.array(dtype=wp.vec3d)): pass\n", 0),
    ("import numpy as wp\nwp.zeros(3)\n", 0),
])
def test_the_check_itself(src, n):
    """The checker flags calls without ``device=`` (so the test above cannot pass vacuously) and nothing else."""
    found = missing_device(src)
    assert len(found) == n, found
    if n:
        assert found[0].startswith("<src>:2 ")
