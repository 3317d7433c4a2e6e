"""`physar ar serve` in a real browser (issue 18): headless Chromium from Debian's packages, driven by selenium
with the system chromedriver, its fake camera fed from the seed cantilever clip of the test-data renderer
(a Y4M file made here, played in a loop). The page sends the camera's frames, the server estimates and
records, and the page shows the augmented frames and the estimates.

Each frame of the clip carries its index as a row of black and white blocks in its bottom-left corner (away
from the object, the markers and the overlay's panels), so every frame the server recorded can be matched to
the clip's frame it came from, whatever the browser skipped or repeated."""
import os
import shutil
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from physar.ar.live import serve
from physar.ar.project import load_project
from physar.ar.project_pipeline import ProjectPipeline
from physar.ar.video import VideoReader
from physar.synth.score import read_columns

CHROMIUM, DRIVER = shutil.which("chromium"), shutil.which("chromedriver")
pytestmark = pytest.mark.skipif(not (CHROMIUM and DRIVER), reason="needs Debian's chromium and chromium-driver "
                                                                  "(`make env` installs them when run as root)")
BITS, B = 8, 16          # frame index in 8 blocks of 16 px, after a white and before a black guard block


def _stamp(img: np.ndarray, j: int) -> np.ndarray:
    out = img.copy()
    h = out.shape[0]
    vals = [255] + [255 * ((j >> b) & 1) for b in range(BITS)] + [0]
    for i, v in enumerate(vals):
        out[h - 4 - B:h - 4, 4 + i * B:4 + (i + 1) * B] = v
    return out


def _read_stamp(img: np.ndarray) -> int | None:
    h = img.shape[0]
    g = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(float)
    m = [g[h - 4 - B + 4:h - 8, 4 + i * B + 4:4 + (i + 1) * B - 4].mean() for i in range(BITS + 2)]
    if m[0] < 160 or m[-1] > 95 or any(95 < v < 160 for v in m):
        return None
    return sum(1 << b for b in range(BITS) if m[1 + b] > 128)


def _write_y4m(path: Path, frames, fps: int = 30) -> list[np.ndarray]:
    """Frames as Chromium's fake camera reads them (4:2:0); returns them converted back to BGR."""
    h, w = frames[0].shape[:2]
    back = []
    with open(path, "wb") as f:
        f.write(f"YUV4MPEG2 W{w} H{h} F{fps}:1 Ip A1:1 C420jpeg\n".encode())
        for img in frames:
            yuv = cv2.cvtColor(img, cv2.COLOR_BGR2YUV_I420)
            f.write(b"FRAME\n" + yuv.tobytes())
            back.append(cv2.cvtColor(yuv, cv2.COLOR_YUV2BGR_I420))
    return back


