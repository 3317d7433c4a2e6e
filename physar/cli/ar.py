"""`physar calibrate`, `physar scene render|model`, `physar ar run`: the augmented-reality pipeline (seed 000)."""

from __future__ import annotations

from pathlib import Path

import typer

from physar.cli._common import log, print_json, user_errors


def _bar(desc: str):
    from tqdm import tqdm

    state = {}

    def cb(k, n):
        if "bar" not in state:
            state["bar"] = tqdm(total=n or None, desc=desc, unit="frame", leave=False, file=__import__("sys").stderr)
        state["bar"].update(k - state["bar"].n)
        if n and k >= n:
            state["bar"].close()

    return cb


def calibrate(
    images: list[Path] = typer.Argument(..., help="ChArUco board images (PNG/JPG)"),  # noqa: B008 - typer idiom
    output: Path = typer.Option(Path("camera.toml"), "--output", "-o", help="camera file to write"),  # noqa: B008 - typer idiom
    squares: str = typer.Option("7x5", help="board squares, COLSxROWS"),
    square: float = typer.Option(0.04, help="square side [m]"),
    marker: float = typer.Option(0.03, help="marker side [m]"),
    dictionary: str = typer.Option("DICT_5X5_100", help="ArUco dictionary of the board"),
    dist: int = typer.Option(5, help="distortion coefficients: 0, 2, 5 or 8"),
    json_out: bool = typer.Option(False, "--json", help="print the result as JSON"),
) -> None:
    """Calibrate a camera from ChArUco images; writes intrinsics + distortion as TOML."""
    from physar.errors import ConfigError
    from physar.vision.calibration import CharucoSpec, calibrate_charuco

    try:
        sx, sy = (int(v) for v in squares.lower().split("x"))
    except ValueError:
        raise ConfigError(f"--squares must look like 7x5, got {squares!r}") from None
    spec = CharucoSpec(sx, sy, square, marker, dictionary)
    cam, info = calibrate_charuco(images, spec, dist_coeffs=dist, progress=_bar("calibrate"))
    cam.save(output, rms_px=info["rms_px"])
    res = {"camera_file": str(output), "fx": cam.fx, "fy": cam.fy, "cx": float(cam.K[0, 2]),
           "cy": float(cam.K[1, 2]), "distortion": cam.dist, "rms_px": info["rms_px"],
           "images_used": len(info["images_used"]), "images_total": info["images_total"]}
    if json_out:
        print_json(res)
    else:
        log(f"fx {cam.fx:.2f} fy {cam.fy:.2f} px, reprojection rms {info['rms_px']:.3f} px from "
            f"{res['images_used']}/{res['images_total']} images; wrote {output}")


def _scene_kind(path: Path) -> str:
    """The scene's `name` (cantilever | foam | seal) from its TOML, with a one-line error if unreadable."""
    from physar.ar.scene import read_scene_toml

    return str(read_scene_toml(path).get("name", "cantilever"))


def scene_render(
    scene: Path = typer.Argument(..., help="scene TOML (examples/scene_cantilever.toml, scene_foam.toml, scene_seal.toml)"),  # noqa: B008 - typer idiom
    out: Path = typer.Option(Path("scene_out"), "--out", "-o", help="output folder"),  # noqa: B008 - typer idiom
    json_out: bool = typer.Option(False, "--json"),
) -> None:
    """Render a synthetic AR scene: scene.mp4 (H.264), truth.csv, camera.toml."""
    kind = _scene_kind(scene)
    if kind == "foam":
        from physar.ar.foam import load_foam_scene, render_foam_scene

        res = render_foam_scene(load_foam_scene(scene), out, progress=_bar("render"))
    elif kind == "seal":
        from physar.ar.seal import load_seal_scene, render_seal_scene

        res = render_seal_scene(load_seal_scene(scene), out, progress=_bar("render"))
    else:
        from physar.ar.scene import load_scene, render_scene

        res = render_scene(load_scene(scene), out, progress=_bar("render"))
    if json_out:
        print_json(res)
    else:
        log(f"rendered {res['frames']} frames {res['width']}x{res['height']} -> {res['video']}, {res['truth']}")


