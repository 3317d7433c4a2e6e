"""`physar synth render|score`: synthetic test clips of any AR project, with truth from a finer mesh, and the
accuracy of `physar ar run` against them."""
from __future__ import annotations

from pathlib import Path

import typer

from physar.cli._common import log, print_json, user_errors

OUTPUTS = ("video.mp4", "truth.csv", "camera.toml", "scenario.json")


@user_errors
def render(
    project: Path = typer.Argument(..., help="AR project file (project.toml)"),  # noqa: B008 - typer idiom
    out: Path = typer.Option(..., "--out", "-o", help="folder for video.mp4, truth.csv, camera.toml, scenario.json"),  # noqa: B008
    scenario: Path = typer.Option(None, "--scenario", "-s", help="scenario TOML (default: every key's default)"),  # noqa: B008
    quick: bool = typer.Option(False, "--quick", help="half size, at most 2 s"),
    json_out: bool = typer.Option(False, "--json", help="print the summary as JSON"),
) -> None:
    """Render a synthetic handheld video of PROJECT's object (truth from a finer mesh) into --out."""
    from physar.ar.project import load_project
    from physar.cli.ar import _bar as bar
    from physar.errors import ConfigError
    from physar.output import check_destination
    from physar.synth import Scenario, load_scenario, render_project

    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: --out must be a folder, and this is a file")
    if out.is_dir() and any(out.iterdir()) and not (out / "scenario.json").is_file():
        raise ConfigError(f"{out}: folder is not empty and holds no previous clip (scenario.json); choose another "
                          "--out (nothing there is overwritten)")
    for name in OUTPUTS:
        check_destination(out / name, inputs=[project, scenario], kind=name)
    proj = load_project(project, progress=bar("model"))
    sc = load_scenario(scenario, proj) if scenario is not None else Scenario()
    existed = out.is_dir()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ConfigError(f"{out}: cannot create the output folder ({e.strerror})") from None
    try:
        info = render_project(proj, sc, out, progress=bar("render"), quick=quick)
    except BaseException:
        if not existed and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # the empty folder this command created; the outputs' temporaries are already gone
        raise
    if json_out:
        print_json(info)
    else:
        log(f"{info['frames']} frames {info['width']}x{info['height']} at {info['fps']:g} fps, truth on "
            f"{info['truth_dofs']} dofs ({info['truth_solves']} solves); wrote {out}/")


@user_errors
def score(
    truth: Path = typer.Argument(..., help="truth.csv of a synthetic clip"),  # noqa: B008 - typer idiom
    estimates: Path = typer.Argument(..., help="estimates CSV of `physar ar run`"),  # noqa: B008 - typer idiom
    project: Path = typer.Option(None, "--project", "-p", help="project file: tolerances from the model's ranges"),  # noqa: B008
    tol: float = typer.Option(0.01, help="tolerance as a fraction of each parameter's range"),
    json_out: bool = typer.Option(False, "--json", help="print the scores as JSON"),
) -> None:
    """Errors of an AR run against a synthetic clip's truth (judged frames: no occluder in view)."""
    import math

    from physar.errors import ConfigError
    from physar.synth.score import read_columns
    from physar.synth.score import score as _score

    if not (math.isfinite(tol) and 0 < tol < 1):
        raise ConfigError(f"--tol must be in (0, 1), got {tol}")
    ranges = None
    if project is not None:
        from physar.ar.project import load_project

        rom = load_project(project, build=False).rom
        ranges = {n: tuple(map(float, r)) for n, r in zip(rom.names, rom.ranges)}
    res = _score(read_columns(truth, "truth file"), read_columns(estimates, "estimates file"), ranges, tol,
                 source=str(estimates))
    if json_out:
        print_json(res)
        return
    for n, p in res["parameters"].items():
        typer.echo(f"{n}: {p['within']}/{p['judged']} judged frames within {p['tolerance']:.4g} "
                   f"(max {p['max_error']:.4g} at frame {p['worst_frame']}, mean {p['mean_error']:.4g})")


def register(app: typer.Typer) -> None:
    sub = typer.Typer(help="Synthetic test clips of any AR project, and scores against their truth.",
                      no_args_is_help=True)
    sub.command("render")(render)
    sub.command("score")(score)
    app.add_typer(sub, name="synth")
