"""`physar calibrate`, `physar ar run|init|print-markers`: the augmented-reality pipeline (seed 000)."""

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
    images: list[Path] = typer.Argument(None, help="ChArUco board images (PNG/JPG)"),  # noqa: B008 - typer idiom
    output: Path = typer.Option(Path("camera.toml"), "--out", "--output", "-o", help="camera file to write"),  # noqa: B008 - typer idiom
    squares: str = typer.Option("7x5", help="board squares, COLSxROWS"),
    square: float = typer.Option(0.04, help="square side \\[m]"),
    marker: float = typer.Option(0.03, help="marker side \\[m]"),
    dictionary: str = typer.Option("DICT_5X5_100", help="ArUco dictionary of the board"),
    dist: int = typer.Option(5, help="distortion coefficients: 0, 2, 5 or 8"),
    print_board: Path | None = typer.Option(None, "--print-board", help="write this board at true scale (.pdf "  # noqa: B008
                                                                          "or .png, print at 100 %) and stop"),
    dpi: float = typer.Option(300, help="--print-board: raster resolution \\[dots per inch]"),
    json_out: bool = typer.Option(False, "--json", help="print the result as JSON"),
) -> None:
    """Calibrate a camera from ChArUco images; writes intrinsics + distortion as TOML. With --print-board,
    write the board to print instead."""
    from physar.errors import ConfigError
    from physar.output import check_destination
    from physar.vision.calibration import CharucoSpec, calibrate_charuco

    try:
        sx, sy = (int(v) for v in squares.lower().split("x"))
    except ValueError:
        raise ConfigError(f"--squares must look like 7x5, got {squares!r}") from None
    spec = CharucoSpec(sx, sy, square, marker, dictionary)
    if print_board is not None:
        from physar.vision.printing import write_board_sheet

        check_destination(print_board, suffixes=[".pdf", ".png"], kind="board sheet")
        res = write_board_sheet(spec, print_board, dpi=dpi)
        if json_out:
            print_json({"board_file": str(res.get("path", print_board)), "squares": [sx, sy], "square_m": square,
                        "marker_m": marker, "dictionary": dictionary})
        else:
            log(f"wrote the {squares} board ({square * 1e3:g} mm squares, {marker * 1e3:g} mm markers, {dictionary}) "
                f"to {res.get('path', print_board)}: print at 100 % (no fit-to-page), then photograph it")
        return
    if not images:
        raise ConfigError("give the board images to calibrate from (or --print-board FILE to print the board)")
    check_destination(output, inputs=images, suffixes=[".toml"], kind="camera file")
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


