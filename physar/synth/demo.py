"""A project end to end on synthetic data, as `physar demo` runs the seed's scenes (seed 000 §5): the test-data
renderer draws the project's scenario (:func:`physar.synth.render.render_project`: the object deformed by a
finer model, truth.csv), the one AR pipeline (:class:`physar.ar.project_pipeline.ProjectPipeline`) runs on the
clip exactly as on a user's video, and the estimates are scored against the truth
(:func:`physar.synth.score.score`), tabulated and plotted (:mod:`physar.ar.report`).

The seed's scenes are project folders under ``examples/ar/<name>/`` (``project.toml``, ``rom.toml``,
``scenario.toml``); any other project folder with a scenario runs the same way.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from physar.errors import ConfigError
from physar.output import write_json

EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "ar"
SCENES = {"ar": "cantilever", "cantilever": "cantilever", "foam": "foam", "seal": "seal", "bracket": "bracket"}
#: every file a project demo writes into its output folder
FILES = ("video.mp4", "truth.csv", "camera.toml", "scenario.json", "augmented.mp4", "estimates.csv",
         "estimate_vs_truth.png", "augmented_frame.png", "report.json")


def scene_project(scene: str) -> Path:
    """The project file of a seed scene (``ar`` is the cantilever)."""
    if scene not in SCENES:
        raise ConfigError(f"unknown scene {scene!r} (scenes: {', '.join(sorted(SCENES))})")
    p = EXAMPLES / SCENES[scene] / "project.toml"
    if not p.is_file():
        raise ConfigError(f"{p}: the example project is missing (run from a physar source checkout)")
    return p


def run_project_demo(project_path, out, scenario_path=None, quick: bool = False,
                     progress: Callable[[str, int, int], None] | None = None, tol: float = 0.01) -> dict:
    """Render, run, score; writes :data:`FILES` into ``out`` and returns the report (also report.json).
    ``scenario_path``: default ``scenario.toml`` beside the project (else the scenario's defaults). A signal
    that stops the AR pipeline early raises KeyboardInterrupt (a partial run is not scored as a demo)."""
    from physar.ar.project import load_project
    from physar.ar.project_pipeline import ProjectPipeline
    from physar.ar.report import dwell_table, plot_estimates
    from physar.ar.runner import pipeline_stats
    from physar.synth.render import render_project
    from physar.synth.scenario import Scenario, load_scenario, resolve
    from physar.synth.score import read_columns, score

    project_path, out = Path(project_path), Path(out)
    cb = (lambda stage: (lambda k, n: progress(stage, k, n))) if progress else (lambda stage: None)
    t0 = time.perf_counter()
    project = load_project(project_path, progress=cb("reduced model"))
    t1 = time.perf_counter()
    if scenario_path is None and (project_path.parent / "scenario.toml").is_file():
        scenario_path = project_path.parent / "scenario.toml"
    scenario = load_scenario(scenario_path, project) if scenario_path is not None else Scenario()
    resolved = resolve(scenario, project, quick=quick, source=str(scenario_path) if scenario_path is not None else
                       f"{project_path} (the default scenario)")
    info = render_project(project, resolved, out, progress=cb("render scene"), quick=quick)
    t2 = time.perf_counter()
    from physar.vision.camera import Camera

    project.camera = Camera.load(out / "camera.toml")   # the clip's camera (quick clips are smaller)
    pipe = ProjectPipeline(project)
    n = int(info.get("frames", 0)) or None
    snap = {max(0, int(0.6 * (n or 1))): out / "augmented_frame.png"}
    summary = pipe.run(out / "video.mp4", out / "augmented.mp4", out / "estimates.csv", progress=cb("AR pipeline"),
                       snapshots=snap)
    if summary.get("interrupted"):  # the pipeline stopped early on a signal: no partial demo is scored or kept
        raise KeyboardInterrupt(summary.get("signal", "interrupted"))
    t3 = time.perf_counter()
    truth, est = read_columns(out / "truth.csv"), read_columns(out / "estimates.csv")
    names, units = list(project.rom.names), list(project.rom.units)
    ranges = {nm: tuple(map(float, r)) for nm, r in zip(names, project.rom.ranges)}
    sc = score(truth, est, ranges, tol=tol)
    title = f"{project.config.name or project_path.parent.name}: estimates vs truth"
    plot_estimates(truth, est, names, units, out / "estimate_vs_truth.png", title, tol, ranges)
    report = {"project": str(project_path), "scenario": None if scenario_path is None else str(scenario_path),
              "quick": quick, **pipeline_stats(summary), "score": sc,
              "table": {nm: dwell_table(truth, est, nm) for nm in names},
              "parameters": project.parameters(), "modes": int(project.rom.n_modes),
              "truth_dofs": info.get("truth_dofs"), "model_dofs": int(project.rom.F.shape[1]),
              "timings_s": {"reduced_model": t1 - t0, "render_scene": t2 - t1, "pipeline": t3 - t2},
              "files": list(FILES)}
    write_json(out / "report.json", report)
    return report


__all__ = ["EXAMPLES", "FILES", "SCENES", "run_project_demo", "scene_project"]
