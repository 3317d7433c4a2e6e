"""`physar demo`: the project's main example (the AR pipeline on scene (a); `--scene foam`: scene (b), the foam
beam without fiducials; `--scene seal`: scene (c), the virtual boot seal; `--scene cantilever`: the static FEM
cantilever)."""

from __future__ import annotations

from pathlib import Path

import typer

from physar.cli._common import log, print_json, user_errors

# Every file a demo writes (the scenes' report["files"]): the output folder may hold these and nothing else,
# so that a demo never mixes its outputs with, or overwrites, a user's files.
DEMO_FILES = frozenset({"scene.mp4", "truth.csv", "camera.toml", "model.npz", "model_von_mises.npz", "plate.png",
                        "plate.json", "augmented.mp4", "estimates.csv", "estimate_vs_truth.png",
                        "augmented_frame.png", "report.json", "cantilever.vtu", "cantilever.png"})


def demo(
    out: Path = typer.Option(Path("demo_out"), "--out", "-o", help="output folder"),  # noqa: B008 - typer idiom
    scene: str = typer.Option("ar", "--scene", help="ar (augmented-reality cantilever, default), foam (seed §5.2: "
                                                    "foam beam, no fiducials), seal (seed §5.3: virtual boot seal) "
                                                    "or cantilever (static FEM example)"),
    quick: bool = typer.Option(False, "--quick", help="AR demos at 640x360 with coarser meshes (a fast check)"),
    json_out: bool = typer.Option(False, "--json", help="print the report as JSON on stdout"),
) -> None:
    """Run the demo: video of a loaded beam in, augmented video + estimates + report out."""
    from physar.errors import ConfigError
    from physar.output import check_folder

    if scene not in ("ar", "foam", "seal", "cantilever"):
        raise ConfigError(f"--scene must be ar, foam, seal or cantilever, got {scene!r}")
    check_folder(out, own=lambda name: name in DEMO_FILES, kind="demo output folder")
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
    from tqdm import tqdm

    from physar.ar.demo import run_ar_demo

    bars = {}

    def progress(stage, k, n):  # bars on a terminal only (disable=None), always closed
        if stage not in bars:
            bars[stage] = tqdm(total=n or None, desc=stage, leave=True, file=__import__("sys").stderr, disable=None)
        bars[stage].update(k - bars[stage].n)

    try:
        if scene == "foam":
            from physar.ar.foam import run_foam_demo

            report = run_foam_demo(out, quick=quick, progress=progress)
        elif scene == "seal":
            from physar.ar.seal import run_seal_demo

            report = run_seal_demo(out, quick=quick, progress=progress)
        else:
            report = run_ar_demo(out, quick=quick, progress=progress)
    finally:
        for b in bars.values():
            b.close()
    if json_out:
        print_json(report)
        return
    if scene == "foam":
        log(f"{report['frames']} frames at {report['fps']:.1f} fps (median latency {report['latency_ms_median']:.1f} "
            f"ms); disk position error {report['mean_abs_error_mm']:.2f} mm mean, {report['max_abs_error_mm']:.2f} mm "
            f"max; markers in {report['scene']['frames_with_markers']} frame(s)")
        log("modes  mean |error| [mm]  max |error| [mm]")
        for row in report["accuracy_vs_modes"]:
            log(f"{row['modes']:5d}  {row['mean_abs_error_mm']:17.2f}  {row['max_abs_error_mm']:16.2f}")
        log(f"wrote {', '.join(str(out / f) for f in report['files'])}")
        return
    if scene == "seal":
        log(f"{report['frames']} frames at {report['fps']:.1f} fps (median latency {report['latency_ms_median']:.1f} "
            f"ms); lever angle error {report['median_abs_error_deg']:.2f} deg median, "
            f"{report['mean_abs_error_deg']:.2f} deg mean; recovery after looking away: "
            f"{report['recovery_frames_after_look_away']} frame(s)")
        log(f"wrote {', '.join(str(out / f) for f in report['files'])}")
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
