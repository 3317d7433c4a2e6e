"""Benchmark of the PhysHO reconstruction at >= 256 px on this CPU (issue 17, part 3 "Resolution"): training
time and peak memory of the reduced synthetic scene of ``examples/recon_bench.toml`` rendered at ``--size``
px (default 256), and the Gaussian rasteriser's forward + backward time per frame at 256 and 512 px.

    .venv/bin/python benchmarks/bench_recon_resolution.py [--config examples/recon_bench.toml] [--size 256]
        [--out /tmp/bench_recon_resolution] [--raster-sizes 256 512] [--repeats 5] [--no-fit]
        [--omp default passive 1thread]
    .venv/bin/python benchmarks/bench_recon_resolution.py --config examples/recon_pillow.toml --out /tmp/brr_pillow

The second command runs the pillow scene of the issue-8 tables (8 particles per cell in the reconstruction, truth
at 27) instead of the reduced one (1 per cell).

Training: ``physar.recon.synth.generate`` writes the scene (the config's ``[synth]`` with ``image_size`` =
``--size``), then ``physar.recon.train.fit`` runs all stages with the config's ``[train]`` (appearance +
fine-tuning on the spin clip, 4DGS-like and Eq. 9 flows, physics, evaluation and preview) in a child process:
wall time per stage (from the progress callback), total, and the child's peak RSS (``ru_maxrss`` of
``RUSAGE_CHILDREN``); the load average is sampled every 5 s during the run (mean and max printed).

Rasteriser: the fitted appearance (``RUN/model.npz``) with the scene's camera scaled to each size (same field
of view), frame ``n_obs // 2`` of the clip with the object at rest and the body posed by LBS; one forward
(``render_scene`` + the L1 image loss of ``fit``) and one backward (gradients w.r.t. colours, opacities and
scales, as in the appearance stage) per repeat, median over ``--repeats`` after one warm-up.

``--omp`` selects the OpenMP settings of the child processes (each a fresh interpreter: libgomp reads its
environment when torch is imported): ``default`` (2 threads, libgomp's default spin-waiting),
``passive`` (2 threads, ``OMP_WAIT_POLICY=PASSIVE``: idle threads sleep instead of spinning), ``1thread``
(``OMP_NUM_THREADS=1``).  On this shared 2-core machine, under load from other processes, libgomp's
spin-waiting made every small torch operation wait for a descheduled thread (a 32 px render: 2.1 s
against 0.012 s passive, load 7; see benchmarks/RESULTS.md).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import threading
import time
from pathlib import Path

OMP_ENV = {"default": {}, "passive": {"OMP_WAIT_POLICY": "PASSIVE"}, "1thread": {"OMP_NUM_THREADS": "1"}}


def _child_env(mode: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "OMP_NUM_THREADS", "GOMP_SPINCOUNT")}
    env.update(OMP_ENV[mode])
    return env


class LoadSampler:
    """os.getloadavg()[0] every ``every`` seconds in a daemon thread."""

    def __init__(self, every: float = 5.0):
        self.samples = [os.getloadavg()[0]]
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, args=(every,), daemon=True)
        self._t.start()

    def _run(self, every):
        while not self._stop.wait(every):
            self.samples.append(os.getloadavg()[0])

    def stop(self) -> dict:
        self._stop.set()
        self._t.join()
        self.samples.append(os.getloadavg()[0])
        return {"mean": sum(self.samples) / len(self.samples), "max": max(self.samples),
                "start": self.samples[0], "end": self.samples[-1]}


# ------------------------------------------------------------------------------------------- child jobs
def job_generate(config: str, size: int, data: Path) -> dict:
    from physar.recon.synth import generate, load_synth_config

    t = time.perf_counter()
    generate(data, load_synth_config(config, {"image_size": size}))
    return {"seconds": time.perf_counter() - t}


def job_fit(config: str, data: Path, run: Path) -> dict:
    from physar.recon.train import fit, load_train_config

    marks: dict[str, list[float]] = {}
    t0 = time.perf_counter()

    def progress(stage, i, n, loss):  # evaluate reports its renders per method, with loss 0.0
        now = time.perf_counter() - t0
        marks.setdefault(("evaluate: " if loss == 0.0 else "") + stage, [now, now])[1] = now

    rep = fit(data, run, load_train_config(config), restart=True, progress=progress)
    total = time.perf_counter() - t0
    return {"seconds": total, "train_seconds": rep["train_seconds"], "marks": marks,
            "loss_physics_last": rep["history_final"]["physics"],
            "recon_large_psnr_physics": rep["methods"]["physics"].get("recon_large", {}).get("psnr"),
            "E_error": rep.get("material", {}).get("mean_abs_log10_error")}


def job_raster(config: str, data: Path, run: Path | None, sizes: list[int], repeats: int) -> dict:
    import numpy as np
    import torch

    from physar.recon.train import (
        Appearance,
        Reconstruction,
        Rig,
        image_loss,
        load_dataset,
        load_train_config,
        render_scene,
    )

    ds = load_dataset(data, with_truth=False)
    cfg = load_train_config(config)
    f = ds.n_obs // 2
    out = {"threads": torch.get_num_threads(), "frame": f, "sizes": {}}
    for s in sizes:
        c = dict(ds.meta["camera"])
        k = s / c["width"]
        c.update(fx=c["fx"] * k, fy=c["fy"] * k, cx=c["cx"] * k, cy=c["cy"] * k, width=s,
                 height=round(c["height"] * k))
        rig = Rig({**ds.meta, "camera": c}, cfg, poses=(ds.rotations, ds.root_t))
        app = Reconstruction.load(run).app if run is not None and (run / "model.npz").exists() else Appearance.init(rig)
        if app.sh.shape[0] != rig.no + rig.nh + rig.nb:  # the kinematic body Gaussians depend on the view
            app = Appearance.init(rig)
        app = Appearance(*[t.detach().clone().requires_grad_(True) for t in app.params()])
        kin = rig.kinematics(ds.rotations, ds.root_t)
        Xo = torch.as_tensor(rig.Xo)
        I_o = torch.eye(3, dtype=torch.float64).expand(rig.no, 3, 3)
        img = torch.as_tensor(np.asarray(ds.rgb[f]))
        gt = torch.nn.functional.interpolate(img.permute(2, 0, 1)[None], size=(c["height"], s), mode="bilinear",
                                             align_corners=False)[0].permute(1, 2, 0)
        mk = torch.nn.functional.interpolate(torch.as_tensor(np.asarray(ds.mask[f]))[None, None],
                                             size=(c["height"], s), mode="bilinear", align_corners=False)[0, 0]
        fw, bw = [], []
        pairs = 0
        for r in range(repeats + 1):
            t = time.perf_counter()
            res = render_scene(rig, app, Xo, I_o, kin["ref"][f], kin["A_h"][f], kin["xb"][f], kin["A_b"][f])
            loss = image_loss(res, gt, mk, cfg)
            t1 = time.perf_counter()
            loss.backward()
            t2 = time.perf_counter()
            for p in app.params():
                p.grad = None
            pairs = res.n_pairs
            if r:
                fw.append(t1 - t)
                bw.append(t2 - t1)
        med = lambda v: float(np.median(v))
        out["sizes"][str(s)] = {"forward": med(fw), "backward": med(bw), "total": med(np.add(fw, bw)),
                                "pairs": pairs, "gaussians": int(app.sh.shape[0]), "load": os.getloadavg()[0]}
    return out


def _run_child(mode: str, args: list[str]) -> tuple[dict, float]:
    """Run this script as a child job with the OpenMP settings of ``mode``; (its JSON result, its peak RSS
    in MiB, from RUSAGE_CHILDREN: the maximum over the children waited for so far)."""
    p = subprocess.run([sys.executable, __file__, *args], env=_child_env(mode), capture_output=True, text=True,
                       check=False)
    if p.returncode != 0:
        sys.stderr.write(p.stderr[-4000:])
        raise SystemExit(f"child {args[:2]} failed ({p.returncode})")
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")][-1]
    return json.loads(line[7:]), resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default="examples/recon_bench.toml")
    ap.add_argument("--size", type=int, default=256, help="image side of the training scene, px")
    ap.add_argument("--out", default="/tmp/bench_recon_resolution")
    ap.add_argument("--raster-sizes", type=int, nargs="+", default=[256, 512])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--no-fit", action="store_true", help="rasteriser timings only (the scene is generated if "
                    "missing; the appearance is the initial one unless OUT/run exists)")
    ap.add_argument("--omp", nargs="+", default=["passive"], choices=list(OMP_ENV),
                    help="OpenMP settings of the training run (the first) and of the rasteriser timings (each)")
    ap.add_argument("--job", help=argparse.SUPPRESS)
    a = ap.parse_args()
    out = Path(a.out)
    data, run = out / f"data{a.size}", out / f"run{a.size}"
    if a.job:  # child process
        if a.job == "generate":
            res = job_generate(a.config, a.size, data)
        elif a.job == "fit":
            res = job_fit(a.config, data, run)
        else:
            res = job_raster(a.config, data, run if run.exists() else None, a.raster_sizes, a.repeats)
        print("RESULT " + json.dumps(res))
        return
    common = ["--config", a.config, "--size", str(a.size), "--out", str(out)]
    out.mkdir(parents=True, exist_ok=True)
    print(f"# bench_recon_resolution: {a.config}, {a.size} px, {os.cpu_count()} CPUs; "
          f"{time.strftime('%Y-%m-%d %H:%M:%S')}; uptime load {os.getloadavg()}")
    if not (data / "scene.json").exists():
        g, _ = _run_child(a.omp[0], ["--job", "generate", *common])
        print(f"generation: {g['seconds']:.1f} s")
    if not a.no_fit:
        ls = LoadSampler()
        r, rss = _run_child(a.omp[0], ["--job", "fit", *common])
        load = ls.stop()
        print(f"\nTraining ({a.omp[0]}): {r['seconds']:.1f} s wall ({r['seconds'] / 60:.1f} min), train_seconds "
              f"{r['train_seconds']:.1f}, peak RSS {rss:.0f} MiB; load mean {load['mean']:.1f}, max "
              f"{load['max']:.1f} (start {load['start']:.1f}, end {load['end']:.1f})")
        print("| stage | start (s) | end (s) | seconds |\n|---|---|---|---|")
        prev = 0.0
        for k, (s0, s1) in r["marks"].items():
            print(f"| {k} | {s0:.1f} | {s1:.1f} | {s1 - prev:.1f} |")
            prev = s1
        print(f"| preview, files | {prev:.1f} | {r['seconds']:.1f} | {r['seconds'] - prev:.1f} |")
        print(f"last physics loss {r['loss_physics_last']:.5f}, recon-large PSNR (physics) "
              f"{r['recon_large_psnr_physics']}, E error {r['E_error']}")
    print("\nRasteriser, forward + backward per frame (median of "
          f"{a.repeats}; ms):\n| OpenMP | px | Gaussians | pairs | forward | backward | total | load |\n"
          "|---|---|---|---|---|---|---|---|")
    for mode in a.omp:
        r, _ = _run_child(mode, ["--job", "raster", *common, "--raster-sizes", *map(str, a.raster_sizes),
                                 "--repeats", str(a.repeats)])
        for s, v in r["sizes"].items():
            print(f"| {mode} ({r['threads']} thr) | {s} | {v['gaussians']} | {v['pairs']} | "
                  f"{v['forward'] * 1e3:.0f} | {v['backward'] * 1e3:.0f} | {v['total'] * 1e3:.0f} | {v['load']:.1f} |")


if __name__ == "__main__":
    main()