def scene_model(
    scene: Path = typer.Argument(..., help="scene TOML"),  # noqa: B008 - typer idiom
    output: Path = typer.Option(Path("model.npz"), "--output", "-o", help="reduced model file to write"),  # noqa: B008 - typer idiom
    json_out: bool = typer.Option(False, "--json"),
) -> None:
    """Build the reduced (PGD) model of a scene's object, with the AR object description, as .npz."""
    kind = _scene_kind(scene)
    if kind == "foam":
        from physar.ar.foam import build_foam_model, load_foam_scene

        rom, _, space, _ = build_foam_model(load_foam_scene(scene), progress=_bar("snapshots"))
        rom.save(output, mesh=space.mesh)
    elif kind == "seal":
        from physar.ar.seal import build_seal_model, load_seal_scene

        rom, vm, seal, _ = build_seal_model(load_seal_scene(scene), progress=_bar("snapshots"))
        space = seal.space
        rom.save(output, mesh=space.mesh)
        vm_path = output.with_name(output.stem + "_von_mises.npz")
        vm.save(vm_path, mesh=space.mesh)
        log(f"von Mises model -> {vm_path}")
    else:
        from physar.ar.pipeline import build_scene_model
        from physar.ar.scene import load_scene

        rom, _obj, space, _info = build_scene_model(load_scene(scene))
        rom.save(output, mesh=space.mesh)
    res = {"model": str(output), "modes": rom.n_modes, "dofs": space.n_dofs, "parameters": rom.names}
    if json_out:
        print_json(res)
    else:
        log(f"{rom.n_modes} modes on {space.n_dofs} dofs -> {output}")


def ar_run(
    model: Path = typer.Argument(..., help="reduced model .npz (physar scene model)"),  # noqa: B008 - typer idiom
    video: Path | None = typer.Argument(None, help="input video (omit with --camera)"),  # noqa: B008 - typer idiom
    camera_file: Path = typer.Option(..., "--camera-file", help="camera TOML (physar calibrate)"),  # noqa: B008 - typer idiom
    out: Path | None = typer.Option(None, "--out", "-o", help="augmented video (.mp4) to write"),  # noqa: B008 - typer idiom
    csv_out: Path | None = typer.Option(None, "--csv", help="per-frame estimates CSV"),  # noqa: B008 - typer idiom
    camera: int | None = typer.Option(None, "--camera", help="live camera index instead of a video file"),
    field: str = typer.Option("von_mises", help="overlay field: von_mises or u"),
    max_frames: int | None = typer.Option(None, help="stop after this many frames"),
    preset: str = typer.Option("ultrafast", help="libx264 preset of the augmented video (ultrafast ... veryslow)"),
    crf: int = typer.Option(20, help="libx264 constant rate factor (quality; lower = better, 0-51)"),
    json_out: bool = typer.Option(False, "--json"),
) -> None:
    """Run the AR pipeline: markers -> pose -> dots -> assimilation -> overlay."""
    from physar.ar.pipeline import ARPipeline
    from physar.ar.video import CameraSource
    from physar.errors import ConfigError
    from physar.rom import SeparatedModel
    from physar.vision.camera import Camera

    if (video is None) == (camera is None):
        raise ConfigError("give either a VIDEO file or --camera INDEX")
    if field not in ("von_mises", "u"):
        raise ConfigError(f"--field must be von_mises or u, got {field!r}")
    presets = ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower", "veryslow")
    if preset not in presets:
        raise ConfigError(f"--preset must be one of {', '.join(presets)}, got {preset!r}")
    if not 0 <= crf <= 51:
        raise ConfigError(f"--crf must be within 0..51, got {crf}")
    cam = Camera.load(camera_file)
    if not Path(model).is_file():
        raise ConfigError(f"{model}: reduced model file not found")
    if video is not None:  # open (and decode the first frame of) the input before the expensive setup
        from physar.ar.video import VideoReader

        source = VideoReader(video, convert="opencv")
    else:
        source = CameraSource(camera, cam.width, cam.height)
    if (source.width, source.height) != cam.size:
        raise ConfigError(f"{video or f'camera {camera}'} is {source.width}x{source.height} but {camera_file} is "
                          f"for {cam.width}x{cam.height}")
    rom = SeparatedModel.load(model)
    pipe = ARPipeline(rom, cam, field=field)
    summary = pipe.run(source, out, csv_out, progress=_bar("AR"), max_frames=max_frames, preset=preset, crf=crf)
    summary.pop("results")
    if json_out:
        print_json(summary)
    else:
        log(f"{summary['frames']} frames at {summary['fps']:.1f} fps, median latency "
            f"{summary['latency_ms_median']:.2f} ms" + (f"; wrote {out}" if out else ""))


def register(app: typer.Typer) -> None:
    app.command("calibrate")(user_errors(calibrate))
    scene = typer.Typer(help="Synthetic AR scenes (render video + truth, build the reduced model).",
                        no_args_is_help=True)
    scene.command("render")(user_errors(scene_render))
    scene.command("model")(user_errors(scene_model))
    app.add_typer(scene, name="scene")
    ar = typer.Typer(help="Augmented-reality pipeline.", no_args_is_help=True)
    ar.command("run")(user_errors(ar_run))
    app.add_typer(ar, name="ar")
