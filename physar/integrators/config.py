"""The dynamics problem file: a physar.fem TOML problem plus a `[dynamics]` table (validated by pydantic).

```toml
[dynamics]
method = "genalpha"       # symplectic_euler | be | si | midpoint | genalpha | theta | trbdf2
h = 0.01                  # time step [s]
steps = 300
r = 0.5                   # generalized-alpha knob (rho_inf), 0 = most damping, 1 = none
theta = 0.5               # theta method knob (Eq. 2.15), 0 = trapezoid, 1 = BDF2
mass = "lumped"           # or "consistent"
gravity = [0, 0, -9.81]   # optional, applied as M g
initial = "rest"          # or "static": start from the static solution under the [[load]]s, released at t = 0
initial_velocity = [0, 0, 0]
output_every = 1          # write every k-th step to the XDMF/MP4
backend = "numpy"         # co-rotated P1: "numpy" or "warp" (NVIDIA Warp CPU kernels; SI steps ~2x faster)
[dynamics.damping]        # Rayleigh D = alpha M + beta K(q)
alpha = 0.0               # [1/s]
beta = 0.0                # [s]
[dynamics.ground]         # optional penalty ground plane
z = 0.0
stiffness = 1e5           # [N/m] per node
[dynamics.newton]
tol = 1e-9
max_iter = 25
linear_solver = "direct"  # or "pcg": CG with a reused Cholesky factor in the rotated frame (large meshes)
linear_rtol = 1e-8        # CG relative residual (pcg only)
tangent = "exact"         # co-rotated P1 only: "exact" or "warped" (R K0 Rᵀ, SPD, SOFA-style)
```
[[fix]] boxes pin nodes (at their `value`, default 0); [[load]]s act during the run (constant), unless
`initial = "static"`.
"""

from __future__ import annotations

import contextlib
import csv
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from physar.errors import ConfigError, SolverError
from physar.fem.config import FemConfig, Problem, _Strict, build_problem, load_config
from physar.fem.solvers import solve_static
from physar.geometry.mesh import _plural
from physar.integrators.model import Ground, SolidModel
from physar.integrators.steppers import Integrator, State, make_integrator
from physar.output import atomic_path

Vec3 = tuple[float, float, float]


class DampingSection(_Strict):
    """Rayleigh damping D = alpha M + beta K(q), K the current tangent."""

    alpha: float = Field(0.0, ge=0, description="Rayleigh mass coefficient [1/s]")
    beta: float = Field(0.0, ge=0, description="Rayleigh stiffness coefficient [s]")


class GroundSection(_Strict):
    """A penalty ground plane: f_z = stiffness max(z - node z, 0) on every node below it."""

    z: float = Field(0.0, description="height of the ground plane [m]")
    stiffness: float = Field(1e5, gt=0, description="penalty stiffness [N/m] per node")


class NewtonSection(_Strict):
    tol: float = Field(1e-9, gt=0, description="relative residual of a step's equations (or relative Newton "
                                               "update of the velocity) at which Newton stops [-]")
    max_iter: int = Field(25, ge=1, description="Newton iterations per step")
    linear_solver: Literal["direct", "pcg"] = Field(
        "direct", description="direct (CHOLMOD, symbolic analysis reused) or pcg (CG preconditioned by a reused "
                              "Cholesky factor in the rotated frame; large meshes)")
    linear_rtol: float = Field(1e-8, gt=0, lt=1, description="relative residual of CG (pcg only) [-]")
    tangent: Literal["exact", "warped"] = Field(
        "exact", description="co-rotated P1 only: exact tangent K(q), or warped R K0 Rᵀ (SPD, SOFA-style)")


