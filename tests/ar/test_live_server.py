"""`physar ar serve` without a browser (issue 18): the access token and TLS off loopback, bounded messages, a
WebSocket from another origin, two viewers, a camera that reconnects (the filter starts afresh), frames
dropped rather than queued, bad frames answered with one message, the recording, and the CLI's refusals.
The frames are the seed cantilever clip of the test-data renderer (tests/ar/conftest.py)."""
import asyncio
import json
import struct
import threading
import time

import aiohttp
import cv2
import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from physar.ar.live import HEADER, LiveServer, LiveSession, self_signed_context, serve
from physar.ar.project import load_project
from physar.ar.project_pipeline import ProjectPipeline
from physar.ar.video import VideoReader
from physar.cli import ar as ar_cli
from physar.errors import ConfigError, PhysarError
from physar.synth.score import read_columns


def _jpeg(frame, q=85) -> bytes:
    return cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, q])[1].tobytes()


def _msg(frame, seq) -> bytes:
    return HEADER.pack(time.perf_counter() * 1e3, seq, 0) + _jpeg(frame)


def _parse(data: bytes):
    n = struct.unpack_from("<I", data)[0]
    return json.loads(data[4:4 + n]), data[4 + n:]


async def _start(project, host="127.0.0.1", ssl_context=None, token=None, max_message=None, **session_kw):
    session = LiveSession(project, **session_kw)
    server = LiveServer(session, token=token, max_message=max_message)
    runner = await server.start(host, 0, ssl_context)
    session.start()
    return session, server, runner


async def _stop(session, runner) -> dict:
    await runner.cleanup()
    return {**await asyncio.to_thread(session.stop), "resets": session.resets}


async def _frame_reply(ws, timeout=30.0):
    """The next binary (frame) message, skipping text ones; -> (meta, jpeg)."""
    while True:
        m = await ws.receive(timeout)
        if m.type == aiohttp.WSMsgType.BINARY:
            return _parse(m.data)
        assert m.type == aiohttp.WSMsgType.TEXT, m


def _qr_in(text: str) -> str | None:
    """The URL of the QR code drawn with block characters in ``text`` (2 modules per character cell, upper
    and lower half; a block is light), read by OpenCV's QR detector."""
    rows = [ln.rstrip("\n") for ln in text.splitlines() if ln and set(ln) <= set(" \u2580\u2584\u2588")]
    if not rows:
        return None
    w = max(len(r) for r in rows)
    light = {"\u2588": (1, 1), "\u2580": (1, 0), "\u2584": (0, 1), " ": (0, 0)}
    img = np.zeros((2 * len(rows), w), np.uint8)
    for i, r in enumerate(rows):
        for j, ch in enumerate(r):
            up, lo = light[ch]
            img[2 * i, j], img[2 * i + 1, j] = 255 * up, 255 * lo
    img = cv2.copyMakeBorder(img, 8, 8, 8, 8, cv2.BORDER_CONSTANT, value=255)
    img = cv2.resize(img, None, fx=8, fy=8, interpolation=cv2.INTER_NEAREST)
    data, _, _ = cv2.QRCodeDetector().detectAndDecode(img)
    return data or None


@pytest.fixture(scope="module")
def project(live_clip):
    return load_project(live_clip[0])


