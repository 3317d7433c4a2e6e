"""CLI: `physar denoise` and `physar noise` for surface meshes and PLY point clouds (seed 001 §3.2.1)."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from physar.cli._common import log, output_path, print_json, user_errors, warn_positional
from physar.errors import PhysarError, PhysarWarning

DEPRECATED = "(deprecated: give it as --out; still accepted)"


def _load(path: Path, role: str = "input"):
    """Return (TriMesh, None) for a surface or (None, points) for a PLY point cloud.

    A file holding tetrahedra (.vtu/.msh/.mesh/.xdmf volume mesh) gives the tet mesh's whole boundary surface
    (:func:`physar.geometry.mesh.boundary_surface`: outward, compact vertex numbering, no unused points), never
    the tagged triangle blocks the file may also hold (a patch of the boundary), with one PhysarWarning naming
    the file. Those blocks' tags and names stay on the boundary faces they cover (-1 elsewhere), so a surface
    format that stores them (.vtu, .msh, .xdmf) writes them to the output. ``role`` is "input" (the output is then a surface mesh) or "reference" (a --reference volume file
    gets the same surface, so its faces match those of the same tet mesh given as the input)."""
    from physar.geometry.io import read_mesh
    from physar.geometry.mesh import TetMesh, TriMesh, boundary_surface
    from physar.geometry.pointcloud import read_ply
    from physar.geometry.quality import oriented

    if path.suffix.lower() == ".ply":
        pts, faces = read_ply(path)
        if faces is None:
            return None, pts
        return oriented(TriMesh(pts, faces, name=str(path)), str(path)), None
    m = read_mesh(path, kind="auto")  # tetrahedra first: their boundary, not the file's tagged triangles
    if isinstance(m, TetMesh):
        surf = boundary_surface(m).mesh
        use = ("the output is a surface mesh (tetrahedralise it again as the [mesh] file of a problem)"
               if role == "input" else "it is compared as the reference surface")
        warnings.warn(f"{path}: holds a volume mesh ({m.n_cells} tetrahedra); its boundary surface "
                      f"({surf.n_faces} triangles) is used and {use}", PhysarWarning, stacklevel=2)
        return TriMesh(surf.points, surf.faces, name=m.name, face_tags=surf.face_tags, tag_names=surf.tag_names), None
    if not isinstance(m, TriMesh):
        raise PhysarError(f"{path}: expected a triangle surface mesh")
    return oriented(m, str(path)), None


_NORMALS = ("nx", "ny", "nz")
_POINT_DATA_FORMATS = {".ply", ".vtu", ".vtk", ".xdmf", ".xmf"}  # surface formats meshio writes point_data to


def _split(mesh, path: Path):
    """``(mesh, source)``: vertices where parts of ``mesh`` touch at a single point split, one copy per part
    (:func:`physar.geometry.quality.split_fans`), with one PhysarWarning naming the file; ``source`` maps the
    output vertices to the file's (for the per-vertex properties)."""
    from physar.geometry.quality import split_fans

    out, src = split_fans(mesh)
    if out is not mesh:
        k = len(np.unique(src[mesh.n_points:]))
        warnings.warn(f"{path}: {k} vertices where parts of the surface touch at a single point (non-manifold) were "
                      f"split, one copy per part ({out.n_points - mesh.n_points} copies added)", PhysarWarning,
                      stacklevel=2)
    return out, src


def _fields(path: Path, n_file: int, source: np.ndarray) -> dict:
    """:func:`_ply_vertex_fields` of the file's ``n_file`` vertices, taken for the vertices ``source`` names."""
    return {k: v[source] for k, v in _ply_vertex_fields(path, n_file).items()}


