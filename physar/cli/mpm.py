"""`physar mpm …`: differentiable MLS-MPM runs from a scene TOML, and material identification (seed 002)."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from physar.cli._common import log, print_json, user_errors

mpm_app = typer.Typer(help="Material Point Method simulation and identification.", no_args_is_help=True)


@mpm_app.command("run")
@user_errors
def run(
    scene: Path = typer.Argument(..., help="scene file (TOML): \\[grid] \\[time] \\[gravity] \\[boundary] \\[\\[body]]"),  # noqa: B008 - typer idiom
    out: Path = typer.Option(..., "--out", "-o", help="folder for frame_NNNN.ply, diagnostics.csv, preview.mp4"),  # noqa: B008 - typer idiom
    json_out: bool = typer.Option(False, "--json", help="print per-frame time, COM, momentum, kinetic energy"),
    no_preview: bool = typer.Option(False, "--no-preview", help="skip the MP4 preview"),
) -> None:
    """Simulate a scene and write per-frame particles, diagnostics and a preview video.

    The folder is written whole: it appears (or replaces a previous run's) only once complete. Ctrl-C or
    SIGTERM stops after the current frame: diagnostics.csv and the preview cover the frames written (exit 130);
    so does a run that diverges (exit 2, the error names the frames written)."""
    from tqdm import tqdm

    from physar.cli._common import check_toml, created_parents, whole_folder
    from physar.mpm.runner import check_run_folder, run_scene
    from physar.output import signal_guard

    check_toml(scene, "scene file")
    whole_folder(out, "a new folder such as run/")
    check_run_folder(out, inputs=[scene])
    bar = None

    def progress(frame: int, frames: int) -> None:
        nonlocal bar
        bar = bar or tqdm(total=frames, desc="frames", file=sys.stderr, disable=True if json_out else None)
        bar.update(1)

    try:
        with created_parents(out), signal_guard() as guard:  # parents made here go again on an error
            res = run_scene(scene, out, progress, preview=not no_preview, stop=lambda: guard.stopped)
    finally:
        if bar is not None:
            bar.close()
    if json_out:
        print_json(res.summary())
    else:
        d0, d1 = res.diagnostics[0], res.diagnostics[-1]
        log(("interrupted: " if res.interrupted else "") + f"{res.n_particles} particles, {res.frames} frames -> "
            f"{out}" + ("" if res.preview or no_preview else " (no MP4 encoder: preview skipped)"))
        log(f"centre of mass {d0['com'].round(4).tolist()} -> {d1['com'].round(4).tolist()} m; "
            f"total energy {d0['total_energy']:.4e} -> {d1['total_energy']:.4e} J")
    if res.interrupted:
        raise typer.Exit(code=130)


@mpm_app.command("identify")
@user_errors
def identify(
    scene: Path = typer.Argument(..., help="scene file (TOML); its E values are the initial guesses"),  # noqa: B008 - typer idiom
    target: Path = typer.Option(..., "--target", "-t", help="folder of frame_NNNN.ply (from `physar mpm run`)"),  # noqa: B008 - typer idiom
    iterations: int = typer.Option(20, "--iterations", help="L-BFGS iterations (>= 1)"),
    fit_nu: bool = typer.Option(False, "--fit-nu", help="also fit Poisson's ratio per body"),
    json_out: bool = typer.Option(False, "--json", help="print the identified parameters as JSON"),
) -> None:
    """Recover per-body Young's moduli (and nu) from a target particle trajectory."""
    from physar.cli._common import check_input, check_toml
    from physar.errors import ConfigError
    from physar.mpm.runner import identify_scene

    if iterations < 1:
        raise ConfigError(f"--iterations must be >= 1, got {iterations}")
    check_toml(scene, "scene file")
    check_input(target, "--target folder of frame_NNNN.ply", folder=True)

    def progress(evaluation: int, loss: float) -> None:
        if not json_out:
            log(f"evaluation {evaluation}: loss {loss:.6e}")

    res = identify_scene(scene, target, iterations=iterations, fit_nu=fit_nu, progress=progress)
    if json_out:
        print_json(res)
    else:
        for b, (e0, e, nu) in enumerate(zip(res["E_initial"], res["E"], res["nu"])):
            log(f"body {b}: E = {e:.6g} Pa (initial {e0:.6g}), nu = {nu:.4g}")
        log(f"final loss {res['loss']:.4e} after {res['evaluations']} evaluations")


def register(app: typer.Typer) -> None:
    app.add_typer(mpm_app, name="mpm")