class DynamicsSection(_Strict):
    method: Literal["symplectic_euler", "be", "si", "midpoint", "genalpha", "theta", "trbdf2"] = Field(
        ..., description="time integrator (seed 001 §2): symplectic_euler (explicit), be (backward Euler), si "
                         "(semi-implicit: one Newton iteration of be), midpoint (implicit), genalpha "
                         "(generalized-alpha, knob r), theta (trapezoid/BDF2 blend, knob theta), trbdf2")
    h: float = Field(..., gt=0, description="time step [s]")
    steps: int = Field(..., ge=1, description="number of time steps")
    r: float | None = Field(None, ge=0, le=1, description="genalpha only: spectral radius at infinity rho_inf "
                                                          "(seed Eq. 2.11-2.12), 0 = most damping, 1 = none; "
                                                          "default 0.5 [-]")
    theta: float | None = Field(None, ge=0, le=1, description="theta only (seed Eq. 2.15): 0 = trapezoid, 1 = "
                                                              "BDF2; default 0.5 [-]")
    mass: Literal["lumped", "consistent"] = Field("lumped", description="mass matrix: lumped (diagonal) or "
                                                                        "consistent")
    gravity: Vec3 | None = Field(None, description="gravitational acceleration, applied as M g [m/s^2] "
                                                   "(default none)")
    initial: Literal["rest", "static"] = Field(
        "rest", description="rest: start undeformed (pinned nodes at their [[fix]] value); static: start from the static solution under the [[load]]s, "
                            "which are released at t = 0")
    initial_velocity: Vec3 = Field((0.0, 0.0, 0.0), description="initial velocity of every free node [m/s]")
    kernel: Literal["auto", "fem", "corotated-p1"] = Field(
        "auto", description="elastic forces: fem (physar.fem assembly, any material and element), corotated-p1 "
                            "(fast kernel: P1 and the corotated material only), auto (corotated-p1 where it "
                            "applies)")
    backend: Literal["numpy", "warp"] = Field(
        "numpy", description="co-rotated P1 kernel: numpy, or warp (NVIDIA Warp CPU kernels; faster on large "
                             "meshes)")
    output_every: int = Field(1, ge=1, description="write every k-th step to the XDMF and the video")
    damping: DampingSection = Field(DampingSection(), description="Rayleigh damping (default none)")
    ground: GroundSection | None = Field(None, description="a penalty ground plane (default none)")
    newton: NewtonSection = Field(NewtonSection(), description="Newton iterations and linear solves of the "
                                                               "implicit methods")

    @model_validator(mode="after")
    def _knobs(self):
        if self.r is not None and self.method != "genalpha":
            raise ValueError(f"r applies to method = \"genalpha\" only (method is {self.method!r})")
        if self.theta is not None and self.method != "theta":
            raise ValueError(f"theta applies to method = \"theta\" only (method is {self.method!r})")
        return self


class DynamicsConfig(FemConfig):
    """A `physar simulate` file: every FemConfig table plus [dynamics]."""

    dynamics: DynamicsSection = Field(..., description="time integration")


def load_dynamics_config(path: str | Path) -> DynamicsConfig:
    return load_config(path, DynamicsConfig)


@dataclass(repr=False)
class Simulation:
    """A dynamics run built from a configuration: the static problem, the model, the integrator, q0 and v0."""

    problem: Problem
    model: SolidModel
    integrator: Integrator
    q0: np.ndarray
    v0: np.ndarray
    config: DynamicsConfig

    def __repr__(self):
        """One line: the model, the integrator, the time step [s] and the number of steps."""
        d = self.config.dynamics
        return f"Simulation({self.model!r}, {self.integrator!r}, h={d.h:g} s, {_plural(d.steps, 'step')})"