def _ply_vertex_fields(path: Path, n_points: int) -> dict:
    """The per-vertex properties of a PLY of ``n_points`` vertices other than x, y, z, in file order: {name: (n,)
    array in the file's type} (colours red/green/blue/alpha, texture coordinates, labels, normals nx/ny/nz, ...);
    {} for another format or a PLY without them. Face properties cannot be written (meshio's PLY writer writes
    none) and get one PhysarWarning naming them."""
    import trimesh

    if path.suffix.lower() != ".ply":
        return {}
    try:
        raw = trimesh.load(path, process=False, force=None).metadata.get("_ply_raw", {})
    except Exception:  # noqa: BLE001 - read_ply already read this file; a second parser failure loses no points
        return {}

    def columns(element) -> dict:
        data = (raw.get(element) or {}).get("data")
        if data is None:
            return {}
        if isinstance(data, np.ndarray) and data.dtype.names:
            return {k: data[k] for k in data.dtype.names}
        return dict(data)

    fields = {}
    for name, col in columns("vertex").items():
        col = np.asarray(col)
        if col.ndim == 2 and col.shape[1] == 1:  # an ASCII PLY's columns: (n, 1)
            col = col[:, 0]
        if name in ("x", "y", "z") or col.ndim != 1 or len(col) != n_points or col.dtype.kind not in "iuf":
            continue
        fields[str(name)] = col.astype(col.dtype.newbyteorder("="), copy=False)
    face_props = [k for k in columns("face") if k not in ("vertex_indices", "vertex_index")]
    if face_props:
        warnings.warn(f"{path}: the face properties {', '.join(face_props)} are not carried to the output (only "
                      "per-vertex properties are)", PhysarWarning, stacklevel=2)
    return fields


_CLOUD_COLOURS = {"red", "green", "blue", "diffuse_red", "diffuse_green", "diffuse_blue"}


def _cloud_colours(path: Path, n_points: int) -> np.ndarray | None:
    """The (n, 3) RGB colours in [0, 1] of a PLY point cloud (:func:`physar.geometry.pointcloud.read_ply` with
    ``colors=True``: red, green, blue or diffuse_red, ...; a float colour outside [0, 1] is a PhysarError naming
    the file and property), None when it has none. The output stores them as uchar (exact for uchar input)
    with alpha 255; every other vertex property (normals, intensity, an alpha that is not everywhere opaque,
    ...) is not carried and gets one PhysarWarning naming the file and the properties."""
    from physar.geometry.pointcloud import read_ply

    rgb = read_ply(path, colors=True)[2]
    fields = _ply_vertex_fields(path, n_points)
    alpha = fields.get("alpha")
    opaque = alpha is not None and (alpha == (np.iinfo(alpha.dtype).max if alpha.dtype.kind in "iu" else 1)).all()
    lost = [k for k in fields if k not in _CLOUD_COLOURS and not (k == "alpha" and opaque)]
    if lost:
        what = "property" if len(lost) == 1 else "properties"
        warnings.warn(f"{path}: the point {what} {', '.join(lost)} {'is' if len(lost) == 1 else 'are'} not carried "
                      "to the output (a point "
                      "cloud keeps x, y, z and its colours red, green, blue)", PhysarWarning, stacklevel=2)
    return rgb


def _output_fields(fields: dict, before, after, out: Path) -> dict | None:
    """Point data of the denoised (or noised) mesh ``after`` from the input's per-vertex ``fields``: every
    property copied unchanged (vertex count and order are the same), except normals nx, ny, nz, which are
    recomputed on the moved vertices (area-weighted face normals, :func:`physar.geometry.quality.vertex_normals`),
    unit length, in the input's type, and flipped as a whole when the input's normals point against the face
    winding (so they keep the file's inside/outside convention). An output format that stores no per-vertex
    data drops them with one PhysarWarning naming the output and the properties."""
    from physar.geometry.quality import vertex_normals

    if not fields:
        return None
    if out.suffix.lower() not in _POINT_DATA_FORMATS:
        warnings.warn(f"{out}: {out.suffix} stores no per-vertex data: the input's {', '.join(fields)} are not "
                      "written (write .ply to keep them)", PhysarWarning, stacklevel=2)
        return None
    fields = dict(fields)
    if all(k in fields for k in _NORMALS):
        given = np.column_stack([fields[k] for k in _NORMALS]).astype(float)
        sign = -1.0 if np.einsum("ij,ij->", given, vertex_normals(before)) < 0 else 1.0
        n = sign * vertex_normals(after)
        for j, k in enumerate(_NORMALS):
            fields[k] = n[:, j].astype(fields[k].dtype if fields[k].dtype.kind == "f" else float)
    return fields


