"""The verified cantilever example (run by `make demo` until the AR demo exists)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from physar.fem.assembly import ElasticModel
from physar.fem.elements import FESpace
from physar.fem.loads import fixed_dofs, traction_load
from physar.fem.materials import LinearElastic
from physar.fem.post import nodal_von_mises, probe, von_mises
from physar.fem.reference import timoshenko_cantilever_tip
from physar.fem.solvers import solve_static
from physar.geometry import TriMesh, box_mesh, write_mesh
from physar.geometry.plot import render_surface
from physar.output import write_json


def cantilever(
    length: float = 1.0,
    width: float = 0.05,
    height: float = 0.05,
    cells: tuple[int, int, int] = (40, 2, 2),
    element: str = "P2",
    E: float = 69e9,
    nu: float = 0.334,
    load: float = 1000.0,
):
    """Aluminium cantilever clamped at x = 0 with a shear load `load` [N] (-z) spread over x = L.

    Returns (space, model, u, tip deflection [m], Timoshenko reference [m]).
    """
    space = FESpace(box_mesh((length, width, height), cells), element)
    model = ElasticModel(space, LinearElastic(E, nu))
    fixed = fixed_dofs(space, box=[[0, 0, 0], [0, width, height]])
    f = traction_load(space, [[length, 0, 0], [length, width, height]], [0, 0, -load])
    u = solve_static(model, f, fixed).u
    tip = -probe(space, u, [length, width / 2, height / 2])[2]
    ref = timoshenko_cantilever_tip(load, length, width, height, E, nu)
    return space, model, u, tip, ref


def run_cantilever_demo(out: str | os.PathLike) -> dict:
    """Solve the cantilever, write cantilever.vtu, cantilever.png and report.json into `out`.

    The VTU's point field ``von_mises`` is the stress recovered at the vertices
    (:func:`physar.fem.post.nodal_von_mises`), its cell field the von Mises stress of each element's mean
    stress; the report's ``max_von_mises_pa`` is the peak of the vertex field (next to the clamp) and
    ``max_von_mises_element_mean_pa`` that of the element means."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    space, model, u, tip, ref = cantilever()
    vm = von_mises(model, u)
    vm_nodal = nodal_von_mises(model, u)
    uv = space.vertex_values(u)
    mag = np.linalg.norm(uv, axis=1)
    write_mesh(out / "cantilever.vtu", space.mesh,
               point_data={"displacement": uv, "displacement_magnitude": mag,
                           "von_mises": vm_nodal},
               cell_data={"von_mises": vm})
    surf = space.mesh.boundary()
    scale = 0.1 * 1.0 / max(mag.max(), 1e-300)  # show the deflection as 10 % of the length
    deformed = TriMesh(surf.mesh.points + scale * uv[surf.node_map], surf.mesh.faces)
    render_surface(deformed, mag[surf.node_map] * 1e3, out / "cantilever.png",
                   title=f"Aluminium cantilever, P2, 1 kN tip load (deformation x{scale:.0f})",
                   label="|u| [mm]", reference=surf.mesh)
    report = {
        "example": "cantilever",
        "tip_deflection_m": tip,
        "timoshenko_m": ref,
        "relative_error": abs(tip - ref) / ref,
        "max_von_mises_pa": float(vm_nodal.max()),
        "max_von_mises_element_mean_pa": float(vm.max()),
        "dofs": space.n_dofs,
        "files": ["cantilever.vtu", "cantilever.png", "report.json"],
    }
    write_json(out / "report.json", report, indent=2)
    return report