def build_simulation(cfg: DynamicsConfig, base_dir: Path | None = None) -> Simulation:
    """Mesh, material, pins and loads from the fem tables; model and integrator from [dynamics]."""
    problem = build_problem(cfg, base_dir)
    d = cfg.dynamics
    if problem.model.density <= 0:
        raise ConfigError("[material] density must be > 0 for dynamics")
    q_fixed = problem.prescribed
    ground = None if d.ground is None else Ground(d.ground.z, d.ground.stiffness)
    f_ext = problem.f_ext
    q0 = None
    if d.initial == "static":
        if not np.any(f_ext) and q_fixed is None:
            raise ConfigError("[dynamics] initial = \"static\" needs at least one [[load]] (or a [[fix]] value)")
        s = cfg.solver
        q0 = solve_static(problem.model, f_ext, problem.fixed, steps=s.steps, tol=s.tol, max_iter=s.max_iter,
                          prescribed=q_fixed).u
        f_ext = np.zeros_like(f_ext)
    model = SolidModel(problem.model, problem.fixed, q_fixed=q_fixed, mass=d.mass,
                       rayleigh=(d.damping.alpha, d.damping.beta), gravity=d.gravity, f_ext=f_ext,
                       ground=ground, kernel=d.kernel, tangent=d.newton.tangent,
                       backend=d.backend)
    integ = make_integrator(d.method, r=d.r, theta=d.theta, tol=d.newton.tol, max_iter=d.newton.max_iter,
                            linear_solver=d.newton.linear_solver, linear_rtol=d.newton.linear_rtol)
    v0 = np.tile(np.asarray(d.initial_velocity, dtype=float), problem.space.n_nodes)
    q0, v0 = model.initial_state(q0, v0)
    return Simulation(problem, model, integ, q0, v0, cfg)


@dataclass(repr=False)
class Trajectory:
    """Frames (every `output_every` steps) of vertex displacements/velocities and the energy per step."""

    times: list = field(default_factory=list)
    u: list = field(default_factory=list)
    v: list = field(default_factory=list)
    energy: list = field(default_factory=list)  # dicts: step, t, kinetic, elastic, potential, total, newton
    interrupted: bool = False  # stopped early on request (a signal); the frames end at the last step done

    def __repr__(self):
        """One line: frames, their time span [s], energy records, interrupted (no arrays)."""
        span = f", t {self.times[0]:.6g}..{self.times[-1]:.6g} s" if self.times else ""
        return (f"Trajectory({_plural(len(self.times), 'frame')}{span}, {_plural(len(self.energy), 'energy record')}"
                f"{', interrupted' if self.interrupted else ''})")


# A node displaced by more than RUNAWAY times the body's bounding-box diagonal means the integration ran
# away (an explicit step beyond its stability limit grows the solution geometrically, and its energy with it,
# long before the numbers overflow to inf). No run this toolkit models (a beam swinging, a body dropped onto
# the ground) moves a node by a thousand body sizes.
RUNAWAY = 1e3


class SimulationDiverged(SolverError):
    """The solution became non-finite or ran away; ``trajectory`` holds the steps before that (all finite)."""

    def __init__(self, message: str, trajectory: Trajectory):
        super().__init__(message)
        self.trajectory = trajectory


# Energy runaway: the total energy E = kinetic + elastic + potential is conserved by the dynamics (constant
# loads and gravity are in the potential) or lost to damping and contact. A growth E(t) - E(0) larger than
# RUNAWAY_ENERGY times the largest energy term seen so far (max |kinetic|, |elastic|, |potential|) means
# that most of the motion is energy the integrator made up: an explicit step past its stability limit, whose
# energy grows geometrically well before a displacement runs away. Checked from step RUNAWAY_FROM on (a first
# step from rest can be dominated by its O(h) start-up error). :func:`energy_growth` is that ratio.
RUNAWAY_ENERGY = 0.9
RUNAWAY_FROM = 10


def energy_growth(total0: float, total: float, scale: float) -> float:
    """(E(t) - E(0)) / scale, scale = the largest |kinetic|, |elastic|, |potential| up to t (0 if scale = 0)."""
    return (total - total0) / scale if scale > 0 else 0.0


def _diverged(state: State, energy: dict, size: float, growth: float = 0.0, step: int = 0) -> str | None:
    """Why ``state`` is not a valid step (non-finite values, runaway displacement or energy), or None."""
    if not (np.all(np.isfinite(state.q)) and np.all(np.isfinite(state.v))):
        return "the solution is no longer finite"
    if not all(np.isfinite(v) for v in energy.values()):
        return "the energy is no longer finite"
    q3 = state.q.reshape(-1, 3) if state.q.size % 3 == 0 else state.q[:, None]
    umax = float(np.abs(q3 - q3.mean(axis=0)).max()) if state.q.size else 0.0  # apart from a rigid translation
    if umax > RUNAWAY * size:
        return (f"a displacement apart from the body's mean translation reached {umax:.3g} m, more than "
                f"{RUNAWAY:g} times the body's size ({size:.3g} m)")
    if step >= RUNAWAY_FROM and growth > RUNAWAY_ENERGY:
        return (f"the total energy grew by {100 * growth:.0f} % of the largest energy term (runaway energy, "
                f"limit {100 * RUNAWAY_ENERGY:.0f} %)")
    return None