def test_token_and_tls_off_loopback(project):
    """Bound to every interface: without TLS the server refuses to start; with TLS, the page and the WebSocket
    without the token, or with a wrong one, get 403, with it 200 (and the page carries a CSP with a nonce).
    Mutants caught: a token checked on the page but not on the WebSocket, a prefix comparison, a wildcard bind
    served over plain http."""
    done = threading.Event()
    done.set()                      # (a server started by mistake would return at once instead of hanging)
    with pytest.raises(ConfigError, match="--tls CERT KEY or --self-signed"):
        serve(project, host="0.0.0.0", port=0, stop_event=done)
    ctx, fp = self_signed_context(["localhost", "127.0.0.1"])
    assert len(fp.split(":")) == 32
    token = "t0k3n-for-the-test"

    async def run():
        session, server, runner = await _start(project, host="0.0.0.0", ssl_context=ctx, token=token)
        base = f"https://127.0.0.1:{server.port}"
        try:
            async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as s:
                for q in ("", "?token=", "?token=t0k3n", f"?token={token}x"):
                    async with s.get(base + "/" + q) as r:
                        assert r.status == 403, q
                    with pytest.raises(aiohttp.WSServerHandshakeError) as e:
                        await s.ws_connect(base + "/ws" + q)
                    assert e.value.status == 403
                async with s.get(f"{base}/?token={token}") as r:
                    assert r.status == 200
                    page = await r.text()
                    assert "Start camera" in page and "__NONCE__" not in page
                    assert "nonce-" in r.headers["Content-Security-Policy"]
                async with s.get(f"{base}/../../etc/passwd?token={token}") as r:
                    assert r.status == 404                 # two routes, no files
                async with s.ws_connect(f"{base}/ws?token={token}") as ws:
                    info = json.loads((await ws.receive(10)).data)
                    assert info["type"] == "info" and (info["width"], info["height"]) == (640, 360)
        finally:
            await _stop(session, runner)

    asyncio.run(run())


def test_oversized_message_and_foreign_origin(project):
    """A message over the bound closes that connection (code 1009) and frees its slot, others go on; a
    WebSocket opened by a page of another origin is refused (403), and so is any request whose Host is not
    this machine's loopback name (DNS rebinding: the page of another site resolved to 127.0.0.1). Mutants
    caught: no size bound (the message would be accepted), a peer kept after its connection dropped, no Origin
    check, no Host check."""
    async def run():
        session, server, runner = await _start(project, max_message=50_000)
        url = f"http://127.0.0.1:{server.port}/ws"
        try:
            async with aiohttp.ClientSession() as s:
                with pytest.raises(aiohttp.WSServerHandshakeError) as e:
                    await s.ws_connect(url, headers={"Origin": "http://evil.example"})
                assert e.value.status == 403
                evil = f"evil.example:{server.port}"          # a site whose name was rebound to 127.0.0.1
                async with s.get(url[:-3], headers={"Host": evil}) as r:
                    assert r.status == 403
                with pytest.raises(aiohttp.WSServerHandshakeError) as e:
                    await s.ws_connect(url, headers={"Host": evil, "Origin": f"http://{evil}"})
                assert e.value.status == 403
                async with s.get(url[:-3], headers={"Host": f"localhost:{server.port}"}) as r:
                    assert r.status == 200
                async with s.ws_connect(url, headers={"Origin": f"http://127.0.0.1:{server.port}"}) as ok_ws:
                    await ok_ws.receive(10)
                    ws = await s.ws_connect(url)
                    await ws.receive(10)
                    assert len(server.peers) == 2
                    await ws.send_bytes(b"\0" * 60_000)
                    m = await ws.receive(10)
                    assert m.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.CLOSING)
                    assert ws.close_code == 1009
                    for _ in range(50):
                        if len(server.peers) == 1:
                            break
                        await asyncio.sleep(0.05)
                    assert len(server.peers) == 1 and not ok_ws.closed
        finally:
            await _stop(session, runner)

    asyncio.run(run())