@pytest.mark.parametrize("overlay", ["server", "auto"])
def test_browser_estimates_match_the_file_pipeline(live_clip, tmp_path, overlay):
    """The page's camera (Chromium's fake camera playing the clip in a loop) through `physar ar serve`: the
    session's estimates match the file pipeline's on the same clip frames within 1 % of the span (5 mm) on
    every frame judged (tracking, load at rest in the clip, after the first second of the stream;
    measured max 2-3 mm); the estimates the page shows (its DOM and its state) are the session's CSV rows;
    latency is measured in the page; a screenshot shows the overlay (saved as an artefact: $PHYSAR_ARTIFACTS
    or the test's folder), with the overlay drawn by the server (augmented JPEG frames) or by the page itself
    on its own video (?overlay=page: the geometry sent per frame). Mutants caught: a page that draws the
    geometry with the wrong faces (IoU 0.40 with the face table shifted by 7; right: 0.71 page, 0.93 server) or nothing, estimates sent for the wrong frame, a page that shows stale or
    no estimates, a page that sends frames without cropping/scaling to the camera's size (the server would
    refuse them), a recording that drops rows."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By

    project_path, clip, frames = live_clip
    truth = np.asarray(read_columns(clip / "truth.csv")["s_true"], float)
    coded = _write_y4m(tmp_path / "camera.y4m", [_stamp(f, j) for j, f in enumerate(frames)])
    assert [_read_stamp(f) for f in coded] == list(range(len(frames)))
    ref = ProjectPipeline(load_project(project_path), overlay=False)
    est_file = np.array([ref.process(f, j, draw=False)[1].mu[0] for j, f in enumerate(coded)])

    out_v, out_c = tmp_path / "live.mp4", tmp_path / "live.csv"
    stop, urls, summary = threading.Event(), [], {}
    server = threading.Thread(target=lambda: summary.update(serve(
        load_project(project_path), port=0, out_video=out_v, out_csv=out_c, ready=urls.append,
        stop_event=stop, log=lambda *_: None)))
    server.start()
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
              "--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream",
              f"--use-file-for-fake-video-capture={tmp_path / 'camera.y4m'}", "--window-size=900,1000"):
        opts.add_argument(a)
    driver = None
    art = Path(os.environ.get("PHYSAR_ARTIFACTS", tmp_path))
    try:
        t0 = time.time()
        while not urls:
            assert server.is_alive() and time.time() - t0 < 60, "the server did not start"
            time.sleep(0.05)
        driver = webdriver.Chrome(service=Service(DRIVER), options=opts)
        driver.get(urls[0] + ("?overlay=server" if overlay == "server" else ""))
        t0 = time.time()
        while driver.execute_script("return window.physarLive.info") is None:
            assert time.time() - t0 < 30, "the page did not connect"
            time.sleep(0.1)
        driver.find_element(By.ID, "start").click()
        t0 = time.time()
        while driver.execute_script("return window.physarLive.frames.length") < 150 and time.time() - t0 < 120:
            time.sleep(0.5)
        art.mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(str(art / f"live_browser_{overlay}.png"))   # live: the page draws as it goes
        assert driver.execute_script("return window.physarLive.mode") == (
            "server" if overlay == "server" else "page")
        rect = driver.execute_script("const r = document.getElementById('view').getBoundingClientRect(); "
                                     "return [r.left, r.top, r.width, r.height]")
        driver.find_element(By.ID, "start").click()          # stop the camera: the page's state settles
        time.sleep(1.0)
        state, shown = driver.execute_script(
            "return [window.physarLive, document.getElementById('est-0').dataset.value]")
        last_shown = state["frames"][-1]
    finally:
        if driver is not None:
            driver.quit()
        stop.set()
        server.join(120)
    assert not state["errors"], state["errors"]
    rows = read_columns(out_c)
    recorded = list(VideoReader(out_v))
    n = len(rows["frame"])
    assert n == len(recorded) == summary["frames"] >= 100, (n, len(recorded), summary.get("frames"))
    src = [_read_stamp(f) for f in recorded]
    assert all(j is not None and 0 <= j < len(frames) for j in src)

    # what the page shows is the session's estimate of that frame
    est = np.asarray(rows["s_est"], float)
    page = [f for f in state["frames"] if f["mu"][0] is not None]
    assert len(page) >= 100
    for f in page:
        assert f["mu"][0] == pytest.approx(est[f["frame"]], rel=1e-5, abs=1e-9)
    assert float(shown) == pytest.approx(last_shown["mu"][0], rel=1e-12)
    lat = [v for v in state["latencies"] if v is not None]
    assert len(lat) >= 100 and 0 < np.median(lat) < 2000

    # the session's estimates against the file pipeline's on the same clip frames
    steady = np.array([np.ptp(truth[max(0, j - 3):j + 4]) == 0 for j in range(len(frames))])
    # from the stream's second second on: the session starts fresh at whatever clip frame the page sends first,
    # the file pipeline at frame 0, and their filters converge from those different starts within about 1 s
    # (one fresh-clone run in five differed by 5.02 mm at the 21st judged frame when judging from frame 3)
    judged = [k for k in range(30, n) if rows["status"][k] == "tracking" and steady[src[k]]]
    assert len(judged) >= 0.5 * (n - 30), (len(judged), n)
    err = np.abs(est[judged] - est_file[[src[k] for k in judged]])
    assert err.max() < 0.005, (err.max(), np.argmax(err))
    print(f"browser vs file pipeline on {len(judged)}/{n} judged frames: max {err.max() * 1e3:.2f} mm, mean "
          f"{err.mean() * 1e3:.2f} mm; page latency median {np.median(lat):.0f} ms; screenshot {art}")

    # the overlay is on the screen, where the server draws it: the pixels the page's view changed from the
    # clip frame it shows (read from its stamp) against those the server's recording of that frame changed
    x, y, w, h = (round(v) for v in rect)
    view = cv2.imread(str(art / f"live_browser_{overlay}.png"))[y:y + h, x:x + w]
    view = cv2.resize(view, (640, 360), interpolation=cv2.INTER_AREA)
    j = _read_stamp(view)
    assert j is not None

    def changed(img):        # pixels the overlay changed, below the text panels and left of the colour bar
        d = np.abs(cv2.blur(img, (5, 5)).astype(int) - cv2.blur(coded[j], (5, 5)).astype(int)).max(2) > 40
        return d[100:, :560]

    page_mask = changed(view)
    same = [k for k in range(n) if src[k] == j]
    server_mask = changed(recorded[same[0] if same else int(np.argmin([abs(i - j) for i in src]))])
    iou = (page_mask & server_mask).sum() / max((page_mask | server_mask).sum(), 1)
    print(f"overlay on the screen: {page_mask.sum()} px changed, IoU with the server's drawing {iou:.2f}")
    assert page_mask.sum() > 2000 and iou > 0.5, (page_mask.sum(), iou)