def run_simulation(sim: Simulation, progress: Callable[[int, int], None] | None = None,
                   stop: Callable[[], bool] | None = None) -> Trajectory:
    """Integrate; record the energy at every step and the vertex fields at every output_every-th step.

    ``stop()`` is polled after every step: when it returns True the run ends there (``trajectory.
    interrupted``). A step whose state is not finite, whose energy is not finite, whose displacement ran
    away (``RUNAWAY``: apart from the body's mean translation, so a long free fall is not a divergence) or whose
    total energy ran away (``RUNAWAY_ENERGY``) raises :class:`SimulationDiverged` carrying the trajectory up to the
    step before it, with its last state recorded as a frame, so that what is written from it is valid; so does a
    step that fails (a SolverError: Newton did not converge), naming the step.
    """
    d = sim.config.dynamics
    space = sim.problem.space
    nv = space.mesh.n_points
    pts = space.mesh.points
    size = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))) if len(pts) else 1.0
    traj = Trajectory()
    integ, model = sim.integrator, sim.model
    state: State = integ.init(model, sim.q0, sim.v0)

    def frame(s):
        traj.times.append(s.t)
        traj.u.append(s.q.reshape(-1, 3)[:nv].astype(np.float64).copy())
        traj.v.append(s.v.reshape(-1, 3)[:nv].astype(np.float32).copy())

    def record(k, s, e):
        traj.energy.append({"step": k, "t": s.t, **e, "newton_iterations": s.newton_iterations})
        if k % d.output_every == 0 or k == d.steps:
            frame(s)

    e0 = model.energy(state.q, state.v)
    record(0, state, e0)
    scale = max(abs(e0["kinetic"]), abs(e0["elastic"]), abs(e0["potential"]))
    fix = "reduce [dynamics] h" + ("" if getattr(integ, "implicit", True) else " or use an implicit method")
    for k in range(1, d.steps + 1):
        prev = state
        try:
            state = integ.step(model, state, d.h)
        except SolverError as exc:  # e.g. Newton did not converge: the steps before it are kept, as for a divergence
            if traj.times[-1] != prev.t:
                frame(prev)
            raise SimulationDiverged(f"{integ.name} failed at step {k} (t = {prev.t + d.h:.4g} s): "
                                     f"{str(exc).removeprefix(integ.name + ': ')}", traj) from None
        with np.errstate(all="ignore"):
            e = model.energy(state.q, state.v)
            scale = max(scale, abs(e["kinetic"]), abs(e["elastic"]), abs(e["potential"]))
            growth = energy_growth(e0["total"], e["total"], scale)
        why = _diverged(state, e, size, growth, k)
        if why is not None:
            if traj.times[-1] != prev.t:
                frame(prev)
            raise SimulationDiverged(f"{integ.name} diverged at step {k} (t = {state.t:.4g} s): {why}; {fix}",
                                     traj)
        record(k, state, e)
        if progress:
            progress(k, d.steps)
        if stop is not None and stop() and k < d.steps:
            traj.interrupted = True
            if traj.times[-1] != state.t:
                frame(state)
            break
    return traj


