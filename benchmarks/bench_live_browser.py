"""Live AR in a browser (`physar ar serve`, issue 18): glass-to-glass latency, frame rate and CPU per frame
with a real browser on this machine.

Headless Debian Chromium (selenium, the system chromedriver) plays a synthetic clip of the seed cantilever
project (`physar synth render`, in a loop) as its fake camera; the page sends each frame as JPEG over the
WebSocket and shows the augmented frame it gets back. Latency is the page's own: from the moment it grabs a
camera frame (performance.now()) to the moment the augmented frame is drawn on its canvas. Measured after a
warm-up, over ``--seconds`` per size, at 640x360 and 1280x720 (the project camera's size; the fake camera
delivers 30 fps, so 30 fps is the ceiling). CPU per frame: the server process (all its threads: decoding,
the pipeline, the overlay, JPEG, the web server, the recording when asked) and the browser (every Chromium
process), from /proc, over the measured frames. Both overlays: drawn by the server (the page shows augmented
JPEG frames) and drawn by the page on its own video (``?overlay=page``: per frame the overlay's geometry;
latency is then the age of the estimate drawn, from the grab of the frame it came from).

    .venv/bin/python benchmarks/bench_live_browser.py [--seconds 15] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import tempfile
import threading
import time
import tomllib
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "ar" / "cantilever"


def _clip(work: Path, quick: bool) -> tuple[Path, Path]:
    """(project file, clip folder) of a 2 s clip at 640x360 (quick) or 1280x720."""
    from physar.ar.project import load_project
    from physar.synth.render import render_project
    from physar.synth.scenario import parse_scenario

    d = work / ("p360" if quick else "p720")
    d.mkdir()
    for f in ("project.toml", "rom.toml"):
        shutil.copy(EXAMPLE / f, d / f)
    shutil.copy(EXAMPLE.parents[1] / "camera_720p.toml", d / "camera.toml")
    text = (d / "project.toml").read_text().replace('"../../camera_720p.toml"', '"camera.toml"')
    (d / "project.toml").write_text(text)
    base = tomllib.loads((EXAMPLE / "scenario.toml").read_text())
    sc = parse_scenario({"seed": 1, "video": {"duration": 2.0}, "camera": base["camera"], "texture": base["texture"],
                         "schedule": {"s": {"keyframes": [[0, 0.42], [0.5, 0.42], [0.7, 0.2], [1.3, 0.2],
                                                          [1.5, 0.42], [2.0, 0.42]]}}})
    render_project(load_project(d / "project.toml"), sc, d / "clip", quick=quick)
    (d / "project.toml").write_text(text.replace('"camera.toml"', '"clip/camera.toml"'))
    return d / "project.toml", d / "clip"


def _y4m(video: Path, path: Path) -> tuple[int, int]:
    from physar.ar.video import VideoReader

    frames = list(VideoReader(video))
    h, w = frames[0].shape[:2]
    with open(path, "wb") as f:
        f.write(f"YUV4MPEG2 W{w} H{h} F30:1 Ip A1:1 C420jpeg\n".encode())
        f.writelines(b"FRAME\n" + cv2.cvtColor(img, cv2.COLOR_BGR2YUV_I420).tobytes() for img in frames)
    return w, h


def _cpu_s(pids) -> float:
    """User + system CPU seconds of the processes ``pids`` (those still alive)."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    for p in pids:
        try:
            f = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
            total += (int(f[11]) + int(f[12])) / tick
        except (OSError, IndexError):
            pass
    return total


def _chromium_pids() -> list[int]:
    out = subprocess.run(["pgrep", "-f", "chromium"], check=False, capture_output=True, text=True).stdout.split()
    return [int(p) for p in out]


def measure(project_path: Path, y4m: Path, seconds: float, overlay: str = "server", warmup: float = 4.0) -> dict:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By

    from physar.ar.live import serve
    from physar.ar.project import load_project

    stop, urls, summary = threading.Event(), [], {}
    project = load_project(project_path)
    server = threading.Thread(target=lambda: summary.update(serve(project, port=0, ready=urls.append,
                                                                  stop_event=stop)))
    server.start()
    while not urls:
        time.sleep(0.05)
    opts = webdriver.ChromeOptions()
    opts.binary_location = shutil.which("chromium")
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
              "--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream",
              f"--use-file-for-fake-video-capture={y4m}", "--window-size=1400,1100"):
        opts.add_argument(a)
    driver = webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=opts)
    try:
        driver.get(urls[0] + ("?overlay=page" if overlay == "page" else "?overlay=server"))
        while driver.execute_script("return window.physarLive.info") is None:
            time.sleep(0.1)
        driver.find_element(By.ID, "start").click()
        time.sleep(warmup)
        n0 = driver.execute_script("return window.physarLive.latencies.length")
        pids = _chromium_pids()
        t0, srv0, br0 = time.perf_counter(), time.process_time(), _cpu_s(pids)
        time.sleep(seconds)
        n1 = driver.execute_script("return window.physarLive.latencies.length")
        wall, srv, br = time.perf_counter() - t0, time.process_time() - srv0, _cpu_s(pids) - br0
        lat = np.array(driver.execute_script("return window.physarLive.latencies"))[-(n1 - n0):]
    finally:
        driver.quit()
        stop.set()
        server.join(60)
    frames = n1 - n0
    return {"frames": int(frames), "fps": frames / wall, "latency_ms_median": float(np.median(lat)),
            "latency_ms_p95": float(np.percentile(lat, 95)), "server_cpu_ms_per_frame": srv / frames * 1e3,
            "browser_cpu_ms_per_frame": br / frames * 1e3, "server_dropped": summary.get("dropped", 0),
            "server_stages_ms_median": summary.get("stages_ms_median", {})}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    load0 = os.getloadavg()
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for quick in (True, False):
            proj, clip = _clip(work, quick)
            w, h = _y4m(clip / "video.mp4", work / f"cam{int(quick)}.y4m")
            for overlay in ("server", "page"):
                rows[f"{w}x{h} {overlay}"] = measure(proj, work / f"cam{int(quick)}.y4m", args.seconds, overlay)
    load1 = os.getloadavg()
    print(f"load average before {load0[0]:.2f}, after {load1[0]:.2f}")
    print("| size, overlay drawn by | frames | fps | latency median [ms] | latency p95 [ms] | server CPU [ms/frame] "
          "| browser CPU [ms/frame] | server stages (median ms) |")
    print("|---|---|---|---|---|---|---|---|")
    for size, r in rows.items():
        st = ", ".join(f"{k} {v:.1f}" for k, v in r["server_stages_ms_median"].items() if k != "decode")
        print(f"| {size} | {r['frames']} | {r['fps']:.1f} | {r['latency_ms_median']:.0f} | {r['latency_ms_p95']:.0f} "
              f"| {r['server_cpu_ms_per_frame']:.1f} | {r['browser_cpu_ms_per_frame']:.1f} | {st} |")
    if args.json:
        args.json.write_text(json.dumps({"load_before": load0, "load_after": load1, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