def _is_cloud(path: Path, read_ply) -> bool:
    """True when the PLY file holds no faces (a point cloud); unreadable files are left to _load."""
    try:
        return read_ply(path)[1] is None
    except (PhysarError, OSError, ValueError):
        return False


def _check_out(out: Path, inp: Path, cloud: bool, reference: Path | None = None) -> None:
    """The output checked before any work: a surface format (.ply only for a point cloud), neither the input
    nor the --reference mesh (both are read, never overwritten), a writable place (one line naming the path)."""
    from physar.geometry.io import SURFACE_FORMATS
    from physar.output import check_destination

    check_destination(out, inputs=[inp, reference], suffixes=[".ply"] if cloud else sorted(SURFACE_FORMATS),
                      kind="point cloud" if cloud else "surface mesh")


def _save(path: Path, mesh, pts, point_data: dict | None = None, colors: np.ndarray | None = None) -> None:
    """Write the surface ``mesh`` with its per-vertex ``point_data``, or (``mesh`` None) the point cloud ``pts``
    with its (n, 3) ``colors`` (None: none), atomically."""
    from physar.geometry.io import write_mesh
    from physar.geometry.pointcloud import write_ply

    if mesh is None:
        write_ply(path, pts, colors=colors)
    else:
        write_mesh(path, mesh, point_data=point_data)


# CLI option -> keyword of each method (None: the option does not apply to that method)
_PARAMS = {
    "two-stage": {"sigma_r": "sigma_r"},
    "al": {"kappa": "kappa", "fidelity": "lam", "tau": "tau"},
    "msal": {"kappa": "kappa", "xi": "xi", "fidelity": "fidelity", "rescale": "rescale"},
    "msal-sharp": {"kappa": "kappa", "xi": "xi", "fidelity": "fidelity", "rescale": "rescale"},
    "laplacian": {}, "taubin": {}, "bnf": {"sigma_r": "sigma_r"},
}


def _method_params(method: str, **given) -> dict:
    """Map the options the user set to `method`'s keywords; an option the method does not take is one line."""
    table = _PARAMS[method]
    out = {}
    for opt, val in given.items():
        if val is None:
            continue
        if opt not in table:
            takes = ", ".join("--" + o.replace("_", "-") for o in table) or "no parameters"
            raise PhysarError(f"--{opt.replace('_', '-')} does not apply to --method {method} (it takes {takes})")
        if not np.isfinite(val):
            raise PhysarError(f"--{opt.replace('_', '-')} must be a finite number, got {val}")
        out[table[opt]] = float(val)
    return out


def reference_errors(noisy, result, clean) -> dict:
    """Errors of the input and of the result against the clean mesh (same faces): mean face-normal angle
    (degrees), mean vertex-to-surface distance (m, and in mean edge lengths of the clean mesh), relative
    volume change (NaN for an open surface)."""
    from physar.geometry import quality as Q

    ebar = Q.mean_edge_length(clean)
    out = {}
    for tag, m in (("_before", noisy), ("", result)):
        d = float(Q.point_to_surface_distance(m.points, clean).mean())
        out["normal_error_deg" + tag] = Q.normal_angle_error(m, clean)
        out["mean_distance_m" + tag] = d
        out["mean_distance_edge" + tag] = d / ebar
        try:
            out["volume_change" + tag] = Q.volume_change(m, clean) if _closed(clean) else float("nan")
        except PhysarError:
            out["volume_change" + tag] = float("nan")
    return out