def write_xdmf(path: str | Path, sim: Simulation, traj: Trajectory) -> Path:
    """XDMF time series (meshio, with its .h5): the reference mesh and, per frame, ``displacement`` [m] and
    ``velocity`` [m/s] at the vertices (n, 3), and the region tags of the tetrahedra, as in the VTU of
    ``physar fem solve`` (:func:`physar.geometry.write_mesh`): ``cell_tags`` (m,) integers (0 where the mesh has
    no tetrahedron tags) on every frame, so a viewer (ParaView's Threshold) selects regions at any time, stored
    once in the .h5 and referenced by each frame, and the region names ({name: (tag, dim)}) in an
    ``<Information>`` element of the mesh grid (:func:`physar.geometry.io.xdmf_names_element`). Array names
    carry no units (the ParaView and physar convention: SI units as stated here)."""
    import copy

    import meshio

    from physar.geometry.io import xdmf_names_element

    path = Path(path)
    if path.suffix.lower() != ".xdmf":
        raise ConfigError(f"trajectory output must end in .xdmf, got {path.name}")
    mesh = sim.problem.space.mesh
    tags = mesh.tags
    cell_data = None
    if tags is not None:
        cell_tags = tags.cell_tags if tags.cell_tags is not None else np.zeros(mesh.n_cells, np.int64)
        cell_data = {"cell_tags": [np.asarray(cell_tags, np.int64)]}
    # meshio's TimeSeriesWriter opens its .h5 relative to the working directory: write from inside
    # the temporary folder (single-threaded CLI use)
    with (
        atomic_path(path, companions=True) as tmp,
        contextlib.chdir(tmp.parent),
        meshio.xdmf.TimeSeriesWriter(tmp.name) as w,
    ):
        w.write_points_cells(mesh.points, [("tetra", mesh.cells)])
        if tags is not None and tags.names:
            w.domain[-1].insert(0, xdmf_names_element(tags.names))  # the mesh grid write_points_cells added
        shared = None  # the cell_tags Attribute of the first frame, whose .h5 data every frame references
        for t, u, v in zip(traj.times, traj.u, traj.v):
            w.write_data(t, point_data={"displacement": u, "velocity": v.astype(np.float64)},
                         cell_data=cell_data if shared is None else None)
            if cell_data is not None and shared is None:
                shared = w.collection[-1].find("Attribute[@Name='cell_tags']")
            elif shared is not None:
                w.collection[-1].append(copy.deepcopy(shared))
    return path


# CSV columns of the energy per step, units in the names (as the AR estimates' ``time_s``): the keys of
# ``Trajectory.energy`` rows -> the header
ENERGY_COLUMNS = {"step": "step", "t": "time_s", "kinetic": "kinetic_J", "elastic": "elastic_J",
                  "potential": "potential_J", "total": "total_J", "newton_iterations": "newton_iterations"}
# the header before the units were added (an earlier energy CSV that a new run may replace)
ENERGY_COLUMNS_V1 = ("step", "t", "kinetic", "elastic", "potential", "total", "newton_iterations")


def write_energy_csv(path: str | Path, traj: Trajectory) -> Path:
    """One row per step, header ``step, time_s, kinetic_J, elastic_J, potential_J, total_J, newton_iterations``:
    the step, its time [s], the kinetic, elastic, potential (gravity, loads, ground) and total energy [J] and
    the Newton iterations of the step (0 for step 0 and explicit steppers); floats to 17 significant digits."""
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(ENERGY_COLUMNS.values())
        for row in traj.energy:
            w.writerow([f"{row[k]:.17g}" if isinstance(row[k], float) else row[k] for k in ENERGY_COLUMNS])
    return path


def summarize(sim: Simulation, traj: Trajectory) -> dict:
    e = traj.energy
    it = [r["newton_iterations"] for r in e[1:]]
    umax = max(float(np.linalg.norm(u, axis=1).max()) for u in traj.u)
    return {
        "method": sim.integrator.name, "h": sim.config.dynamics.h, "steps": sim.config.dynamics.steps,
        "dofs": sim.model.n_dofs, "elements": int(sim.problem.space.mesh.n_cells),
        "kernel": sim.model.kernel.name,
        "energy_initial": e[0]["total"], "energy_final": e[-1]["total"],
        "newton_iterations_mean": float(np.mean(it)) if it else 0.0,
        "newton_iterations_max": int(max(it)) if it else 0,
        "max_displacement": umax, "frames": len(traj.times),
    }


__all__ = ["DynamicsConfig", "DynamicsSection", "Simulation", "SimulationDiverged", "Trajectory",
           "build_simulation", "load_dynamics_config", "run_simulation", "summarize", "write_energy_csv", "write_xdmf"]
