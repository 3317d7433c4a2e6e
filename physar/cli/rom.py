"""`physar rom …` (reduced models: build, info, eval) and `physar assimilate` (seed 000 §3-§5)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import typer
from typer.core import TyperCommand

from physar.cli._common import log, print_json, user_errors

rom_app = typer.Typer(help="Reduced parametric models (PGD, non-intrusive PGD, POD).", no_args_is_help=True)


def _parse_params(model, items: list[str], flag: str = "--param", partial: bool = False):
    """NAME=VALUE items -> the parameter vector (every parameter required), or with ``partial`` the mapping
    {name: value} of those given (``assimilate`` starts the others at the centre of their range)."""
    import math

    from physar.errors import ConfigError

    given = {}
    for it in items:
        name, sep, val = it.partition("=")
        name = name.strip()
        if not sep or name not in model.names:
            raise ConfigError(f"{flag} {it!r}: expected NAME=VALUE with NAME one of {model.names}")
        if name in given:  # "last wins" would silently drop a value the user typed
            first = next(i for i in items if i.partition("=")[0].strip() == name)
            raise ConfigError(f"{flag} given twice for {name} ({first!r} and {it!r}); give each parameter once")
        try:
            given[name] = float(val)
        except ValueError:
            raise ConfigError(f"{flag} {it!r}: {val!r} is not a number") from None
        if not math.isfinite(given[name]):
            raise ConfigError(f"{flag} {it!r}: not a finite number")
    missing = [n for n in model.names if n not in given]
    if missing and not partial:
        raise ConfigError(f"missing {flag} for {', '.join(missing)} (model parameters: {model.names})")
    for n, (lo, hi), u in zip(model.names, model.ranges, model.units):
        v = given.get(n)
        if v is not None and not lo - 1e-12 * max(1.0, abs(hi - lo)) <= v <= hi + 1e-12 * max(1.0, abs(hi - lo)):
            raise ConfigError(f"{flag} {n}={v}: outside the model's range [{lo}, {hi}] {u}")
    return given if partial else np.array([given[n] for n in model.names])


@rom_app.command("build")
@user_errors
def build(
    config: Path = typer.Argument(..., help="FEM problem file (TOML) with [\\[parameter]] tables and \\[rom]"),  # noqa: B008 - typer idiom
    out: Path = typer.Option(..., "--out", "-o", help="reduced model file (.npz)"),  # noqa: B008 - typer idiom
    workers: int | None = typer.Option(None, "--workers",
                                          help="non-intrusive: start a Dask LocalCluster with N workers"),
    scheduler: str | None = typer.Option(None, "--scheduler", help="non-intrusive: Dask scheduler address"),
    json_out: bool = typer.Option(False, "--json", help="print a summary as JSON on stdout"),
) -> None:
    """Build a reduced model offline (PGD, non-intrusive PGD or POD) and save it."""
    from tqdm import tqdm

    from physar.cli._common import check_toml
    from physar.errors import PhysarError
    from physar.output import check_destination
    from physar.rom.config import build_rom, load_rom_config

    if workers is not None and workers < 1:
        raise PhysarError(f"--workers must be >= 1, got {workers}")
    check_toml(config, "rom build file")
    check_destination(out, inputs=[config], suffixes=[".npz"], kind="reduced model")
    cfg = load_rom_config(config)
    given = [f for f, v in (("--workers", workers), ("--scheduler", scheduler)) if v is not None]
    if given and cfg.rom.method != "pgd_nonintrusive":  # silently ignored otherwise
        raise PhysarError(f"{' and '.join(given)}: only for [rom] method = \"pgd_nonintrusive\" (its snapshot "
                          f"solves); {config} has method = {cfg.rom.method!r}")
    bars: list = []  # drawn at the first progress report: checks and warnings of the set-up print before it

    def progress(done: int, total: int) -> None:
        if not bars:
            bars.append(tqdm(desc=f"rom build ({cfg.rom.method})", file=sys.stderr,
                             unit="mode" if cfg.rom.method == "pgd" else "solve"))
        bar = bars[0]
        if total and bar.total != total:
            bar.total = total
        bar.n = done
        bar.refresh()

    try:
        rom, space, _ = build_rom(cfg, progress, str(config), workers=workers, scheduler=scheduler)
    except PhysarError as exc:
        for b in bars:
            b.close()
        if str(exc).startswith(str(config)):
            raise
        raise type(exc)(f"{config}: {exc}") from None
    for b in bars:
        b.close()
    rom.save(out, space=space)
    summary = _info(rom)
    summary["output"] = str(out)
    if json_out:
        print_json(summary)
    else:
        log(f"wrote {out}: {rom.n_modes} modes, parameters {rom.names}, "
            f"build {rom.metadata['build_time_s']:.2f} s")
        for k in ("check_error", "error_estimate"):
            if k in rom.metadata:
                log(f"{k.replace('_', ' ')}: {rom.metadata[k]:.3e}")


def _kinds(rom) -> list:
    """Each parameter's kind: the model's own (format 2), else the build configuration's, else None."""
    kinds = getattr(rom, "kinds", None)
    if kinds:
        return list(kinds)
    params = rom.metadata.get("parameters")
    by_name = {p.get("name"): p.get("kind") for p in params if isinstance(p, dict)} if isinstance(params, list) else {}
    return [by_name.get(n) for n in rom.names]