def _closed(mesh) -> bool:
    e = np.sort(mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool((counts == 2).all())


def render_before_after(before, after, path: Path, title: str = "") -> Path:
    """PNG of two flat-shaded views (Lambert, one directional light) of the surface before and after,
    same camera and scale; matplotlib Agg (no display), written through physar.output.save_figure."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from physar.output import save_figure

    lo, hi = before.points.min(axis=0), before.points.max(axis=0)
    ext = np.maximum(hi - lo, 1e-12)
    light = np.array([0.35, -0.55, 0.76])
    fig = plt.figure(figsize=(10, 4.8))
    for k, (mesh, name) in enumerate(((before, "before"), (after, "after"))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        n = mesh.face_normals()
        fill = np.array([-0.6, 0.2, 0.3]) / np.linalg.norm([-0.6, 0.2, 0.3])  # second, weaker light
        shade = np.clip(0.22 + 0.6 * np.abs(n @ light) + 0.25 * np.abs(n @ fill), 0, 1)
        colours = np.c_[np.repeat(shade[:, None], 3, axis=1) * [0.86, 0.88, 0.92], np.ones(len(shade))]
        ax.add_collection3d(Poly3DCollection(mesh.points[mesh.faces], facecolors=colours, edgecolors=colours, linewidths=0.1))
        ax.set_xlim(lo[0], hi[0]), ax.set_ylim(lo[1], hi[1]), ax.set_zlim(lo[2], hi[2])
        ax.set_box_aspect(np.maximum(ext, 0.12 * ext.max()))
        ax.view_init(25, -60)
        ax.set_axis_off()
        ax.set_title(name)
    fig.suptitle(title)
    return save_figure(fig, path, dpi=120, bbox_inches="tight")


def register(app: typer.Typer) -> None:
    """Add the `denoise` and `noise` commands to `app`."""

    @app.command("denoise")
    @user_errors
    def denoise_cmd(
        inp: Annotated[Path, typer.Argument(help="input surface mesh (PLY/OBJ/STL/OFF; a volume mesh file: its whole boundary surface) or PLY point cloud")],
        out_arg: Annotated[Path | None, typer.Argument(metavar="OUT", show_default=False,
                                                       help="output file " + DEPRECATED)] = None,
        out_opt: Annotated[Path | None, typer.Option("--out", "-o", show_default=False,
                                                     help="output file (same kinds as the input)")] = None,
        method: str = typer.Option(
            None, "--method",
            help="two-stage (default for meshes: bilateral normal filter, feature-weighted Taubin, vertex update; the "
                 "amount of filtering from the mesh's own noise estimate) | al | msal (seed 001) | msal-sharp (MSAL, CAD feature "
                 "mode) | laplacian | taubin | bnf; point clouds: msal (default) | al"),
        iterations: int = typer.Option(None, "--iterations", help="iterations (default per method; two-stage: "
                                                                  "normal-filter iterations, automatic)"),
        kappa: float = typer.Option(None, "--kappa", help="al/msal: edge-stopping width κ in units of the "
                                                          "robust noise scale (default 1.5)"),
        xi: float = typer.Option(None, "--xi", help="msal: step decay ξ, τ_k = ξ^k (default 0.9)"),
        fidelity: float = typer.Option(None, "--fidelity", help="msal: fidelity factor f, λ_i = f σ_i/max σ "
                                                                "(default 0.05); al: constant λ (default 0)"),
        tau: float = typer.Option(None, "--tau", help="al: step size τ (default 0.5)"),
        rescale: float = typer.Option(None, "--rescale", help="msal: sharp-edge rescale ρ in [0, 1] (edge-"
                                                              "stopping scale follows the remaining noise)"),
        sigma_r: float = typer.Option(None, "--sigma-r", help="two-stage/bnf: range kernel width on normals"),
        reference: Annotated[Path | None, typer.Option(
            "--reference", help="clean mesh with the same faces (a volume mesh file: its boundary surface, as for the "
                                "input): print the mean face-normal angle error, mean vertex distance, volume change")] = None,
        render: Annotated[Path | None, typer.Option(
            "--render", help="before/after shaded picture (PNG; default: --out with suffix .png)")] = None,
        no_render: bool = typer.Option(False, "--no-render", help="write no picture"),
        k: int = typer.Option(None, "--k", help="neighbours for point clouds (default 10)"),
        json_out: bool = typer.Option(False, "--json", help="print a JSON summary on stdout"),
    ) -> None:
        """Denoise a surface mesh or point cloud (seed 001 §3.2.1 AL/MSAL, or the two-stage default).

        Surface PLY input: per-vertex colours and other properties are kept
        (.ply, .vtu, .vtk or .xdmf output); normals nx, ny, nz are recomputed.
        PLY point cloud input: the points are moved, none removed or reordered,
        and each keeps its colour (red, green, blue)."""
        import sys

        import numpy as np
        from tqdm import tqdm

        from physar.geometry.denoise import MAX_ITERATIONS, METHODS, check_cloud_extent, denoise
        from physar.geometry.pointcloud import denoise_points
        from physar.output import check_destination

        out = output_path(out_opt, out_arg, "physar denoise IN --out OUT")
        if method is None:  # two-stage for surfaces, msal for point clouds (the only ones they take)
            from physar.geometry.pointcloud import read_ply

            cloud_in = inp.suffix.lower() == ".ply" and inp.is_file() and _is_cloud(inp, read_ply)
            method = "msal" if cloud_in else "two-stage"
        if method not in METHODS:
            raise PhysarError(f"unknown denoising method {method!r}; choose one of {sorted(METHODS)}")
        if iterations is not None and not 1 <= iterations <= MAX_ITERATIONS:
            raise PhysarError(f"--iterations must be within 1..{MAX_ITERATIONS}, got {iterations}")
        params = _method_params(method, kappa=kappa, xi=xi, fidelity=fidelity, tau=tau, rescale=rescale,
                                sigma_r=sigma_r)
        _check_out(out, inp, cloud=False, reference=reference)
        png = None if no_render else (render or out.with_suffix(".png"))
        if png is not None:
            from physar.output import png_by_physar

            # the default picture (OUT.png, not named by the user) never replaces a picture physar did not draw
            check_destination(png, inputs=[inp, out, reference], suffixes=[".png"],
                              kind="picture (--render PATH or --no-render to choose)",
                              replaces=None if render else png_by_physar)
        mesh, pts = _load(inp)
        if mesh is not None:
            if k is not None:  # silently unused before
                raise PhysarError(f"--k {k}: neighbours of a point cloud; {inp} is a surface mesh, whose "
                                  "neighbours are its edges (drop --k)")
            n_file = mesh.n_points
            mesh, src = _split(mesh, inp)
        k = 10 if k is None else k
        ref = None
        if reference is not None:
            if mesh is None:
                raise PhysarError(f"{inp}: --reference needs a surface mesh (faces), got a point cloud")
            ref, _ = _load(reference, role="reference")
            if ref is not None:
                ref, _ = _split(ref, reference)
            if ref is None or ref.faces.shape != mesh.faces.shape or not np.array_equal(ref.faces, mesh.faces):
                raise PhysarError(f"{reference}: --reference must have the same faces as {inp} (the clean copy "
                                  f"of the noisy mesh)")
        if mesh is None:
            _check_out(out, inp, cloud=True, reference=reference)
            if method not in ("al", "msal"):
                raise PhysarError(f"{inp}: point clouds support --method al or msal, got {method!r}")
            if k < 1:
                raise PhysarError(f"--k must be >= 1 (neighbours per point), got {k}")
            if {"rescale", "sigma_r", "lam"} & set(params):
                raise PhysarError(f"{inp}: point clouds take --kappa and --tau (al) or --kappa, --xi and "
                                  f"--fidelity (msal)")
            check_cloud_extent(pts, str(inp))
            rgb = _cloud_colours(inp, len(pts))  # the denoiser moves points in place: same order, same count
        bar = tqdm(desc=f"{method} iterations", file=sys.stderr, disable=None if not json_out else True)
        prog = lambda i, q: bar.update(1)
        try:
            if mesh is not None:
                res = denoise(mesh, method, iterations, progress=prog, **params)
                moved = np.linalg.norm(res.points - mesh.points, axis=1)
                _save(out, res, None, _output_fields(_fields(inp, n_file, src), mesh, res, out))
                n = mesh.n_points
            else:
                q = denoise_points(pts, method, iterations, k=k, progress=prog, **params)
                moved = np.linalg.norm(q - pts, axis=1)
                _save(out, None, q, colors=rgb)
                n = len(pts)
        finally:
            bar.close()
        summary = {"input": str(inp), "output": str(out), "method": method, "parameters": params, "points": n,
                   "mean_displacement_m": float(moved.mean()), "max_displacement_m": float(moved.max())}
        if ref is not None:
            summary["reference"] = {"path": str(reference), **reference_errors(mesh, res, ref)}
        if png is not None and mesh is not None:
            render_before_after(mesh, res, png, title=f"{inp.name}: {method}")
            summary["picture"] = str(png)
        if json_out:
            print_json(summary)
            warn_positional(out_arg, out_opt, "denoise")
            return
        log(f"wrote {out}: {n} points, mean displacement {moved.mean():.3g} m")
        if mesh is not None and iterations is None and not moved.max() > 0:
            log("the input came back unchanged: no filtering is estimated to beat it (a clean or nearly noise-free "
                "mesh); --iterations N forces N filter iterations")
        if ref is not None:
            r = summary["reference"]
            log(f"against {reference}: mean face-normal error {r['normal_error_deg_before']:.2f} -> "
                f"{r['normal_error_deg']:.2f} deg, mean vertex distance {r['mean_distance_m_before']:.3g} -> "
                f"{r['mean_distance_m']:.3g} m ({r['mean_distance_edge']:.3f} mean edge lengths), volume change "
                f"{100 * r['volume_change_before']:+.2f} -> {100 * r['volume_change']:+.2f} %")
        if "picture" in summary:
            log(f"wrote {png} (before / after)")
        warn_positional(out_arg, out_opt, "denoise")

    @app.command("noise")
    @user_errors
    def noise_cmd(
        inp: Annotated[Path, typer.Argument(help="input surface mesh (a volume mesh file: its whole boundary surface)")],
        out_arg: Annotated[Path | None, typer.Argument(metavar="OUT", show_default=False,
                                                       help="output surface mesh " + DEPRECATED)] = None,
        out_opt: Annotated[Path | None, typer.Option("--out", "-o", show_default=False,
                                                     help="output surface mesh (PLY/OBJ/STL/OFF)")] = None,
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

        Surface PLY input: per-vertex colours and other properties are kept,
        normals recomputed (as in `denoise`).
        """
        from physar.geometry.quality import add_noise, mean_edge_length

        out = output_path(out_opt, out_arg, "physar noise IN --out OUT")
        if seed < 0:
            raise PhysarError(f"--seed must be an integer >= 0, got {seed}")
        _check_out(out, inp, cloud=False)
        mesh, _ = _load(inp)
        if mesh is None:
            raise PhysarError(f"{inp}: `noise` needs a surface mesh (faces), got a point cloud")
        n_file = mesh.n_points
        mesh, src = _split(mesh, inp)
        noisy = add_noise(mesh, sigma, seed, direction)
        _save(out, noisy, None, _output_fields(_fields(inp, n_file, src), mesh, noisy, out))
        summary = {"input": str(inp), "output": str(out), "sigma_m": sigma * mean_edge_length(mesh),
                   "seed": seed, "direction": direction}
        if json_out:
            print_json(summary)
        else:
            log(f"wrote {out} (noise std {summary['sigma_m']:.3g} m)")
        warn_positional(out_arg, out_opt, "noise")
