"""`physar demo`: scene (a) of seed 000 §5.1 end to end.

Renders the synthetic video of the aluminium cantilever with a moving load, builds its reduced model by
PGD on a coarser mesh than the one that made the video, runs the AR pipeline on the video and writes
augmented.mp4, estimates.csv, estimate_vs_truth.png, augmented_frame.png and report.json (with a table
like the seed's Table 1: actual load position, mean estimate, absolute difference).
"""
from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from physar.ar.runner import pipeline_stats, run_scene_demo, write_report
from physar.ar.scene import Occlusion, SceneSpec, VideoSection, read_truth, render_scene


def demo_scene(quick: bool = False) -> SceneSpec:
    """The demo's scene (a): 1280x720 at 30 fps, 11 load positions from 460 mm to 60 mm (1.3 s each,
    14.3 s), a full occlusion of 30 frames while the load moves, two markers hidden for 20 frames and the
    middle of the beam hidden for 15 frames. ``quick``: 640x360, 5 positions (tests)."""
    if quick:
        return SceneSpec(
            video=VideoSection(width=640, height=360, duration=6.5, crf=18),
            load={"positions": [0.45, 0.35, 0.25, 0.15, 0.08], "dwell": 1.0, "move": 0.3},
            occlusion=[Occlusion(start=1.2, frames=30, kind="full")])
    return SceneSpec(
        video=VideoSection(duration=14.3),
        occlusion=[Occlusion(start=4.5, frames=30, kind="full"), Occlusion(start=7.0, frames=20, kind="markers"),
                   Occlusion(start=10.0, frames=15, kind="beam")])


def judged_frames(L: float, truth: dict, est: dict, recovery_frames: int = 5):
    """|s_est - s_true| (m) per frame and the frames the accuracy goal is judged on: tracking, the load beyond
    20 % of the span L from the clamp, and not the ``recovery_frames`` frames after a full occlusion (those are
    judged by the recovery criterion: the frames until the error is back within 1 % of the span, listed per
    occlusion). Returns (err, judged, recovery), over the frames both files have."""
    s_t, s_e = truth["s_true_m"], est["s_est"]
    n = min(len(s_t), len(s_e))
    err = np.abs(s_e[:n] - s_t[:n])
    tracking = est["status"][:n] == "tracking"
    full = np.array(["full" in o for o in truth["occluded"][:n]])
    after = np.zeros(n, bool)
    recovery = []
    for e in np.flatnonzero(full[:-1] & ~full[1:]) + 1:
        after[e:e + recovery_frames] = True
        ok = np.flatnonzero((err[e:e + 30] <= 0.01 * L) & tracking[e:e + 30])
        recovery.append(int(ok[0]) + 1 if ok.size else None)
    return err, tracking & (s_t[:n] >= 0.2 * L) & ~after, recovery


def evaluate(spec: SceneSpec, truth: dict, est: dict, recovery_frames: int = 5) -> dict:
    """Accuracy of the estimates against the truth (positions in mm)."""
    L = spec.beam.length
    err, judged, recovery = judged_frames(L, truth, est, recovery_frames)
    n = len(err)
    s_t, s_e = truth["s_true_m"][:n], est["s_est"][:n]
    tracking = est["status"][:n] == "tracking"
    occl_any = np.array([bool(o) for o in truth["occluded"][:n]])
    table = []
    for s in spec.load.positions:
        sel = tracking & (np.abs(s_t - s) < 1e-9)
        if sel.any():
            m = float(np.mean(s_e[sel]))
            table.append({"actual_mm": round(s * 1e3, 2), "mean_estimate_mm": round(m * 1e3, 2),
                          "abs_difference_mm": round(abs(m - s) * 1e3, 2), "frames": int(sel.sum())})
    return {
        "mean_abs_error_mm": float(np.mean(err[judged]) * 1e3) if judged.any() else float("nan"),
        "max_abs_error_mm": float(np.max(err[judged]) * 1e3) if judged.any() else float("nan"),
        "mean_abs_error_all_tracking_mm": float(np.mean(err[tracking]) * 1e3) if tracking.any() else float("nan"),
        "fraction_within_1pct_span": float(np.mean(err[judged] <= 0.01 * L)) if judged.any() else float("nan"),
        "judged_frames": int(judged.sum()),
        "tracking_frames": int(tracking.sum()),
        "occluded_frames": int(occl_any.sum()),
        "recovery_frames_after_full_occlusion": recovery,
        "table": table,
    }