def _info(rom) -> dict:
    from physar.rom import FORMAT_VERSION

    meta = dict(rom.metadata)
    d = {"format_version": FORMAT_VERSION, "method": meta.get("method"), "n_modes": rom.n_modes,
         "n_dofs": int(rom.F.shape[1]),
         "parameters": [{"name": n, "kind": k, "unit": u, "range": [float(r[0]), float(r[1])], "grid_points": int(g.size)}
                        for n, k, u, r, g in zip(rom.names, _kinds(rom), rom.units, rom.ranges, rom.grids)],
         "mode_amplitudes": rom.mode_amplitudes().tolist()}
    for k in ("check_error", "check_errors", "error_estimate", "n_solves", "build_time_s", "material", "element",
              "mesh_checksum", "path", "load", "radius"):
        if k in meta:
            d[k] = meta[k]
    if rom._mesh_arrays is not None:
        d["mesh"] = {"points": len(rom._mesh_arrays[0]), "cells": len(rom._mesh_arrays[1])}
    return d


@rom_app.command("info")
@user_errors
def info(
    model_file: Path = typer.Argument(..., help="reduced model (.npz)"),  # noqa: B008 - typer idiom
    check: Path | None = typer.Option(None, "--check", help="the model's `rom build` file: also report its "  # noqa: B008 - typer idiom
                                      "discretisation error against full solves on a twice finer mesh"),
    check_points: int = typer.Option(3, "--check-points", help="parameter points of --check (1-100)"),
    json_out: bool = typer.Option(False, "--json", help="print as JSON on stdout"),
) -> None:
    """Describe a reduced model: method, modes, parameters (kind, range, unit), mesh, error estimates; with
    --check CONFIG its error of displacement and von Mises stress against a finer check solve."""
    from physar.cli._common import check_toml
    from physar.errors import ConfigError
    from physar.rom import SeparatedModel

    if not 1 <= check_points <= 100:
        raise ConfigError(f"--check-points must be within 1..100, got {check_points}")
    check_toml(check, "rom build file (--check)")
    rom = SeparatedModel.load(model_file)
    d = _info(rom)
    if check is not None:
        from tqdm import tqdm

        from physar.rom.config import load_rom_config
        from physar.rom.quality import discretisation_error

        with tqdm(total=check_points, desc="check: full solves on a twice finer mesh", unit="point",
                  file=sys.stderr, leave=False,
                  disable=None if not json_out else True) as bar:
            chk = discretisation_error(load_rom_config(check), rom, points=check_points, source=str(check),
                                       progress=lambda k, n: bar.update(k - bar.n))
        d["check"] = chk.summary()
    if json_out:
        print_json(d)
        return
    for k, v in d.items():
        if k == "parameters":
            for p in v:
                lo, hi = p["range"]
                log(f"parameter {p['name']}: {p['kind'] or 'unspecified'}, range [{lo:.6g}, {hi:.6g}] {p['unit']}, "
                    f"{p['grid_points']} grid points")
        elif k == "mode_amplitudes":
            log(f"{k}: " + ", ".join(f"{a:.2e}" for a in v))
        elif k == "check":
            _log_check(v)
        else:
            log(f"{k}: {v}")