def test_two_viewers_reconnect_and_recording(project, live_clip, tmp_path):
    """Camera A sends frames 0-14 (load at 420 mm) while a second page watches: both get every augmented frame
    (a 640x360 JPEG and its estimate, within 1 % of the span of the finer-mesh truth after the first frame). A closes; camera B
    presses Start again (a new stream) and sends frame 35 with a capture time that is not a number: the reply is
    valid JSON (time null) and its estimate is exactly what a fresh pipeline gives on that frame. A closes;
    camera B connects and sends frame 30 (load at 200 mm): its estimate is again a fresh pipeline's (the
    filter and the pose tracker were reset, not carried over). The recording has one CSV
    row and one video frame per processed frame, and appears only when the session stops. Mutants caught: a
    frame sent only to the camera page, the filter kept across cameras (the estimate would be pulled towards
    420 mm), a reset only when the page changes, NaN written into the JSON, a recording written in place."""
    _, clip, frames = live_clip
    truth = read_columns(clip / "truth.csv")["s_true"]
    out_v, out_c = tmp_path / "live.mp4", tmp_path / "live.csv"

    async def run():
        session, server, runner = await _start(project, out_video=out_v, out_csv=out_c)
        url = f"http://127.0.0.1:{server.port}/ws"
        viewer_got = []
        try:
            async with aiohttp.ClientSession() as s:
                viewer = await s.ws_connect(url)
                await viewer.receive(10)
                cam = await s.ws_connect(url)
                await cam.receive(10)
                await cam.send_str(json.dumps({"type": "camera"}))
                for k in range(15):
                    await cam.send_bytes(_msg(frames[k], k + 1))
                    meta, _jpg = await _frame_reply(cam)
                    assert meta["seq"] == k + 1 and meta["status"] == "tracking"
                    if k:   # the first frame is one fresh solve (measured 14.7 mm off at JPEG quality 85)
                        assert abs(meta["mu"][0] - truth[k]) < 0.005, (k, meta["mu"], truth[k])
                    vm, vj = await _frame_reply(viewer)
                    viewer_got.append(vm["seq"])
                    assert cv2.imdecode(np.frombuffer(vj, np.uint8), cv2.IMREAD_COLOR).shape == (360, 640, 3)
                assert viewer_got == list(range(1, 16))
                assert not out_v.exists() and not out_c.exists()          # written at the end, atomically
                await cam.send_str(json.dumps({"type": "camera"}))      # Stop, then Start again on this page
                restart = HEADER.pack(float("nan"), 16, 0) + _jpeg(frames[35])   # (a page clock gone wrong)
                await cam.send_bytes(restart)
                m = await cam.receive(30)
                while m.type != aiohttp.WSMsgType.BINARY:
                    m = await cam.receive(30)
                n = struct.unpack_from("<I", m.data)[0]
                meta_a = json.loads(m.data[4:4 + n], parse_constant=lambda c: pytest.fail(f"{c} in JSON"))
                await _frame_reply(viewer)
                await cam.close()
                cam_b = await s.ws_connect(url)
                await cam_b.receive(10)
                await cam_b.send_str(json.dumps({"type": "camera"}))
                data = _msg(frames[30], 1)
                await cam_b.send_bytes(data)
                meta_b, _ = await _frame_reply(cam_b)
                await cam_b.close()
                await viewer.close()
        finally:
            summary = await _stop(session, runner)
        return meta_a, restart, meta_b, data, summary

    meta_a, restart, meta_b, data, summary = asyncio.run(run())
    assert meta_a["stamp"] is None and meta_a["seq"] == 16
    img = cv2.imdecode(np.frombuffer(restart[HEADER.size:], np.uint8), cv2.IMREAD_COLOR)
    _, fresh = ProjectPipeline(load_project(live_clip[0]), overlay=False).process(img, 0, draw=False)
    assert meta_a["mu"][0] == pytest.approx(float(fresh.mu[0]), abs=1e-9)
    img = cv2.imdecode(np.frombuffer(data[HEADER.size:], np.uint8), cv2.IMREAD_COLOR)
    _, fresh = ProjectPipeline(load_project(live_clip[0]), overlay=False).process(img, 0, draw=False)
    assert abs(truth[30] - 0.2) < 1e-9
    assert meta_b["mu"][0] == pytest.approx(float(fresh.mu[0]), abs=1e-9)
    assert abs(meta_b["mu"][0] - 0.2) < 0.01          # one fresh solve, no filter history
    assert summary["frames"] == 17 and summary["resets"] == 2
    rows = read_columns(out_c)
    assert len(rows["frame"]) == 17 and sum(1 for _ in VideoReader(out_v)) == 17