def plot_estimates(spec: SceneSpec, truth: dict, est: dict, path) -> None:
    """Plot the estimated load against the truth over time, written to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    L = spec.beam.length
    n = min(len(truth["time_s"]), len(est["time_s"]))
    t = truth["time_s"][:n]
    s_t, s_e, sd = truth["s_true_m"][:n] * 1e3, est["s_est"][:n] * 1e3, est["s_std"][:n] * 1e3
    tracking = est["status"][:n] == "tracking"
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    occl = truth["occluded"][:n]
    for kind, col in (("full", "0.6"), ("markers", "tab:orange"), ("beam", "tab:purple")):
        m = np.array([kind in o for o in occl])
        if m.any():
            for ax in (a1, a2):
                ax.fill_between(t, 0, 1, where=m, transform=ax.get_xaxis_transform(), color=col, alpha=0.25,
                                lw=0, label=f"occlusion: {kind}" if ax is a1 else None)
    a1.plot(t, s_t, "k-", lw=2, label="true load position")
    a1.plot(t, s_e, "-", color="tab:blue", lw=1.2, label="AR estimate")
    sd = np.minimum(np.nan_to_num(sd, nan=0.0), 0.05 * L * 1e3)
    a1.fill_between(t, s_e - 2 * sd, s_e + 2 * sd, color="tab:blue", alpha=0.25, lw=0, label="estimate ± 2 sd")
    a1.axhline(0.2 * L * 1e3, color="0.4", ls=":", lw=1, label="20 % of span: goal ±1 % above it")
    a1.set_ylabel("load position s [mm]")
    a1.set_ylim(-0.02 * L * 1e3, 1.1 * L * 1e3)
    a1.set_title(f"Scene (a): aluminium cantilever, moving {spec.beam.load:.0f} N load - estimate vs truth")
    a1.legend(loc="upper right", fontsize=8, ncol=2)
    err = np.where(tracking, s_e - s_t, np.nan)
    far = s_t >= 0.2 * L * 1e3
    a2.plot(t, np.where(far, err, np.nan), color="tab:red", lw=1, label="estimate - truth")
    a2.plot(t, np.where(far, np.nan, err), color="tab:red", lw=1, alpha=0.35,
            label="load within 20 % of span (not judged)")
    a2.axhline(10 * L, color="0.3", ls="--", lw=1, label="±1 % of span")
    a2.axhline(-10 * L, color="0.3", ls="--", lw=1)
    a2.set_ylim(-30 * L, 30 * L)
    a2.set_xlabel("time [s]")
    a2.set_ylabel("error [mm]")
    a2.legend(loc="upper left", fontsize=8, ncol=3)
    fig.tight_layout()
    tmp = Path(path).with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)


def run_ar_demo(out, quick: bool = False, progress: Callable[[str, int, int], None] | None = None,
                spec: SceneSpec | None = None) -> dict:
    """Render scene (a), build its reduced model, run the AR pipeline; write the outputs into `out`."""
    from physar.ar.pipeline import ARPipeline, build_scene_model, read_estimates

    out, spec = Path(out), spec or demo_scene(quick)

    def build(p):
        rom, obj, space, _info = build_scene_model(spec, progress=p)
        rom.save(out / "model.npz", mesh=space.mesh)
        return rom, obj

    run = run_scene_demo(out, spec, progress, render_scene, "reduced model (PGD)", build,
                         lambda model, cam: ARPipeline(model[0], cam, model[1]), 0.45)
    rom = run.model[0]
    truth = read_truth(out / "truth.csv")
    est = read_estimates(out / "estimates.csv")
    ev = evaluate(spec, truth, est)
    plot_estimates(spec, truth, est, out / "estimate_vs_truth.png")
    report = {
        "example": "ar_cantilever",
        "scene": {"width": spec.video.width, "height": spec.video.height, "fps": spec.video.fps,
                  "duration_s": spec.video.duration, "beam_mm": [spec.beam.length * 1e3, spec.beam.width * 1e3,
                                                                 spec.beam.height * 1e3],
                  "E_pa": spec.beam.E, "nu": spec.beam.nu, "load_n": spec.beam.load, "dots": spec.beam.dots,
                  "truth_mesh": list(spec.beam.truth_cells), "model_mesh": list(spec.beam.model_cells)},
        **pipeline_stats(run.summary),
        "modes": rom.n_modes,
        **ev,
        "timings_s": run.timings_s,
        "files": ["scene.mp4", "truth.csv", "camera.toml", "model.npz", "augmented.mp4", "estimates.csv",
                  "estimate_vs_truth.png", "augmented_frame.png", "report.json"],
    }
    write_report(out, report)
    return report
