"""`physar damping` (artificial damping of the time steppers, seed 001 §2.1) and `physar simulate`."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from physar.cli._common import log, print_json, user_errors
from physar.errors import ConfigError

_METHODS = ["symplectic_euler", "be", "si", "midpoint", "genalpha", "theta", "trbdf2"]


HW_RANGE = (1e-6, 1e6)  # backward Euler's d/omega stays within 1e-3 of its closed form here; at 1e-8 it is 2x off;
# a stepper with less damping (gen-alpha, TR-BDF2 at small h omega) gives values below ~1e-9: rounding noise


def _parse_hw(hw: list[str] | None, extra: list[str]) -> list[float]:
    vals = []
    for tok in list(hw or []) + list(extra):
        for part in str(tok).split(","):
            if not part:
                continue
            try:
                x = float(part)
            except ValueError:
                if part.startswith("--"):  # the extra arguments after --hw 1 2 hold an unknown option
                    raise ConfigError(f"physar damping: no such option {part} (see physar damping --help)") from None
                raise ConfigError(f"--hw: {part!r} is not a number") from None
            if not 0 < x < float("inf"):
                raise ConfigError(f"--hw values must be finite and > 0, got {x}")
            if not HW_RANGE[0] <= x <= HW_RANGE[1]:
                raise ConfigError(f"--hw {x:g} is outside [{HW_RANGE[0]:g}, {HW_RANGE[1]:g}]: there rho is within "
                                  "rounding of 1 or of 0, so d/omega = -(2/(h omega)) ln rho is rounding noise "
                                  "(inside, |d/omega| below about 1e-9 is rounding noise too)")
            vals.append(x)
    return vals


@user_errors
def damping(
    ctx: typer.Context,
    method: str | None = typer.Option(None, "--method", "-m", help="be | si | midpoint | genalpha | theta | trbdf2 | symplectic_euler"),
    r: float | None = typer.Option(None, "--r", help="generalized-alpha knob r = rho_inf in [0, 1] (default 0.5)"),
    theta: float | None = typer.Option(None, "--theta", help="theta method knob in [0, 1] (default 0.5)"),
    hw: list[str] | None = typer.Option(None, "--hw", help="h*omega values: --hw 0.1 1 10 (or 0.1,1,10)"),  # noqa: B008 - typer idiom
    json_out: bool = typer.Option(False, "--json", help="print {hw, rho, d_over_omega} as JSON"),
    plot: Path | None = typer.Option(None, "--plot", help="PNG with the seed's Fig. 2.1 (gen-alpha) and Fig. 2.2 (theta)"),  # noqa: B008 - typer idiom
) -> None:
    """Spectral radius rho and artificial damping d/omega = -(2/(h omega)) ln rho of a stepper on q'' + w^2 q = 0."""
    import numpy as np

    from physar.integrators.analysis import damping_curve, plot_damping_figures

    values = _parse_hw(hw, ctx.args)
    if method is None and plot is None:
        raise ConfigError("give --method (with --hw) and/or --plot PNG")
    if plot is not None:
        from physar.output import check_destination

        check_destination(plot, suffixes=[".png"], kind="plot")
    if method is not None:
        if method not in _METHODS:
            raise ConfigError(f"--method {method!r} is unknown; choose one of {', '.join(_METHODS)}")
        if not values:
            values = [0.01, 0.1, 1.0, 10.0, 100.0]
        c = damping_curve(method, values, r=r, theta=theta)
        d = [float(x) if np.isfinite(x) else None for x in c["d_over_omega"]]
        out = {"method": method, "hw": c["hw"], "rho": c["rho"], "d_over_omega": d}
        if r is not None:
            out["r"] = r
        if theta is not None:
            out["theta"] = theta
        if json_out:
            print_json(out)
        else:
            log(f"{'h*omega':>10} {'rho':>14} {'d/omega':>14}")
            for x, p, dd in zip(c["hw"], c["rho"], d):
                log(f"{x:10.4g} {p:14.8g} {dd if dd is not None else float('inf'):14.8g}")
    elif ctx.args:
        raise ConfigError(f"unexpected arguments: {' '.join(ctx.args)}")
    if plot is not None:
        plot_damping_figures(plot)
        log(f"wrote {plot}")


@user_errors
def simulate(
    config: Path = typer.Argument(..., help="problem file (TOML): the fem tables plus \\[dynamics]"),  # noqa: B008 - typer idiom
    out: Path = typer.Option(..., "--out", "-o", help="trajectory (.xdmf + .h5): displacement \\[m], velocity \\[m/s], region tags cell_tags"),  # noqa: B008 - typer idiom
    video: Path | None = typer.Option(None, "--video", help="MP4 of the deformed surface (H.264)"),  # noqa: B008 - typer idiom
    energy_csv: Path | None = typer.Option(None, "--energy", help="energy per step CSV: step, time_s, kinetic_J, elastic_J, potential_J, total_J, newton_iterations (default: OUT with .csv)"),  # noqa: B008 - typer idiom
    fps: float = typer.Option(30.0, "--fps", help="video frame rate"),
    plot: Path | None = typer.Option(None, "--plot", help="PNG of kinetic, elastic, potential (gravity, loads) and total energy against time"),  # noqa: B008 - typer idiom
    energy_warn: float = typer.Option(0.05, "--energy-warn", help="warn when the total energy grows by more than this fraction of the largest energy term"),
    json_out: bool = typer.Option(False, "--json", help="print a run summary as JSON"),
) -> None:
    """Integrate M q'' = f_els + f_dmp + f_ext in time and write the trajectory, energies and a video.

    The XDMF holds per frame the vertex arrays displacement \\[m] and velocity \\[m/s] and the tetrahedra's region
    tags cell_tags with their names (as the VTU of fem solve); the energy CSV's header carries the units:
    step, time_s, kinetic_J, elastic_J, potential_J, total_J, newton_iterations.

    Ctrl-C or SIGTERM stops after the current step: the steps done so far are written (exit 130). A run
    that diverges (non-finite state, runaway displacement, or total energy grown by more than 90 % of the
    largest energy term) writes the steps before it (and the --plot) and exits 2 naming the step. A total
    energy growth above --energy-warn (default 5 %) of the largest energy term is one warning line."""
    from tqdm import tqdm

    from physar.cli._common import check_toml
    from physar.errors import PhysarError
    from physar.integrators.config import (
        SimulationDiverged,
        build_simulation,
        load_dynamics_config,
        run_simulation,
        summarize,
        write_energy_csv,
        write_xdmf,
    )
    from physar.integrators.render import check_fps
    from physar.output import check_destination, signal_guard

    check_toml(config, "problem file")
    check_fps(fps, "--fps")
    csv_path = energy_csv or out.with_suffix(".csv")
    cfg = load_dynamics_config(config)
    mesh_in = []  # the input mesh (and an XDMF's .h5) is never replaced by an output
    if cfg.mesh.file:
        m = config.parent / cfg.mesh.file
        mesh_in = [m, m.with_suffix(".h5")] if m.suffix.lower() in (".xdmf", ".xmf") else [m]
    check_destination(out, inputs=[config, *mesh_in], suffixes=[".xdmf"], kind="trajectory")
    check_destination(out.with_suffix(".h5"), inputs=[config, *mesh_in], kind="trajectory data")
    from physar.integrators.config import ENERGY_COLUMNS, ENERGY_COLUMNS_V1
    from physar.output import csv_header_starts

    # the default energy CSV (OUT.csv, not named by the user) never replaces a CSV that is not an earlier one
    # (of this version, units in the header, or of an earlier one, without)
    ours, older = csv_header_starts(*list(ENERGY_COLUMNS.values())[:3]), csv_header_starts(*ENERGY_COLUMNS_V1[:3])
    check_destination(csv_path, inputs=[config, *mesh_in, out, out.with_suffix(".h5")], suffixes=[".csv"],
                      kind="energy CSV", replaces=None if energy_csv else lambda p: ours(p) or older(p))
    if video is not None:
        check_destination(video, inputs=[config, *mesh_in, out, csv_path], suffixes=[".mp4"], kind="video")
    if plot is not None:
        check_destination(plot, inputs=[config, *mesh_in, out, csv_path, video], suffixes=[".png"],
                          kind="energy plot")
    if not (0 < energy_warn < float("inf")):
        raise ConfigError(f"--energy-warn must be a finite fraction > 0, got {energy_warn}")
    failure = None
    try:
        sim = build_simulation(cfg)
        with signal_guard() as guard, tqdm(total=cfg.dynamics.steps, desc=f"{cfg.dynamics.method} steps",
                                           file=sys.stderr, disable=None) as bar:
            log(f"simulating {cfg.dynamics.steps} steps (Ctrl-C stops and writes the steps done)")
            try:
                traj = run_simulation(sim, lambda k, n: bar.update(1), stop=lambda: guard.stopped)
            except SimulationDiverged as exc:
                traj, failure = exc.trajectory, exc
    except PhysarError as exc:
        if str(exc).startswith(str(config)):
            raise
        raise type(exc)(f"{config}: {exc}") from None
    write_xdmf(out, sim, traj)
    write_energy_csv(csv_path, traj)
    if plot is not None:
        from physar.integrators.analysis import plot_energies

        plot_energies(plot, traj.energy, title=f"{cfg.dynamics.method}, h = {cfg.dynamics.h:g} s",
                      potential_label="potential (gravity, loads" + (", ground)" if cfg.dynamics.ground else ")"))
    if failure is not None:
        raise type(failure)(f"{config}: {failure}; wrote steps 0-{traj.energy[-1]['step']} to {out} and "
                            f"{csv_path}" + (f" and {plot}" if plot else ""), traj) from None
    summary = summarize(sim, traj)
    summary.update({"output": str(out), "energy_csv": str(csv_path), "interrupted": traj.interrupted})
    from physar.integrators.analysis import energy_drift

    drift = energy_drift(traj.energy)
    summary["energy_growth"] = drift["growth"]
    if plot is not None:
        summary["plot"] = str(plot)
    if drift["growth"] > energy_warn:
        import warnings

        from physar.errors import PhysarWarning

        warnings.warn(PhysarWarning(
            f"the total energy grew by {100 * drift['growth']:.1f} % of the largest energy term (at t = "
            f"{drift['t_max_growth']:.4g} s; limit --energy-warn {100 * energy_warn:g} %): the integrator adds "
            f"energy ({cfg.dynamics.method}, h = {cfg.dynamics.h:g} s); reduce h or use a dissipative method"),
            stacklevel=1)
    if video is not None:
        from physar.integrators.render import write_video

        surf = sim.problem.space.mesh.boundary()
        log(f"rendering {len(traj.u)} frames")
        write_video(video, surf.mesh.points, surf.mesh.faces, [u[surf.node_map] for u in traj.u], traj.times,
                    fps=fps, title=f"{cfg.dynamics.method}, h = {cfg.dynamics.h:g} s")
        summary["video"] = str(video)
    if json_out:
        print_json(summary)
    else:
        log(("interrupted: " if traj.interrupted else "") + f"wrote {out}, {csv_path}"
            + (f", {video}" if video else "") + (f", {plot}" if plot else ""))
        log(f"energy {summary['energy_initial']:.6g} J -> {summary['energy_final']:.6g} J, "
            f"Newton iterations mean {summary['newton_iterations_mean']:.2f} (max {summary['newton_iterations_max']})")
    if traj.interrupted:
        raise typer.Exit(code=130)


def register(app: typer.Typer) -> None:
    app.command("damping", context_settings={"allow_extra_args": True, "ignore_unknown_options": True})(damping)
    app.command("simulate")(simulate)
