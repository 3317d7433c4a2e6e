"""CLI: `physar denoise` and `physar noise` for surface meshes and PLY point clouds (seed 001 §3.2.1)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from physar.cli._common import log, print_json, user_errors
from physar.errors import PhysarError


def _load(path: Path):
    """Return (TriMesh, None) for a surface or (None, points) for a PLY point cloud."""
    from physar.geometry.io import read_mesh
    from physar.geometry.mesh import TriMesh
    from physar.geometry.pointcloud import read_ply

    if path.suffix.lower() == ".ply":
        pts, faces = read_ply(path)
        if faces is None:
            return None, pts
        return TriMesh(pts, faces, name=str(path)), None
    m = read_mesh(path, kind="tri")
    if not isinstance(m, TriMesh):
        raise PhysarError(f"{path}: expected a triangle surface mesh")
    return m, None


def _check_out(out: Path, inp: Path, cloud: bool) -> None:
    """The output checked before any work: a surface format (.ply only for a point cloud), not the input,
    a writable place (one line naming the path)."""
    from physar.geometry.io import SURFACE_FORMATS
    from physar.output import check_destination

    check_destination(out, inputs=[inp], suffixes=[".ply"] if cloud else sorted(SURFACE_FORMATS),
                      kind="point cloud" if cloud else "surface mesh")


def _save(path: Path, mesh, pts) -> None:
    from physar.geometry.io import write_mesh
    from physar.geometry.pointcloud import write_ply

    if mesh is None:
        write_ply(path, pts)
    else:
        write_mesh(path, mesh)


def register(app: typer.Typer) -> None:
    """Add the `denoise` and `noise` commands to `app`."""

    @app.command("denoise")
    @user_errors
    def denoise_cmd(
        inp: Annotated[Path, typer.Argument(help="input mesh (PLY/OBJ/STL/OFF) or PLY point cloud")],
        out: Annotated[Path, typer.Argument(help="output file (same kinds)")],
        method: str = typer.Option("msal", "--method", help="al | msal | msal-sharp (CAD: edge-preserving) | laplacian | taubin | bnf"),
        iterations: int = typer.Option(None, "--iterations", help="iterations (default per method)"),
        k: int = typer.Option(10, "--k", help="neighbours for point clouds"),
        json_out: bool = typer.Option(False, "--json", help="print a JSON summary on stdout"),
    ) -> None:
        """Denoise a surface mesh or point cloud with AL/MSAL (seed 001 §3.2.1) or a baseline."""
        import inspect
        import sys

        import numpy as np
        from tqdm import tqdm

        from physar.geometry.denoise import MAX_ITERATIONS, METHODS, denoise
        from physar.geometry.pointcloud import denoise_points

        if method not in METHODS:
            raise PhysarError(f"unknown denoising method {method!r}; choose one of {sorted(METHODS)}")
        if iterations is not None and not 1 <= iterations <= MAX_ITERATIONS:
            raise PhysarError(f"--iterations must be within 1..{MAX_ITERATIONS}, got {iterations}")
        _check_out(out, inp, cloud=False)
        mesh, pts = _load(inp)
        if mesh is None:
            if method not in ("al", "msal"):
                raise PhysarError(f"{inp}: point clouds support --method al or msal, got {method!r}")
            if k < 1:
                raise PhysarError(f"--k must be >= 1 (neighbours per point), got {k}")
            _check_out(out, inp, cloud=True)
        total = iterations
        if total is None:  # the method's own default, for the progress bar
            if mesh is None:
                total = 10 if method == "al" else 8  # denoise_points defaults
            else:
                total = inspect.signature(METHODS[method]).parameters["iterations"].default
        bar = tqdm(total=total, desc=f"{method} iterations", file=sys.stderr, disable=None if not json_out else True)
        prog = lambda i, q: bar.update(1)
        try:
            if mesh is not None:
                res = denoise(mesh, method, iterations, progress=prog)
                moved = np.linalg.norm(res.points - mesh.points, axis=1)
                _save(out, res, None)
                n = mesh.n_points
            else:
                q = denoise_points(pts, method, iterations, k=k, progress=prog)
                moved = np.linalg.norm(q - pts, axis=1)
                _save(out, None, q)
                n = len(pts)
        finally:
            bar.close()
        summary = {"input": str(inp), "output": str(out), "method": method, "points": n,
                   "mean_displacement_m": float(moved.mean()), "max_displacement_m": float(moved.max())}
        if json_out:
            print_json(summary)
        else:
            log(f"wrote {out}: {n} points, mean displacement {moved.mean():.3g} m")

    @app.command("noise")
    @user_errors
    def noise_cmd(
        inp: Annotated[Path, typer.Argument(help="input surface mesh")],
        out: Annotated[Path, typer.Argument(help="output surface mesh")],
        sigma: float = typer.Option(0.2, "--sigma", help="noise std s as a fraction of the mean edge length ē"),
        seed: int = typer.Option(0, "--seed", help="random seed (an integer >= 0)"),
        direction: str = typer.Option(
            "random", "--direction",
            help="random (default, the normal-filtering literature's convention: each vertex moves by "
                 "s·N(0,1) along its own uniformly random unit direction, covariance s²/3·I) | "
                 "normal (s·N(0,1) along the vertex normal)"),
        json_out: bool = typer.Option(False, "--json"),
    ) -> None:
        """Add seeded Gaussian noise to a surface mesh.

        Default (the convention of the mesh normal-filtering papers, e.g. Zheng et al. 2011, Zhang et al.
        2015): vertex i moves by s·t_i·u_i, t_i ~ N(0, 1), u_i uniform on the unit sphere, s = sigma·ē,
        so the mean squared displacement is s² (not 3s² as for N(0, s²I) per coordinate).
        """
        from physar.geometry.quality import add_noise, mean_edge_length

        if seed < 0:
            raise PhysarError(f"--seed must be an integer >= 0, got {seed}")
        _check_out(out, inp, cloud=False)
        mesh, _ = _load(inp)
        if mesh is None:
            raise PhysarError(f"{inp}: `noise` needs a surface mesh (faces), got a point cloud")
        noisy = add_noise(mesh, sigma, seed, direction)
        _save(out, noisy, None)
        summary = {"input": str(inp), "output": str(out), "sigma_m": sigma * mean_edge_length(mesh),
                   "seed": seed, "direction": direction}
        if json_out:
            print_json(summary)
        else:
            log(f"wrote {out} (noise std {summary['sigma_m']:.3g} m)")
