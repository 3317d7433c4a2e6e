"""`physar demo`: the project's main example (the AR pipeline on scene (a); `--scene cantilever`: the static
FEM cantilever)."""

from __future__ import annotations

from pathlib import Path

import typer

from physar.cli._common import log, print_json, user_errors


def demo(
    out: Path = typer.Option(Path("demo_out"), "--out", "-o", help="output folder"),
    scene: str = typer.Option("ar", "--scene", help="ar (augmented-reality cantilever, default) or cantilever "
                                                    "(static FEM example)"),
    quick: bool = typer.Option(False, "--quick", help="AR demo at 640x360, 6.5 s (for a fast check)"),
    json_out: bool = typer.Option(False, "--json", help="print the report as JSON on stdout"),
) -> None:
    """Run the demo: video of a loaded beam in, augmented video + estimates + report out."""
    from physar.errors import ConfigError

    if scene == "cantilever":
        from physar.fem.examples import run_cantilever_demo

        report = run_cantilever_demo(out)
        if json_out:
            print_json(report)
        else:
            log(f"cantilever tip deflection {report['tip_deflection_m'] * 1e3:.4f} mm, Timoshenko "
                f"{report['timoshenko_m'] * 1e3:.4f} mm (relative difference {report['relative_error']:.2%})")
            log(f"wrote {', '.join(str(out / f) for f in report['files'])}")
        return
    if scene != "ar":
        raise ConfigError(f"--scene must be ar or cantilever, got {scene!r}")
    from tqdm import tqdm

    from physar.ar.demo import run_ar_demo

    bars = {}

    def progress(stage, k, n):
        if stage not in bars:
            bars[stage] = tqdm(total=n or None, desc=stage, leave=True, file=__import__("sys").stderr)
        bars[stage].update(k - bars[stage].n)

    report = run_ar_demo(out, quick=quick, progress=progress)
    for b in bars.values():
        b.close()
    if json_out:
        print_json(report)
        return
    log(f"{report['frames']} frames at {report['fps']:.1f} fps (median latency {report['latency_ms_median']:.1f} ms); "
        f"load position error {report['mean_abs_error_mm']:.2f} mm mean, {report['max_abs_error_mm']:.2f} mm max "
        f"(beyond 20 % of the span from the clamp)")
    log("actual [mm]  mean estimate [mm]  |difference| [mm]")
    for row in report["table"]:
        log(f"{row['actual_mm']:10.1f}  {row['mean_estimate_mm']:18.2f}  {row['abs_difference_mm']:17.2f}")
    log(f"wrote {', '.join(str(out / f) for f in report['files'])}")


def register(app: typer.Typer) -> None:
    app.command("demo")(user_errors(demo))