def _pct(v) -> str:
    return "n/a" if v is None else f"{100 * v:.2g} %"


def _log_check(c: dict) -> None:
    """The discretisation check in a few lines (worst over the points, then each point)."""
    log(f"check against a {c['refine']}x finer mesh ({c['dofs']} -> {c['fine_dofs']} dofs, {c['time_s']:.1f} s), "
        f"relative errors (L2 / max):")
    rows = [("displacement", "displacement"), ("von Mises, everywhere", "stress"),
            (f"von Mises, >= {1e3 * c['away_m']:.3g} mm from supports and loads", "away")]
    width = max(len(label) for label, _ in rows) + 1
    for label, key in rows:
        log(f"  {label + ':':<{width}} {_pct(c[key + '_l2'])} / {_pct(c[key + '_max'])}")
    for p in c["points"]:
        mu = ", ".join(f"{n}={v:.4g}" for n, v in p["params"].items())
        at = ", ".join(f"{x:.4g}" for x in p["stress_max_at"])
        log(f"  at {mu}: displacement {_pct(p['displacement_max'])}, von Mises {_pct(p['stress_max'])} (largest at "
            f"({at}) m), away {_pct(p['away_max'])}; peak {p['peak_von_mises']:.4g} Pa (finer mesh "
            f"{p['peak_von_mises_fine']:.4g} Pa)")


