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

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from physar.errors import ConfigError
from physar.mpm.io import read_trajectory, write_diagnostics_csv, write_particles_ply, write_preview_mp4
from physar.mpm.model import MPMSolver, diagnostics
from physar.mpm.scene import Scene, build_model, load_scene


@dataclass
class RunResult:
    frames: int
    time: list = field(default_factory=list)  # s, frame 0 included
    diagnostics: list = field(default_factory=list)  # one dict per frame (see model.diagnostics)
    n_particles: int = 0
    preview: bool = False  # whether preview.mp4 was written

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


def run_scene(scene: Scene | str | Path, out: str | Path | None, progress: Callable[[int, int], None] | None = None,
              preview: bool = True, particles_per_cell: int | None = None) -> RunResult:
    """Simulate ``scene`` (a TOML path or a parsed :class:`Scene`) and write its outputs into ``out``.

    ``out = None`` only computes the diagnostics.  ``particles_per_cell`` overrides the scene's sampling.
    ``progress(frame, frames)`` is called after every frame.
    """
    sc, base = _scene_and_dir(scene)
    model, x0, v0 = build_model(sc, base, particles_per_cell=particles_per_cell)
    if out is not None:
        out = Path(out)
        if out.exists() and not out.is_dir():
            raise ConfigError(f"--out '{out}' exists and is not a folder")
        out.mkdir(parents=True, exist_ok=True)
        for old in out.glob("frame_*.ply"):  # a shorter re-run must not leave frames of an older one behind
            old.unlink()
    solver = MPMSolver(model)
    a, b = model.state(x0, v0), model.state(x0, v0)
    n_frames = sc.time.frames
    res = RunResult(frames=n_frames, n_particles=model.n_particles)
    xs = []
    for f in range(n_frames + 1):
        if f > 0:
            a, b = solver.simulate_frame(a, b)
        st = a.numpy()
        res.time.append(f * model.frame_dt)
        res.diagnostics.append(diagnostics(model, st))
        if out is not None:
            write_particles_ply(out / f"frame_{f:04d}.ply", st["x"], st["v"], model.body)
            xs.append(st["x"])
        if progress and f > 0:
            progress(f, n_frames)
    if out is not None:
        write_diagnostics_csv(out / "diagnostics.csv", res.time, res.diagnostics)
        if preview:
            res.preview = write_preview_mp4(out / "preview.mp4", xs, model.body, sc.grid.size,
                                            fps=1.0 / model.frame_dt)
    return res


def identify_scene(scene: Scene | str | Path, target: str | Path, iterations: int = 20, fit_nu: bool = False,
                   progress: Callable[[int, float], None] | None = None) -> dict:
    """Identify per-body E (and nu) of ``scene`` from the frames in folder ``target``; returns a JSON-able dict."""
    from physar.mpm.identify import identify

    sc, base = _scene_and_dir(scene)
    model, x0, v0 = build_model(sc, base)
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
