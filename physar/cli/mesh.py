"""`physar mesh …`: mesh generation and conversion."""

from __future__ import annotations

from pathlib import Path

import typer

from physar.cli._common import log, print_json, user_errors
from physar.geometry import box_mesh, read_mesh, write_mesh
from physar.geometry.io import check_mesh_destination

mesh_app = typer.Typer(help="Create and convert meshes.", no_args_is_help=True)


@mesh_app.command("box")
@user_errors
def box(
    size: tuple[float, float, float] = typer.Option(..., "--size", help="L W H in metres"),
    cells: tuple[int, int, int] = typer.Option(..., "--cells", help="nx ny nz hexahedra (6 tets each)"),
    out: Path = typer.Option(..., "-o", "--out", help="output mesh (.vtu, .xdmf, .msh, .mesh)"),  # noqa: B008 - typer idiom
    json_out: bool = typer.Option(False, "--json", help="print a JSON summary on stdout"),
) -> None:
    """Structured tetrahedral mesh of a box."""
    check_mesh_destination(out)
    m = box_mesh(size, cells)
    write_mesh(out, m)
    summary = {"file": str(out), "points": m.n_points, "tetrahedra": m.n_cells}
    if json_out:
        print_json(summary)
    else:
        log(f"wrote {out}: {m.n_points} points, {m.n_cells} tetrahedra")


@mesh_app.command("convert")
@user_errors
def convert(
    src: Path = typer.Argument(..., help="input mesh"),  # noqa: B008 - typer idiom
    dst_arg: Path | None = typer.Argument(None, metavar="OUT", show_default=False,  # noqa: B008 - typer idiom
                                          help="output mesh (deprecated: give it as --out; still accepted)"),
    dst_opt: Path | None = typer.Option(None, "--out", "-o", show_default=False,  # noqa: B008 - typer idiom
                                        help="output mesh; format from the suffix"),
) -> None:
    """Convert a tetrahedral or triangle mesh between formats (validated on the way).

    Region tags and physical-group names are kept in .msh, .vtu and .xdmf;
    .mesh and .vtk keep the tag numbers only (one warning names the regions).
    A surface with degenerate faces (a vertex repeated in a face, or zero area) is refused in one line
    naming their counts, as denoise and fem refuse it; so is a tetrahedral mesh with a degenerate element."""
    from physar.cli._common import output_path, warn_positional
    from physar.geometry.io import SURFACE_FORMATS, VOLUME_FORMATS
    from physar.geometry.mesh import TriMesh, check_faces
    from physar.output import check_destination

    dst = output_path(dst_opt, dst_arg, "physar mesh convert IN --out OUT")
    check_destination(dst, inputs=[src], suffixes=sorted(VOLUME_FORMATS | SURFACE_FORMATS), kind="mesh")
    m = read_mesh(src)
    if isinstance(m, TriMesh):
        check_faces(m, str(src))
    write_mesh(dst, m)
    log(f"wrote {dst}")
    warn_positional(dst_arg, dst_opt, "mesh convert")


def register(app: typer.Typer) -> None:
    app.add_typer(mesh_app, name="mesh")
