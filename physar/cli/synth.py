"""`physar synth render|score`: synthetic test clips of any AR project, with truth from a finer mesh, and the
accuracy of `physar ar run` against them."""
from __future__ import annotations

from pathlib import Path

import typer

from physar.cli._common import log, print_json, user_errors

OUTPUTS = ("video.mp4", "truth.csv", "camera.toml", "scenario.json")
OUT_HELP = ("folder for video.mp4, truth.csv, camera.toml, scenario.json (new, empty, or a previous clip: replaced "
            "when the new one is complete)")


def _own(name: str) -> bool:
    return name in OUTPUTS


def _check_clip_folder(out: Path, inputs) -> None:
    """--out before any work: a folder (new, empty, or a previous clip of this command and nothing else), each
    output file writable there and none of them an input (one line naming the path)."""
    from physar.errors import ConfigError
    from physar.output import check_destination, check_folder

    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: --out must be a folder, and this is a file")
    if out.is_dir():
        foreign = sorted(e.name for e in out.iterdir() if not _own(e.name))
        if foreign:
            more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
            what = ("holds a previous clip and files this command did not write" if (out / "scenario.json").exists()
                    else "holds no previous clip (scenario.json) but files this command did not write")
            raise ConfigError(f"{out}: folder {what} ({foreign[0]}{more}); choose another --out (nothing there is "
                              "touched)")
    check_folder(out, own=_own, inputs=inputs, kind="output folder")
    for name in OUTPUTS:
        check_destination(out / name, inputs=inputs, kind=name)


def _moved(info: dict, tmp: Path, out: Path) -> dict:
    """The summary's paths inside the temporary folder, as they are once it took the place of --out."""
    return {k: str(out / Path(v).name) if isinstance(v, str) and Path(v).parent == tmp else v
            for k, v in info.items()}


@user_errors
def render(
    project: Path = typer.Argument(..., help="AR project file (project.toml)"),  # noqa: B008 - typer idiom
    out: Path = typer.Option(..., "--out", "-o", help=OUT_HELP),  # noqa: B008 - typer idiom
    scenario: Path = typer.Option(None, "--scenario", "-s", help="scenario TOML (default: every key's default)"),  # noqa: B008
    quick: bool = typer.Option(False, "--quick", help="half size, at most 2 s"),
    json_out: bool = typer.Option(False, "--json", help="print the summary as JSON"),
) -> None:
    """Render a synthetic handheld video of PROJECT's object (truth from a finer mesh) into --out.

    Every input is checked before the first frame; the clip is written into a hidden folder beside --out that
    takes its place only when complete (Ctrl-C or an error leave --out as it was; exit 130 on a signal)."""
    from physar.ar.project import load_project
    from physar.cli._common import check_toml, created_parents, whole_folder
    from physar.cli.ar import _bar as bar
    from physar.output import atomic_folder
    from physar.synth import Scenario, load_scenario, render_project
    from physar.synth.scenario import resolve

    check_toml(project, "project file")
    check_toml(scenario, "scenario file")
    dest = whole_folder(out, "a new folder such as clip/")
    _check_clip_folder(out, [project, scenario])
    proj = load_project(project, progress=bar("model"))
    sc = load_scenario(scenario, proj) if scenario is not None else Scenario()
    res = resolve(sc, proj, quick=quick, source=str(scenario) if scenario is not None else
                  f"{project} (the default scenario)")
    try:
        with created_parents(dest), atomic_folder(dest, own=_own) as tmp:
            info = _moved(render_project(proj, res, tmp, progress=bar("render"), quick=quick), tmp, out)
    except KeyboardInterrupt:
        log(f"interrupted: nothing written ({out} is as it was)")
        raise typer.Exit(code=130) from None
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
        from physar.cli._common import check_toml

        check_toml(project, "project file")
        rom = load_project(project, build=False).rom
        ranges = {n: tuple(map(float, r)) for n, r in zip(rom.names, rom.ranges)}
    res = _score(read_columns(truth, "truth file"), read_columns(estimates, "estimates file"), ranges, tol,
                 source=str(estimates), truth_source=str(truth))
    if res["truth_frames"] != res["estimate_frames"]:
        import warnings

        from physar.errors import PhysarWarning

        warnings.warn(PhysarWarning(
            f"{estimates}: {res['estimate_frames']} frames, {truth}: {res['truth_frames']}: only the first "
            f"{res['frames']} are scored (a run stopped early, --max-frames, or another clip)"), stacklevel=1)
    if json_out:
        print_json(res)
        return
    for n, p in res["parameters"].items():
        if p["tolerance"] is None:
            typer.echo(f"{n}: not judged: its truth is constant ({p['constant']:.4g}), which gives no range for the "
                       "tolerance; give --project")
            continue
        typer.echo(f"{n}: {p['within']}/{p['judged']} judged frames within {p['tolerance']:.4g} "
                   f"(max {p['max_error']:.4g} at frame {p['worst_frame']}, mean {p['mean_error']:.4g})")


def register(app: typer.Typer) -> None:
    sub = typer.Typer(help="Synthetic test clips of any AR project, and scores against their truth.",
                      no_args_is_help=True)
    sub.command("render")(render)
    sub.command("score")(score)
    app.add_typer(sub, name="synth")