def test_frames_dropped_not_queued_and_bad_frames(project, live_clip):
    """A camera that sends 40 frames without waiting: each frame is either processed or dropped (none
    waits in a queue), some are dropped, and the newest one is processed. A frame of the wrong size and bytes
    that are no image get one error message naming the problem; the next good frame is answered. Mutants
    caught: an unbounded queue (nothing dropped, every frame processed late), the oldest frame kept instead of
    the newest, a bad frame that kills the session."""
    _, _, frames = live_clip

    async def run():
        session, server, runner = await _start(project)
        url = f"http://127.0.0.1:{server.port}/ws"
        try:
            async with aiohttp.ClientSession() as s, s.ws_connect(url) as cam:
                await cam.receive(10)
                await cam.send_str(json.dumps({"type": "camera"}))
                msgs = [_msg(frames[k % len(frames)], k + 1) for k in range(40)]
                for m in msgs:
                    await cam.send_bytes(m)
                seqs = []
                while True:
                    try:
                        meta, _ = await _frame_reply(cam, timeout=3.0)
                    except TimeoutError:
                        break
                    seqs.append(meta["seq"])
                small = cv2.resize(frames[0], (320, 180))
                await cam.send_bytes(HEADER.pack(0.0, 41, 0) + _jpeg(small))
                err = json.loads((await cam.receive(30)).data)
                await cam.send_bytes(HEADER.pack(0.0, 42, 0) + b"not an image at all")
                err2 = json.loads((await cam.receive(30)).data)
                await cam.send_bytes(_msg(frames[5], 43))
                meta, _ = await _frame_reply(cam)
        finally:
            summary = await _stop(session, runner)
        return seqs, err, err2, meta, summary, session.source

    seqs, err, err2, meta, _summary, src = asyncio.run(run())
    assert seqs and seqs[-1] == 40 and seqs == sorted(seqs)
    assert src.dropped > 0 and len(seqs) + src.dropped == 40, (len(seqs), src.dropped)
    assert err["type"] == "error" and err["seq"] == 41 and "320x180" in err["message"] and "640x360" in err["message"]
    assert err2["type"] == "error" and "not a JPEG" in err2["message"]
    assert meta["seq"] == 43 and meta["status"] == "tracking"


def test_serve_cli_refusals(live_clip, tmp_path):
    """One line and exit 2 for: a wildcard bind without TLS, a missing certificate file, both --tls and
    --self-signed, a JPEG quality of 0, a recording with the wrong suffix, a port in use; nothing written."""
    app = typer.Typer()
    ar_cli.register(app)
    proj = str(live_clip[0])
    cert = tmp_path / "c.pem"
    cert.write_text("x")
    cases = [(["--host", "0.0.0.0"], "--tls CERT KEY or --self-signed"),
             (["--tls", str(tmp_path / "no.pem"), str(tmp_path / "no.key")], "no.pem: TLS certificate file not found"),
             (["--tls", str(cert), str(cert), "--self-signed"], "not both"),
             (["--quality", "0"], "--quality must be within 1..100, got 0"),
             (["--out", str(tmp_path / "aug.avi")], "unknown augmented video suffix '.avi'")]
    import socket

    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    cases.append((["--port", str(busy.getsockname()[1])], f"cannot listen on 127.0.0.1:{busy.getsockname()[1]}"))
    for args, text in cases:
        r = CliRunner().invoke(app, ["ar", "serve", proj, *(["--port", "0"] if "--port" not in args else []), *args])
        assert r.exit_code == 2, (args, r.output)
        lines = [ln for ln in r.output.splitlines() if ln.strip()]
        assert len(lines) == 1 and text in lines[0], (args, r.output)
    busy.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.pem"]