def ar_run(
    project: Path = typer.Argument(..., help="AR project file (.toml; `physar ar init`)"),  # noqa: B008 - typer idiom
    source: str | None = typer.Argument(None, help="video file, camera index (0, 1, ...) or stream URL "
                                                    "(rtsp://, tcp://, udp://, http://...)"),
    out: Path | None = typer.Option(None, "--out", "-o", help="augmented video (.mp4) to write"),  # noqa: B008 - typer idiom
    csv_out: Path | None = typer.Option(None, "--csv", help="per-frame estimates CSV"),  # noqa: B008 - typer idiom
    camera: int | None = typer.Option(None, "--camera", help="live camera index instead of a video file"),
    field: str | None = typer.Option(None, help="overlay field: von_mises, u, ux, uy, uz; default the project's"),
    max_frames: int | None = typer.Option(None, help="stop after this many frames"),
    preset: str = typer.Option("ultrafast", help="libx264 preset of the augmented video (ultrafast ... veryslow)"),
    crf: int = typer.Option(20, help="libx264 constant rate factor (quality; lower = better, 0-51)"),
    json_out: bool = typer.Option(False, "--json"),
) -> None:
    """Run the AR pipeline on a video, a camera or a stream: markers -> pose -> dots -> assimilation -> overlay."""
    from physar.errors import ConfigError

    if project.suffix.lower() != ".toml":
        raise ConfigError(f"{project}: give an AR project file (physar ar init project.toml)")
    if (source is None) == (camera is None):
        raise ConfigError("give either a SOURCE (video file, camera index or URL) or --camera INDEX")
    presets = ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower", "veryslow")
    if preset not in presets:
        raise ConfigError(f"--preset must be one of {', '.join(presets)}, got {preset!r}")
    if not 0 <= crf <= 51:
        raise ConfigError(f"--crf must be within 0..51, got {crf}")
    if max_frames is not None and max_frames < 1:
        raise ConfigError(f"--max-frames must be >= 1, got {max_frames}")
    spec = source if source is not None else str(camera)
    summary, dictionary = _run_project(project, spec, out, csv_out, field, max_frames, preset, crf)
    summary.pop("results", None)
    if json_out:
        print_json(summary)
    else:
        log(("interrupted after " if summary.get("interrupted") else "") +
            f"{summary['frames']} frames at {summary['fps']:.1f} fps, median latency "
            f"{summary['latency_ms_median']:.2f} ms" + (f"; wrote {out}" if out else "")
            + (f" and {csv_out}" if csv_out else ""))
    counts = summary.get("status_counts", {})
    if summary["frames"] and not counts.get("tracking", 0):
        unseen = dictionary is not None and summary.get("marker_frames", 1) == 0
        hidden = summary.get("hidden_frames", 0)
        log(f"warning: no frame was tracked ({', '.join(f'{v} {k}' for k, v in sorted(counts.items()))}): "
            + (f"no marker of the project was found in any frame: check [[marker]] dictionary = \"{dictionary}\" "
               "(the ArUco dictionary of the printed markers; `physar ar print-markers` prints the project's) and "
               "each [[marker]] id and size (m); " if unseen and counts.get("lost", 0) else
               "no pose from the markers: check each [[marker]] id, size (m), center, normal and up against the "
               "printed markers; " if counts.get("lost", 0) else "")
            + (f"the object itself hid the dots in {hidden} frames: film from a side where they are in view; "
               if hidden else "")
            + ("too few dots or features found: check [dots] colour, diameter and points, [tracking] min_dots"
               if counts.get("hold", 0) > hidden else "").rstrip("; "))
    if summary.get("interrupted"):
        raise typer.Exit(code=130)  # Ctrl-C / SIGTERM: the outputs up to the last frame are complete


def _open(spec: str, cam, what: str):
    """The frame source of SOURCE (see physar.ar.sources), its size checked against the camera file."""
    from physar.ar.sources import open_source
    from physar.errors import ConfigError

    src = open_source(spec, width=cam.width, height=cam.height, convert="opencv")
    if (src.width, src.height) != cam.size:
        src.close()  # stops the decoding thread first: left running, it aborted the interpreter at exit
        raise ConfigError(f"{spec} is {src.width}x{src.height} but {what} is for {cam.width}x{cam.height}"
                          + cam.size_hint(src.width, src.height))
    return src


def _run_project(project_path, spec, out, csv_out, field, max_frames, preset, crf):
    from physar.ar.project import FIELDS, load_project
    from physar.ar.project_pipeline import ProjectPipeline
    from physar.errors import ConfigError

    if field is not None and field not in FIELDS:
        raise ConfigError(f"--field must be one of {', '.join(FIELDS)}, got {field!r}")
    from physar.output import check_destination, csv_header_starts

    for path, suf, kind, ours in ((out, [".mp4"], "augmented video", None),
                                  (csv_out, [".csv"], "estimates CSV", csv_header_starts("frame", "time_s", "status"))):
        if path is not None:
            check_destination(path, inputs=[project_path, spec], suffixes=suf, kind=kind, replaces=ours)
    from physar.ar.project import project_camera
    from physar.ar.sources import is_url

    cam, sc = project_camera(project_path)
    what = f"{project_path} [camera] file" + (f" scaled by {sc:g}" if sc != 1 else "")
    if not is_url(spec) and not spec.isdigit() and Path(spec).is_file():
        _open(spec, cam, what).close()  # a video file's size checked before the model is (re)built
    project = load_project(project_path, progress=_bar("model"))
    if field is not None:
        project.config.overlay.field = field
    pipe = ProjectPipeline(project)      # built before the source opens: a live source drops frames meanwhile
    src = _open(spec, project.camera, what)
    try:
        summary = pipe.run(src, out, csv_out, progress=_bar("AR"), max_frames=max_frames, preset=preset, crf=crf,
                           keep_results=False)  # running statistics only: bounded memory on a live source
    finally:
        src.close()  # the reader's thread stopped before the interpreter ends, on an error too
    return summary, (project.config.marker[0].dictionary if project.config.marker else None)


