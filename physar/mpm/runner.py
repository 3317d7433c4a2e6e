"""Run a scene file to disk, and identify a scene's materials from a run on disk (``physar mpm run|identify``).

``run_scene`` advances the forward solver (:class:`physar.mpm.model.MPMSolver`, seed 002 Alg. 1) frame by
frame and writes, into the output folder,

* ``frame_0000.ply`` … ``frame_NNNN.ply``: particle positions (m), velocities (m/s) and body ids;
* ``diagnostics.csv``: per frame the centre of mass, linear and (APIC) angular momentum, kinetic, potential
  and elastic energy (:func:`physar.mpm.model.diagnostics`);
* ``preview.mp4``: a side view (x right, z up) at the frame rate 1 / frame_dt.

``identify_scene`` fits the per-body Young's moduli of a scene (its E values are the initial guesses) to such a
folder with :func:`physar.mpm.identify.identify` (seed 002 §4.4).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from physar.errors import SolverError
from physar.mpm.io import read_trajectory, write_diagnostics_csv, write_particles_ply, write_preview_mp4
from physar.mpm.model import MPMSolver, diagnostics
from physar.mpm.scene import Scene, build_model, load_scene
from physar.output import atomic_folder, check_folder, own_names


@dataclass(repr=False)
class RunResult:
    frames: int
    time: list = field(default_factory=list)  # s, frame 0 included
    diagnostics: list = field(default_factory=list)  # one dict per frame (see model.diagnostics)
    n_particles: int = 0
    preview: bool = False  # whether preview.mp4 was written
    interrupted: bool = False  # stopped early on request; the outputs cover frames 0..frames

    def __repr__(self) -> str:
        """One line: frames, their time span [s], particles, preview and interruption (no per-frame data)."""
        span = f", t {self.time[0]:.6g}..{self.time[-1]:.6g} s" if self.time else ""
        return (f"RunResult({self.frames} frames{span}, {self.n_particles} particles"
                f"{', preview.mp4' if self.preview else ''}{', interrupted' if self.interrupted else ''})")

    def summary(self) -> dict:
        """The ``--json`` record of ``physar mpm run`` (per frame, frame 0 included)."""
        return {
            "frames": self.frames,
            "time": [float(t) for t in self.time],
            "com": [[float(c) for c in d["com"]] for d in self.diagnostics],
            "momentum": [[float(c) for c in d["momentum"]] for d in self.diagnostics],
            "kinetic_energy": [float(d["kinetic_energy"]) for d in self.diagnostics],
        }


def _scene_and_dir(scene: Scene | str | Path) -> tuple[Scene, Path | None]:
    if isinstance(scene, Scene):
        return scene, None
    return load_scene(scene), Path(scene).resolve().parent


OWN_FILES = own_names(r"frame_\d{4,}\.ply", r"diagnostics\.csv", r"preview\.mp4")  # what run_scene writes


def check_run_folder(out: str | Path, inputs=()) -> Path:
    """The output folder of :func:`run_scene`, checked before any work: a new, empty or previous-run folder
    (one holding only frame_NNNN.ply, diagnostics.csv and preview.mp4), never one with other files."""
    return check_folder(out, own=OWN_FILES, inputs=inputs, kind="MPM output folder")


def run_scene(scene: Scene | str | Path, out: str | Path | None, progress: Callable[[int, int], None] | None = None,
              preview: bool = True, particles_per_cell: int | None = None,
              stop: Callable[[], bool] | None = None) -> RunResult:
    """Simulate ``scene`` (a TOML path or a parsed :class:`Scene`) and write its outputs into ``out``.

    ``out = None`` only computes the diagnostics.  ``particles_per_cell`` overrides the scene's sampling.
    ``progress(frame, frames)`` is called after every frame; ``stop()`` is polled after every frame and ends
    the run there when it returns True (``interrupted``). Either way, and when the simulation diverges (its state
    stops being finite or blows up: SolverError after writing), ``diagnostics.csv`` and the preview cover exactly
    the frames written.

    The outputs are written into a hidden folder beside ``out`` that takes its place once they are complete
    (:func:`physar.output.atomic_folder`): an error or a second Ctrl-C leaves ``out`` as it was (absent, or a
    previous run's output), never a folder holding some frames without their diagnostics.
    """
    if out is not None:
        out = check_run_folder(out, inputs=[] if isinstance(scene, Scene) else [scene])
    sc, base = _scene_and_dir(scene)
    source = "scene" if isinstance(scene, Scene) else str(scene)
    kept = 24 * (sc.time.frames + 1) if out is not None and preview else 0  # the preview's positions per frame
    model, x0, v0 = build_model(sc, base, particles_per_cell=particles_per_cell, source=source,
                                bytes_per_particle=kept)
    folder = atomic_folder(out, own=OWN_FILES) if out is not None else contextlib.nullcontext(None)
    with folder as tmp:
        res, failure = _simulate(sc, model, x0, v0, tmp, progress, preview, stop)
    if failure is not None:
        wrote = f"; wrote frames 0-{res.frames} to {out}" if out is not None else ""
        raise SolverError(f"{source}: {failure}{wrote}")
    return res


def _simulate(sc: Scene, model, x0, v0, out: Path | None, progress, preview: bool, stop):
    """The frame loop of :func:`run_scene` writing into ``out``; returns (result, failure message or None)."""
    solver = MPMSolver(model)
    a, b = model.state(x0, v0), model.state(x0, v0)
    n_frames = sc.time.frames
    res = RunResult(frames=n_frames, n_particles=model.n_particles)
    xs, failure = [], None
    for f in range(n_frames + 1):
        if f > 0:
            try:
                a, b = solver.simulate_frame(a, b)
            except SolverError as exc:  # a blow-up: the frames before it are kept and described
                failure = f"at frame {f} (t = {f * model.frame_dt:.4g} s): {exc}"
                break
        st = a.numpy()
        if not (np.isfinite(st["x"]).all() and np.isfinite(st["v"]).all()):
            failure = (f"the particle state is no longer finite at frame {f} (t = {f * model.frame_dt:.4g} s); "
                       "reduce frame_dt / raise substeps, or soften the material")
            break
        with np.errstate(over="ignore", invalid="ignore"):  # a finite but huge state: inf energies, no noise
            d = diagnostics(model, st)
        res.time.append(f * model.frame_dt)
        res.diagnostics.append(d)
        if out is not None:
            write_particles_ply(out / f"frame_{f:04d}.ply", st["x"], st["v"], model.body)
            if preview:  # kept only for the preview (the memory estimate counts them only then)
                xs.append(st["x"])
        if progress and f > 0:
            progress(f, n_frames)
        if stop is not None and f < n_frames and stop():
            res.interrupted = True
            break
    res.frames = len(res.time) - 1
    if out is not None:
        write_diagnostics_csv(out / "diagnostics.csv", res.time, res.diagnostics)
        if preview:
            res.preview = write_preview_mp4(out / "preview.mp4", xs, model.body, sc.grid.size,
                                            fps=1.0 / model.frame_dt)
    return res, failure


def identify_scene(scene: Scene | str | Path, target: str | Path, iterations: int = 20, fit_nu: bool = False,
                   progress: Callable[[int, float], None] | None = None) -> dict:
    """Identify per-body E (and nu) of ``scene`` from the frames in folder ``target``; returns a JSON-able dict."""
    from physar.mpm.identify import identify

    sc, base = _scene_and_dir(scene)
    # identification keeps each frame's state (x, v, C, F, Jp: 200 B per particle) for the backward pass
    model, x0, v0 = build_model(sc, base, source="scene" if isinstance(scene, Scene) else str(scene),
                                bytes_per_particle=200 * (sc.time.frames + 1))
    frames = read_trajectory(target)
    res = identify(model, x0, v0, sc.time.frames, frames, fit_nu=fit_nu, iterations=iterations, progress=progress)
    return {
        "E": [float(e) for e in res.E],
        "nu": [float(n) for n in res.nu],
        "E_initial": [float(b.E) for b in sc.body],
        "loss": res.loss,
        "evaluations": len(res.history),
        "frames": sc.time.frames,
    }


def initial_state(scene: Scene) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - convenience
    _model, x0, v0 = build_model(scene)
    return x0, v0