def test_page_overlay_geometry_matches_the_server_drawing(project, live_clip):
    """A page in overlay=page mode gets the surface triangles and colour table once and per frame the vertex
    pixels, the visible faces far to near and their colour levels; filled as the page fills them, they cover
    the pixels the server's own drawing changes on the same frame (intersection over union > 0.8 away from the
    text panel and the colour bar), and the colour levels index the table. Mutants caught: a wrong byte layout
    (float64 pixels, uint16 ids), x and y swapped, face ids taken as vertex ids, levels outside the table."""
    _, _, frames = live_clip

    async def run():
        session, server, runner = await _start(project)
        base = f"http://127.0.0.1:{server.port}/ws"
        try:
            async with aiohttp.ClientSession() as s:
                cam = await s.ws_connect(base + "?overlay=page")
                info = json.loads((await cam.receive(10)).data)
                jpg_peer = await s.ws_connect(base)
                await jpg_peer.receive(10)
                await cam.send_str(json.dumps({"type": "camera"}))
                out = []
                for k in (3, 25):
                    await cam.send_bytes(_msg(frames[k], k))
                    meta, body = await _frame_reply(cam)
                    jm, jpg = await _frame_reply(jpg_peer)
                    assert jm["seq"] == meta["seq"] == k
                    out.append((meta, body, jpg))
                with pytest.raises(aiohttp.WSServerHandshakeError) as e:
                    await s.ws_connect(base + "?overlay=vr")
                assert e.value.status == 400
        finally:
            await _stop(session, runner)
        return info, out

    info, out = asyncio.run(run())
    mesh = info["mesh"]
    faces = np.array(mesh["faces"]).reshape(-1, 3)
    nv = mesh["n_vertices"]
    assert faces.max() == nv - 1 and len(mesh["lut"]) == 48
    for (meta, body, jpg), k in zip(out, (3, 25)):
        g = meta["geometry"]
        p = np.frombuffer(body, np.float32, 2 * nv).reshape(nv, 2)
        ids = np.frombuffer(body, np.uint32, g["faces"], 8 * nv)
        lev = np.frombuffer(body, np.uint8, g["faces"], 8 * nv + 4 * g["faces"])
        assert len(body) == 8 * nv + 5 * g["faces"] and lev.max() < len(mesh["lut"])
        mask = np.zeros((360, 640), np.uint8)
        for f in faces[ids]:
            cv2.fillConvexPoly(mask, np.round(p[f] * 16).astype(np.int32), 255, cv2.LINE_8, 4)
        sent = cv2.imdecode(np.frombuffer(_jpeg(frames[k]), np.uint8), cv2.IMREAD_COLOR)
        drawn = cv2.imdecode(np.frombuffer(jpg, np.uint8), cv2.IMREAD_COLOR)
        diff = np.abs(cv2.blur(drawn, (3, 3)).astype(int) - cv2.blur(sent, (3, 3)).astype(int)).max(2) > 25
        a, b = mask[100:, :560] > 0, diff[100:, :560]
        iou = (a & b).sum() / max((a | b).sum(), 1)
        assert a.sum() > 2000 and iou > 0.8, (k, a.sum(), b.sum(), iou)