def ar_serve(
    project: Path = typer.Argument(..., help="AR project file (.toml; `physar ar init`)"),  # noqa: B008 - typer idiom
    host: str = typer.Option("127.0.0.1", help="interface to listen on; another than loopback needs TLS "
                                               "and prints a URL with an access token"),
    port: int = typer.Option(8765, help="TCP port (0: any free one)"),
    tls: tuple[str, str] = typer.Option(("", ""), "--tls", help="PEM certificate and key files",
                                        metavar="CERT KEY", show_default=False),
    self_signed: bool = typer.Option(False, "--self-signed", help="make a certificate for this run "
                                                                  "(the browser asks to accept it once)"),
    out: Path | None = typer.Option(None, "--out", "-o", help="record the augmented video (.mp4)"),  # noqa: B008
    csv_out: Path | None = typer.Option(None, "--csv", help="record the per-frame estimates (.csv)"),  # noqa: B008
    quality: int = typer.Option(80, help="JPEG quality of the augmented frames sent to the pages (1-100)"),
    json_out: bool = typer.Option(False, "--json", help="print the session summary as JSON at the end"),
) -> None:
    """Serve live AR to a web browser: open the printed URL (a phone on the same network with --host 0.0.0.0
    --self-signed), press "Start camera", see the object augmented. Ctrl-C ends; recordings are then complete."""
    import sys

    from physar.ar.live import is_loopback, self_signed_context, serve, tls_context
    from physar.ar.project import load_project
    from physar.errors import ConfigError
    from physar.output import check_destination

    if project.suffix.lower() != ".toml":
        raise ConfigError(f"{project}: give an AR project file (physar ar init project.toml)")
    if not project.is_file():
        raise ConfigError(f"{project}: AR project file not found" + (" (it is a folder)" if project.is_dir() else ""))
    if not 0 <= port <= 65535:
        raise ConfigError(f"--port must be within 0..65535, got {port}")
    if not 1 <= quality <= 100:
        raise ConfigError(f"--quality must be within 1..100, got {quality}")
    cert, key = (Path(tls[0]), Path(tls[1])) if tls[0] else (None, None)
    if self_signed and cert is not None:
        raise ConfigError("give either --tls CERT KEY or --self-signed, not both")
    from physar.output import csv_header_starts

    for path, suf, kind, ours in ((out, [".mp4"], "augmented video", None),
                                  (csv_out, [".csv"], "estimates CSV", csv_header_starts("frame", "time_s", "status"))):
        if path is not None:
            check_destination(path, inputs=[project], suffixes=suf, kind=kind, replaces=ours)
    ctx, fingerprint = None, None
    if cert is not None:
        ctx = tls_context(cert, key)
    elif self_signed:
        from physar.ar.live import lan_address

        ctx, fingerprint = self_signed_context(["localhost", "127.0.0.1", lan_address()]
                                               + ([host] if host not in ("0.0.0.0", "::") else []))
    if not is_loopback(host) and ctx is None:
        raise ConfigError(f"--host {host} lets other machines in: give --tls CERT KEY or --self-signed "
                          "(a phone's browser opens its camera only on an https page)")
    proj = load_project(project, progress=_bar("model"))

    def ready(url):
        log(f"serving {project} on {url}")
        if fingerprint:
            log(f"self-signed certificate, SHA-256 {fingerprint}")
        if not is_loopback(host):
            import segno

            segno.make(url, error="l").terminal(out=sys.stderr, compact=True)
        log("open it in a browser, press Start camera; Ctrl-C stops" + (" and finishes the recording"
                                                                         if out or csv_out else ""))

    summary = serve(proj, host=host, port=port, ssl_context=ctx, out_video=out, out_csv=csv_out,
                    quality=quality, ready=ready)
    if summary.get("error"):
        log(f"error: the live session stopped: {summary['error']}")
        raise typer.Exit(code=1)
    if json_out:
        print_json(summary)
    elif summary.get("frames"):
        log(f"{summary['frames']} frames at {summary['fps']:.1f} fps, {summary.get('dropped', 0)} dropped, median "
            f"latency {summary['latency_ms_median']:.1f} ms" + (f"; wrote {out}" if out else "")
            + (f" and {csv_out}" if csv_out else ""))
    else:
        log("no camera frame came; nothing recorded")