class _RepeatableProbe(TyperCommand):
    """`rom eval` with ``--probe X Y Z`` repeatable (typer has no list-of-tuples option: three values each)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        for p in self.params:
            if p.name == "probe":
                p.nargs = 3


def _probe_points(items) -> np.ndarray:
    from physar.errors import ConfigError

    try:
        return np.array([[float(v) for v in it] for it in items], float).reshape(-1, 3)
    except ValueError:
        bad = next(" ".join(it) for it in items if not all(_is_number(v) for v in it))
        raise ConfigError(f"--probe {bad}: expected three numbers x y z (m)") from None


def _is_number(v) -> bool:
    try:
        float(v)
    except ValueError:
        return False
    return True


@rom_app.command("eval", cls=_RepeatableProbe)
@user_errors
def evaluate(
    model_file: Path = typer.Argument(..., help="reduced model (.npz)"),  # noqa: B008 - typer idiom
    param: list[str] = typer.Option([], "--param", help="NAME=VALUE, one per parameter, e.g. s=0.3"),  # noqa: B008 - typer idiom
    probe: list[Any] = typer.Option([], "--probe", metavar="X Y Z",  # noqa: B008 - typer idiom
                                    help="probe point x y z \\[m]; repeat for more points"),
    out: Path | None = typer.Option(None, "--out", "-o", help="write the displacement field (.vtu/.xdmf)"),  # noqa: B008 - typer idiom
    json_out: bool = typer.Option(False, "--json", help="print results as JSON on stdout"),
) -> None:
    """Evaluate u(mu) of a reduced model, at probe points and/or on the whole mesh."""
    from physar.fem import probe as fe_probe
    from physar.geometry.io import VOLUME_FORMATS
    from physar.output import check_destination
    from physar.rom import SeparatedModel

    if out is not None:
        check_destination(out, inputs=[model_file], suffixes=sorted(VOLUME_FORMATS), kind="displacement field")
    pts = _probe_points(probe)
    rom = SeparatedModel.load(model_file)
    mu = _parse_params(rom, param)
    u = rom.evaluate(mu)
    space = rom.space() if (len(pts) or out) else None
    probes = [{"point": p.tolist(), "u": fe_probe(space, u, p).tolist()} for p in pts]
    res = {"params": dict(zip(rom.names, mu.tolist())),
           "max_displacement": float(np.linalg.norm(u.reshape(-1, 3), axis=1).max()), "probes": probes}
    if out is not None:
        from physar.geometry import write_mesh

        uv = space.vertex_values(u)
        write_mesh(out, space.mesh, point_data={"displacement": uv,
                                                "displacement_magnitude": np.linalg.norm(uv, axis=1)})
        res["output"] = str(out)
    if json_out:
        print_json(res)
    else:
        log(f"max displacement {res['max_displacement']:.6e} m at {res['params']}")
        for p in probes:
            log(f"probe {p['point']}: u = {p['u']}")


@user_errors
def assimilate_cmd(
    model_file: Path = typer.Argument(..., help="reduced model (.npz) with its mesh (from `physar rom build`)"),  # noqa: B008 - typer idiom
    observations: Path = typer.Argument(..., help="CSV with header x,y,z,ux,uy,uz (m)"),  # noqa: B008 - typer idiom
    mu0: list[str] = typer.Option([], "--mu0", help="start NAME=VALUE (default: centre of the ranges)"),  # noqa: B008 - typer idiom
    alpha: float = typer.Option(0.0, "--alpha", help="Tikhonov weight towards --mu0 (>= 0)"),
    noise: float | None = typer.Option(None, "--noise", help="std of the observation noise \\[m] if known "
                                                            "(default: estimated from the residual)"),
    false_alarm: float = typer.Option(1e-3, "--false-alarm", help="false-alarm rate of the test that decides "
                                                                  "a multi-start (0: never)"),
    model_error: float = typer.Option(0.01, "--model-error", help="relative error of the model on the "
                                                                  "observations, added to the noise [-]"),
    restart: float | None = typer.Option(None, "--restart-residual",
                                         help="deprecated: multi-start when ||r||/||u_obs|| stays above this "
                                              "(instead of the statistical test)"),
    json_out: bool = typer.Option(False, "--json", help="print results as JSON on stdout"),
) -> None:
    """Estimate the model parameters from observed displacements (Levenberg-Marquardt on the ROM)."""
    from physar.assimilation import assimilate, observation_matrix, read_observations
    from physar.errors import PhysarError
    from physar.rom import SeparatedModel

    if not (alpha >= 0 and np.isfinite(alpha)):
        raise PhysarError(f"--alpha must be a finite number >= 0, got {alpha}")
    for flag, v in (("--noise", noise), ("--model-error", model_error), ("--restart-residual", restart)):
        if v is not None and not (v >= 0 and np.isfinite(v)):
            raise PhysarError(f"{flag} must be a finite number >= 0, got {v}")
    if not 0 <= false_alarm < 1:
        raise PhysarError(f"--false-alarm must be within [0, 1), got {false_alarm}")
    if restart is not None:
        log("warning: --restart-residual is deprecated: the multi-start is decided by a statistical test "
             "(--false-alarm, --noise, --model-error)")
    rom = SeparatedModel.load(model_file)
    lo, hi = rom.mesh().bounds
    pts, disp = read_observations(observations, body_size=float(np.linalg.norm(hi - lo)))
    try:
        C = observation_matrix(rom.space(), pts)
    except PhysarError as exc:
        raise type(exc)(f"{observations}: {exc}") from None
    rom.set_observation(matrix=C)
    start = _parse_params(rom, mu0, "--mu0", partial=True) if mu0 else None
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)    # (said once above)
        res = assimilate(rom, disp.ravel(), mu0=start, alpha=alpha, restart_residual=restart,
                         false_alarm=false_alarm, noise=noise, model_error=model_error)
    out = {"params": dict(zip(rom.names, res.params.tolist())), "std": dict(zip(rom.names, res.std.tolist())),
           "residual": res.residual, "iterations": res.iterations, "time_us": res.time_us,
           "relative_residual": res.residual / max(float(np.linalg.norm(disp)), 1e-300),
           "observations": len(pts), "units": dict(zip(rom.names, rom.units)),
           "restarted": bool(res.restarted), "fit_ratio": float(res.fit_ratio) if np.isfinite(res.fit_ratio) else None}
    if json_out:
        print_json(out)
    else:
        for n, v, s, u in zip(rom.names, res.params, res.std, rom.units):
            log(f"{n} = {v:.6g} ± {s:.2g} {u}")
        log(f"residual {res.residual:.3e} m, {res.iterations} LM iterations, {res.time_us:.0f} µs")


def register(app: typer.Typer) -> None:
    app.add_typer(rom_app, name="rom")
    app.command("assimilate")(assimilate_cmd)