def test_serve_cli_self_signed_token_qr_and_sigint(live_clip, tmp_path):
    """`physar ar serve --host 0.0.0.0 --self-signed --out --csv`: prints an https URL with a token, the
    certificate's fingerprint and a QR code; the page needs that token; a camera's frames are recorded; SIGINT
    while the camera is still sending ends it with exit 0, the MP4 and the CSV complete (one row and one frame per processed frame) and nothing
    else in the folder. Mutants caught: a wildcard bind served without the token, a recording lost or left
    as a temporary on Ctrl-C (the event loop closed under a frame in progress)."""
    import os
    import re
    import signal
    import subprocess
    import sys
    from pathlib import Path

    _, _, frames = live_clip
    out = tmp_path / "rec"
    out.mkdir()
    physar = Path(sys.executable).with_name("physar")
    proc = subprocess.Popen([str(physar), "ar", "serve", str(live_clip[0]), "--host", "0.0.0.0", "--port", "0",
                             "--self-signed", "--out", str(out / "live.mp4"), "--csv", str(out / "live.csv")],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    lines = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stderr.readline, "")), daemon=True)
    reader.start()        # (one reader of the pipe: readline's buffer and communicate() would split it)
    try:
        url = None
        t0 = time.time()
        while url is None and time.time() - t0 < 120 and (proc.poll() is None or reader.is_alive()):
            m = re.search(r"serving .* on (https://\S+)", "".join(lines))
            url = m.group(1) if m else None
            time.sleep(0.05)
        assert url and re.search(r"\?token=[\w-]{16,}$", url), lines
        port = int(re.search(r":(\d+)/", url).group(1))
        base = f"https://127.0.0.1:{port}/"
        token = url.split("?token=")[1]

        replies = []

        async def client():       # streams until the server goes away: SIGINT comes with frames in flight
            async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(ssl=False)) as s:
                async with s.get(base) as r:
                    assert r.status == 403
                async with s.ws_connect(f"{base}ws?token={token}") as cam:
                    await cam.receive(10)
                    await cam.send_str(json.dumps({"type": "camera"}))
                    k = 0
                    while True:
                        try:
                            await cam.send_bytes(_msg(frames[k % len(frames)], k + 1))
                            m = await cam.receive(0.2)
                        except (ConnectionError, RuntimeError):
                            return
                        except TimeoutError:
                            m = None
                        if m is not None and m.type == aiohttp.WSMsgType.BINARY:
                            replies.append(k)
                        elif m is not None and m.type != aiohttp.WSMsgType.TEXT:
                            return
                        k += 1
                        await asyncio.sleep(0.02)

        streamer = threading.Thread(target=lambda: asyncio.run(client()))
        streamer.start()
        t0 = time.time()
        while len(replies) < 6 and time.time() - t0 < 60:
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        proc.wait(60)
        reader.join(30)
        streamer.join(30)
    finally:
        if proc.poll() is None:
            proc.kill()
    text = "".join(lines)
    assert proc.returncode == 0, text
    assert "SHA-256" in text, text
    assert _qr_in(text) == url, text        # the QR code printed is the URL with its token
    n = int(re.search(r"(\d+) frames at", text).group(1))
    assert "Traceback" not in text and n >= 6, text
    assert sorted(p.name for p in out.iterdir()) == ["live.csv", "live.mp4"]
    assert len(read_columns(out / "live.csv")["frame"]) == n and sum(1 for _ in VideoReader(out / "live.mp4")) == n


def test_a_failing_session_is_reported_not_hidden(project, live_clip, tmp_path, monkeypatch):
    """A recording that cannot be opened stops serve() before it listens (one error naming the cause); a
    session whose frame loop fails tells every page and ends serve() with the error in its summary instead of
    serving a dead session. Mutants caught: the server listening with a dead session, the error swallowed."""
    _, _, frames = live_clip
    with pytest.raises(PhysarError, match="cannot start the session"):
        serve(project, port=0, out_video="/proc/physar-cannot-write-here.mp4", ready=lambda u: pytest.fail(u))

    calls = {"n": 0}
    real = ProjectPipeline.process

    def failing(self, frame, index, draw=True, gray=None):
        calls["n"] += 1
        if calls["n"] == 3:
            raise FloatingPointError("a bug in the frame loop")
        return real(self, frame, index, draw, gray)

    monkeypatch.setattr(ProjectPipeline, "process", failing)
    urls, summary, got = [], {}, []
    th = threading.Thread(target=lambda: summary.update(serve(project, port=0, ready=urls.append)))
    th.start()
    while not urls:
        assert th.is_alive()
        time.sleep(0.05)

    async def client():
        async with aiohttp.ClientSession() as s, s.ws_connect(urls[0] + "ws") as cam:
            await cam.receive(10)
            await cam.send_str(json.dumps({"type": "camera"}))
            for k in range(3):
                await cam.send_bytes(_msg(frames[k], k + 1))
                while True:
                    m = await cam.receive(30)
                    if m.type == aiohttp.WSMsgType.TEXT:
                        got.append(json.loads(m.data))
                        return
                    if m.type != aiohttp.WSMsgType.BINARY:
                        return
                    break

    asyncio.run(client())
    th.join(30)
    assert not th.is_alive()
    assert got and got[0]["type"] == "error" and "FloatingPointError: a bug in the frame loop" in got[0]["message"]
    assert "a bug in the frame loop" in summary["error"]