def ar_print_markers(
    project: Path = typer.Argument(..., help="AR project file"),  # noqa: B008 - typer idiom
    output: Path = typer.Option(Path("markers.pdf"), "--out", "-o", help="sheet to write (.pdf or .png)"),  # noqa: B008 - typer idiom
    dpi: float = typer.Option(300, help="resolution of the raster \\[dots per inch]"),
) -> None:
    """Write the project's markers at true size (print at 100 %, no scaling) with their ids and sides."""
    from physar.ar.project import parse_project, read_project_toml
    from physar.output import check_destination
    from physar.vision.printing import write_marker_sheet

    cfg = parse_project(read_project_toml(project), str(project))
    if not cfg.marker:
        from physar.errors import ConfigError

        raise ConfigError(f"{project}: the project has no [[marker]] tables to print")
    check_destination(output, inputs=[project], suffixes=[".pdf", ".png"], kind="marker sheet")
    res = write_marker_sheet([(m.dictionary, m.id, m.size) for m in cfg.marker], output, dpi=dpi)
    log(f"wrote {len(cfg.marker)} markers to {res.get('path', output)}: print at 100 % (no fit-to-page)")


def ar_init(
    output: Path = typer.Argument(Path("project.toml"), help="project file to write"),  # noqa: B008 - typer idiom
    force: bool = typer.Option(False, "--force", help="overwrite an existing file"),
) -> None:
    """Write a commented AR project template (model, camera, markers, dots, overlay) to edit for your object."""
    from physar.ar.project import TEMPLATE
    from physar.errors import ConfigError
    from physar.output import check_destination
    from physar.vision.camera import _atomic_write_text

    if output.exists() and not force:
        raise ConfigError(f"{output} exists; pass --force to overwrite it")
    if output.is_dir():
        raise ConfigError(f"{output} is a folder; give a file name such as {output / 'project.toml'}")
    if not output.parent.is_dir() if str(output.parent) else False:
        raise ConfigError(f"{output.parent}: folder not found")
    check_destination(output, suffixes=[".toml"], kind="AR project file")  # `init x.json`, `init newdir/`
    _atomic_write_text(output, TEMPLATE)
    log(f"wrote {output}: edit [model], [camera], [[marker]] and [dots], then `physar ar run {output} VIDEO`")


def register(app: typer.Typer) -> None:
    app.command("calibrate")(user_errors(calibrate))
    ar = typer.Typer(help="Augmented-reality pipeline.", no_args_is_help=True)
    ar.command("run")(user_errors(ar_run))
    ar.command("init")(user_errors(ar_init))
    ar.command("serve")(user_errors(ar_serve))
    ar.command("print-markers")(user_errors(ar_print_markers))
    app.add_typer(ar, name="ar")
