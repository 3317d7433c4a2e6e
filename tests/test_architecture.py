"""The layer rule of ARCHITECTURE.md: data flows one way, a layer imports only the layers before it.

geometry -> fem -> (integrators | rom) -> assimilation -> vision/ar, and
geometry -> mpm -> gaussians/skinning -> recon. The CLI may import everything; `errors`, `output` (the one
module that writes files: destination checks, atomic writes, signals) and `media` (the one video decoder) are
shared, and import no layer.
"""
import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "physar"
SHARED = {"errors", "output", "media"}

ALLOWED = {
    "geometry": set(),
    "fem": {"geometry"},
    "integrators": {"geometry", "fem"},
    "rom": {"geometry", "fem"},
    "assimilation": {"geometry", "fem", "rom"},
    "vision": {"geometry", "fem", "rom", "assimilation"},
    "ar": {"geometry", "fem", "rom", "assimilation", "vision"},
    "mpm": {"geometry"},
    "gaussians": {"geometry", "mpm"},
    "skinning": {"geometry", "mpm", "gaussians"},
    "recon": {"geometry", "mpm", "gaussians", "skinning"},
    "synth": {"geometry", "fem", "rom", "assimilation", "vision", "ar"},
}


def _physar_imports(path: Path):
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module == "physar":
            names = [f"physar.{a.name}" for a in node.names]  # from physar import media
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        for name in names:
            parts = name.split(".")
            if parts[0] == "physar" and len(parts) > 1:
                yield parts[1], node.lineno


def _layer_files():
    for layer in sorted(ALLOWED):
        for path in sorted((ROOT / layer).rglob("*.py")):
            yield layer, path


def test_every_subpackage_has_a_layer():
    packages = {p.name for p in ROOT.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert packages - {"cli"} <= set(ALLOWED), f"add {packages - {'cli'} - set(ALLOWED)} to ALLOWED"


@pytest.mark.parametrize("layer,path", list(_layer_files()), ids=lambda v: str(v) if isinstance(v, str) else v.name)
def test_layer_imports_only_earlier_layers(layer, path):
    bad = [f"{path.relative_to(ROOT.parent)}:{line} imports physar.{dep}"
           for dep, line in _physar_imports(path)
           if dep not in ALLOWED[layer] | {layer} | SHARED]
    assert not bad, "layer rule broken (ARCHITECTURE.md): " + "; ".join(bad)


@pytest.mark.parametrize("name", sorted(SHARED))
def test_shared_modules_import_no_layer(name):
    bad = [f"physar/{name}.py:{line} imports physar.{dep}"
           for dep, line in _physar_imports(ROOT / f"{name}.py") if dep not in SHARED]
    assert not bad, "a shared module depends on a layer: " + "; ".join(bad)


def test_from_physar_import_form_is_seen(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("from physar import recon\nimport physar.fem.solvers\nfrom physar.vision import camera\n")
    assert sorted(d for d, _ in _physar_imports(f)) == ["fem", "recon", "vision"]
