"""`physar fem …`: static finite-element solves from a TOML problem file."""

from __future__ import annotations

from pathlib import Path

import typer

from physar.cli._common import log, print_json, user_errors

_OUT_HELP = ("result mesh (.vtu/.xdmf): displacement and von Mises at the vertices (stress recovered there), "
             "von Mises of each element's mean stress per element")

fem_app = typer.Typer(help="Finite-element statics.", no_args_is_help=True)


@fem_app.command("solve")
@user_errors
def solve(
    config: Path = typer.Argument(..., help="problem file (TOML), see README"),  # noqa: B008 - typer idiom
    out: Path = typer.Option(..., "--out", "-o", help=_OUT_HELP),  # noqa: B008 - typer idiom
    json_out: bool = typer.Option(False, "--json", help="print results as JSON on stdout"),
) -> None:
    """Solve a static problem and write the deformed fields."""
    from tqdm import tqdm

    from physar.cli._common import check_toml
    from physar.fem.config import load_config, run_config
    from physar.geometry import write_mesh
    from physar.geometry.io import check_mesh_destination

    check_toml(config, "problem file")
    mesh_file = load_config(config).mesh.file  # the result never replaces the input mesh (or a link to it)
    check_mesh_destination(out, inputs=[config] + ([config.parent / mesh_file] if mesh_file else []),
                           kind="result mesh")
    bar = None

    def progress(step: int, steps: int) -> None:
        nonlocal bar
        if steps > 1:  # a bar on a terminal only (disable=None), always closed
            bar = bar or tqdm(total=steps, desc="load steps", file=__import__("sys").stderr, disable=None)
            bar.update(1)

    try:
        result = run_config(config, progress)
        write_mesh(out, result.problem.space.mesh, point_data=result.point_data(),
                   cell_data={"von_mises": result.von_mises})
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM (meshing, assembly, solve or the write: atomic, so no file)
        if bar is not None:
            bar.close()
            bar = None
        log(f"interrupted: nothing written ({out} is as it was)")
        raise typer.Exit(code=130) from None
    finally:
        if bar is not None:
            bar.close()
    summary = result.summary()
    summary["output"] = str(out)
    if json_out:
        print_json(summary)
    else:
        log(f"wrote {out}")
        at = ", ".join(f"{v:.4g}" for v in summary["max_von_mises_point"])
        log(f"max displacement {summary['max_displacement']:.6e} m, "
            f"max von Mises {summary['max_von_mises']:.4e} Pa at the vertex [{at}] (element means: "
            f"{summary['max_von_mises_element_mean']:.4e} Pa), Newton iterations {summary['newton_iterations']}")
        for p in summary["probes"]:
            log(f"probe {p['point']}: u = {p['u']}")


def register(app: typer.Typer) -> None:
    app.add_typer(fem_app, name="fem")
