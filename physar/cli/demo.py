"""`physar demo`: the seed's scenes end to end on synthetic video: each is a project folder under
`examples/ar/` (the cantilever `ar`, the default; `foam`, the foam beam without fiducials; `seal`, the virtual
boot seal; `bracket`, an L-bracket from an STL surface) rendered by the test-data renderer and run by the one
AR pipeline (`physar.synth.demo`); `--project` runs any other project folder the same way; `--scene
cantilever` is the static FEM cantilever."""

from __future__ import annotations

from pathlib import Path

import typer

from physar.cli._common import log, print_json, user_errors

# Every file a demo writes: the output folder may hold these and nothing else, so that a demo never mixes its
# outputs with, or overwrites, a user's files.
FEM_FILES = frozenset({"cantilever.vtu", "cantilever.png", "report.json"})


def _demo_files() -> frozenset:
    from physar.synth.demo import FILES

    return frozenset(FILES) | FEM_FILES


def demo(
    out: Path = typer.Option(Path("demo_out"), "--out", "-o", help="output folder"),  # noqa: B008 - typer idiom
    scene: str | None = typer.Option(None, "--scene", help="ar (augmented-reality cantilever, default), foam (seed §5.2: "
                                                    "foam beam, no fiducials), seal (seed §5.3: virtual boot seal), "
                                                    "bracket (an L-bracket from an STL surface) or cantilever "
                                                    "(static FEM example)"),
    project: Path | None = typer.Option(None, "--project", help="run this AR project file instead of a scene "  # noqa: B008
                                                                "(its scenario.toml beside it, or --scenario)"),
    scenario: Path | None = typer.Option(None, "--scenario", help="scenario TOML of the synthetic clip"),  # noqa: B008
    quick: bool = typer.Option(False, "--quick", help="half-size clip of at most 2 s (a fast check)"),
    json_out: bool = typer.Option(False, "--json", help="print the report as JSON on stdout"),
) -> None:
    """Run a demo: a synthetic video of a seed scene in, augmented video + estimates + report out.

    Every input is checked before the work starts; the outputs are written into a hidden folder beside --out
    that takes its place only when the demo is complete (Ctrl-C, SIGTERM or an error leave --out as it was:
    exit 130 on a signal)."""
    from physar.cli._common import check_toml, created_parents, whole_folder
    from physar.errors import ConfigError
    from physar.output import atomic_folder, check_folder
    from physar.synth.demo import SCENES

    if project is not None and scene is not None:
        raise ConfigError(f"give --scene or --project, not both (--scene {scene} --project {project})")
    scene = scene if scene is not None else "ar"
    if project is None and scene not in (*SCENES, "cantilever"):
        raise ConfigError(f"--scene must be one of {', '.join(sorted({*SCENES, 'cantilever'}))}, got {scene!r}")
    fem = project is None and scene == "cantilever"
    if fem and scenario is not None:
        raise ConfigError(f"--scenario {scenario}: --scene cantilever is the static FEM example, it renders no clip "
                          "(a scenario applies to the AR scenes and to --project)")
    check_toml(project, "project file")
    check_toml(scenario, "scenario file")
    files = _demo_files()

    def own(name):
        return name in files

    dest = whole_folder(out, "a new folder such as demo_out/")
    check_folder(out, own=own, inputs=[project, scenario], kind="demo output folder")
    if fem:
        from physar.fem.examples import run_cantilever_demo

        with created_parents(dest, "demo output folder"), atomic_folder(dest, own=own) as tmp:
            report = run_cantilever_demo(tmp)
        if json_out:
            print_json(report)
        else:
            log(f"cantilever tip deflection {report['tip_deflection_m'] * 1e3:.4f} mm, Timoshenko "
                f"{report['timoshenko_m'] * 1e3:.4f} mm (relative difference {report['relative_error']:.2%})")
            log(f"wrote {', '.join(str(out / f) for f in report['files'])}")
        return
    from tqdm import tqdm

    from physar.synth.demo import run_project_demo, scene_project

    bars = {}

    def progress(stage, k, n):  # bars on a terminal only (disable=None), always closed
        if stage not in bars:
            bars[stage] = tqdm(total=n or None, desc=stage, leave=True, file=__import__("sys").stderr, disable=None)
        bars[stage].update(k - bars[stage].n)

    path = project if project is not None else scene_project(scene)
    try:
        with created_parents(dest, "demo output folder"), atomic_folder(dest, own=own) as tmp:
            report = run_project_demo(path, tmp, scenario, quick=quick, progress=progress)
    except KeyboardInterrupt:
        for b in bars.values():
            b.close()
        log(f"interrupted: nothing written ({out} is as it was)")
        raise typer.Exit(code=130) from None
    finally:
        for b in bars.values():
            b.close()
    if json_out:
        print_json(report)
        return
    log(f"{report['frames']} frames at {report['fps']:.1f} fps (median latency {report['latency_ms_median']:.1f} ms)")
    units = {p["name"]: p["unit"] for p in report["parameters"]}
    for name, sc in report["score"]["parameters"].items():
        u = units.get(name, "")
        k = 1e3 if u == "m" else 1.0
        un = "mm" if u == "m" else u
        log(f"{name}: {sc['within']}/{sc['judged']} judged frames within 1 % of its range; |error| mean "
            f"{sc['mean_error'] * k:.3g} {un}, median {sc['median_error'] * k:.3g} {un}, max {sc['max_error'] * k:.3g} "
            f"{un}; recovery {sc['recovery_frames']} frame(s)")
        rows = report["table"].get(name) or []
        if rows:
            log(f"  actual [{un}]  mean estimate [{un}]  |difference| [{un}]")
            for r in rows:
                log(f"  {r['actual'] * k:10.2f}  {r['mean_estimate'] * k:17.2f}  {r['abs_difference'] * k:16.2f}")
    log(f"wrote {', '.join(str(out / f) for f in report['files'])}")


def register(app: typer.Typer) -> None:
    app.command("demo")(user_errors(demo))
