"""Live AR transport (issue 18): JPEG over a WebSocket vs WebRTC (aiortc), browser-to-server round trip.

Both ends run in this one process and talk over loopback; nothing leaves the machine. For each transport,
frame size and mode a client sends camera-like BGR frames (a camera panning over a textured scene with a
moving ball and sensor noise, fixed seed; never a flat image) to a server, which decodes each frame, draws a
rectangle on it (the stand-in for the AR overlay) and sends it back; the client decodes the reply.

* ``ws``: aiohttp WebSocket server and client. The client encodes the frame with ``cv2.imencode`` (JPEG,
  quality 80) and sends one binary message: an 8-byte send timestamp, then the JPEG. The server decodes it
  (``cv2.imdecode``), draws, re-encodes JPEG 80 and sends it back with the same header.
  ``ws-deflate``: the same, with the client offering permessage-deflate as browsers do (aiohttp's
  ``WebSocketResponse`` accepts it by default, ``compress=True``), so both sides deflate the JPEGs.
* ``ws-fastapi``: the same client and frames against a FastAPI (Starlette) app served by uvicorn in the same
  event loop (``uvicorn.Server.serve()``, default asyncio loop like ``ar serve``, not uvloop; ``http="auto"``,
  ``lifespan="off"``, no access log). Its ``@app.websocket`` endpoint loops on ``websocket.receive()`` and does
  the same server work as ``ws`` (the one ``process`` function). uvicorn's WebSocket implementation is
  ``--uvicorn-ws`` (default ``auto``, which is ``websockets-sansio`` when ``websockets`` is installed), with
  ``ws_per_message_deflate=False`` (the client offers no deflate anyway, as for ``ws``).
* ``webrtc-vp8`` / ``webrtc-h264``: two aiortc ``RTCPeerConnection`` objects, offer and answer handed over
  directly (no signalling server, no STUN). A ``VideoStreamTrack`` on the client sends
  ``av.VideoFrame.from_ndarray(..., format="bgr24")`` frames (pts from the wall clock, time base 1/90000);
  the server converts each received frame with ``to_ndarray(format="bgr24")``, draws and returns it on its
  own track. The codec is forced with ``setCodecPreferences``; aiortc's encoder settings are its defaults.

Every frame carries its index in its top-left corner (12 bits as 16x16 black/white blocks, and the
complement in a second row as a check), read back from the reply by thresholding each block's mean, so
the reply is matched to its send time whatever the codec does to pts.

Modes:

* ``closed``: the client sends the next frame as soon as a reply frees a slot in a window of frames in
  flight: window 1 for the WebSocket (next frame when the previous reply is back). WebRTC needs window 3:
  aiortc's jitter buffer releases a frame only when the first packet of the *next* frame arrives, so with
  one or two frames in flight nothing ever comes back (``--webrtc-window 1`` times out). With 3, each reply
  releases the next send, so the work is as serial as the WebSocket's: 1/fps is one processing round trip
  and the latency three of them (each hop holds a frame until the next one comes).
* ``paced``: a camera at ``--rate`` fps (default 30): frames leave on the clock whatever the replies do
  (at most 30 in flight). This is the live case; WebRTC latency here includes aiortc's one-frame hold per
  hop (2 frame intervals).

Measured over ``--frames`` frames after ``--warmup`` frames (connection set-up, codec start, bitrate
ramp): round-trip latency (client send time, taken before encoding, to the decoded reply) median and
p95; fps = replies per second between the first and last measured reply; CPU ms per frame =
``time.process_time()`` over the same interval / frames. The process holds both client and server
(and aiortc's encoder and decoder threads), so CPU covers both sides. Also: payload bytes per frame
each way (WebSocket message bytes before deflate; RTP payload bytes from aiortc's sender stats), PSNR of
every 10th reply against the sent frame with the same rectangle drawn (two lossy hops), frames lost.
With ``--repeat N`` every configuration runs N times, round robin, and the table gives the medians over the
runs (the median latency's range in brackets; replies and losses summed).

Server footprint (``--footprint``, for the WebSocket servers among ``--transports``: ``ws`` is aiohttp,
``ws-fastapi`` FastAPI/uvicorn), each measured in fresh subprocesses, ``--repeat`` times, interleaved:

* import time: a fresh interpreter imports ``asyncio, json, socket, ssl`` (which ``physar.ar.live`` imports
  before the server stack), then the clock runs over importing ``aiohttp.web``; ``fastapi, uvicorn``; and
  ``fastapi, uvicorn`` plus the modules uvicorn loads when it starts (its HTTP and WebSocket protocol
  implementations, lifespan off). Median over ``--import-runs`` interpreters per repeat; also the number of
  modules the import adds.
* the server alone in its own process (this script with ``--serve-child``; it imports numpy and OpenCV first,
  as ``physar.ar.live`` does): RSS (``VmRSS``) before the stack is imported, once it listens, after
  ``--warmup`` + ``--frames`` closed-loop frames, and the peak (``VmHWM``); the server's own CPU ms per frame
  (its ``process_time`` over the measured frames, asked for with a text message), and the round trip's
  median latency and fps as seen by the client in this process.

    .venv/bin/python benchmarks/bench_live_transport.py --repeat 3            # all but ws-fastapi, ~7 min
    .venv/bin/python benchmarks/bench_live_transport.py --sizes 640x360 --transports ws webrtc-vp8 \\
        --modes closed --frames 150 --json /tmp/transport.json
    .venv/bin/python benchmarks/bench_live_transport.py --transports ws,ws-fastapi --repeat 3 --footprint

Needs ``aiohttp`` and ``aiortc`` (``pip install aiohttp aiortc``); ``ws-fastapi`` needs ``fastapi`` and
``uvicorn[standard]``.
"""
from __future__ import annotations

import argparse
import asyncio
import collections
import fractions
import json
import math
import os
import platform
import struct
import subprocess
import sys
import time

import cv2
import numpy as np

BLOCK = 16  # index block size (px), one macroblock
BITS = 12  # index bits: frames 0..4095 per run
JPEG = [cv2.IMWRITE_JPEG_QUALITY, 80]
TIME_BASE = fractions.Fraction(1, 90000)
POOL = 60  # distinct camera frames, a 2 s loop at 30 fps
TRANSPORTS = ("ws", "ws-deflate", "ws-fastapi", "webrtc-vp8", "webrtc-h264")
STACKS = {"ws": "aiohttp", "ws-fastapi": "FastAPI/uvicorn"}  # the WebSocket servers of --footprint
MODES = ("closed", "paced")
PACED_WINDOW = 30


def camera_frames(w: int, h: int, count: int = POOL, seed: int = 0) -> list[np.ndarray]:
    """A camera panning over a textured, lit scene with a moving ball and sensor noise (loops smoothly)."""
    rng = np.random.default_rng(seed)
    m = max(16, w // 12)  # pan margin
    H, W = h + 2 * m, w + 2 * m
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    base = np.stack([90 + 60 * xx / W, 110 + 50 * yy / H, 150 - 40 * (xx + yy) / (W + H)], axis=-1)
    base *= (1 - 0.3 * (((xx - W / 2) / (W / 2)) ** 2 + ((yy - H / 2) / (H / 2)) ** 2))[..., None]
    tex = cv2.GaussianBlur(rng.standard_normal((H, W), dtype=np.float32), (0, 0), 2.0 * w / 640)
    base += (tex * (25 / tex.std()))[..., None]
    scene = np.clip(base, 0, 255).astype(np.uint8)
    s = w / 640
    for _ in range(14):
        col = tuple(int(v) for v in rng.integers(0, 256, 3))
        x, y = int(rng.integers(0, W)), int(rng.integers(0, H))
        kind = int(rng.integers(0, 3))
        if kind == 0:
            size = rng.integers(20, 90, 2) * s
            cv2.rectangle(scene, (x, y), (x + int(size[0]), y + int(size[1])), col, -1)
        elif kind == 1:
            cv2.circle(scene, (x, y), int(rng.integers(10, 50) * s), col, -1, cv2.LINE_AA)
        else:
            end = (int(rng.integers(0, W)), int(rng.integers(0, H)))
            cv2.line(scene, (x, y), end, col, max(1, int(3 * s)), cv2.LINE_AA)
    cv2.putText(scene, "physar live AR", (int(80 * s), int(150 * s)), cv2.FONT_HERSHEY_SIMPLEX, 1.4 * s,
                (25, 25, 25), max(1, int(3 * s)), cv2.LINE_AA)
    frames = []
    for k in range(count):
        ph = 2 * np.pi * k / count
        dx = round(m + 0.8 * m * float(np.sin(ph)))
        dy = round(m + 0.5 * m * float(np.sin(2 * ph + 1)))
        f = scene[dy:dy + h, dx:dx + w].astype(np.float32)
        cv2.circle(f, (int(w * (0.5 + 0.35 * np.sin(ph))), int(h * (0.6 + 0.15 * np.sin(3 * ph)))),
                   int(40 * s), (40, 60, 220), -1, cv2.LINE_AA)
        f += rng.standard_normal(f.shape, dtype=np.float32) * 3.0
        frames.append(np.clip(f, 0, 255).astype(np.uint8))
    return frames


def stamp(img: np.ndarray, k: int) -> None:
    """Write index k into the top-left corner: bits in row 0, their complement in row 1."""
    for b in range(BITS):
        v = 255 if (k >> b) & 1 else 0
        img[:BLOCK, b * BLOCK:(b + 1) * BLOCK] = v
        img[BLOCK:2 * BLOCK, b * BLOCK:(b + 1) * BLOCK] = 255 - v


def read_stamp(img: np.ndarray) -> int | None:
    """The index written by `stamp`, or None where the two rows are not complementary."""
    q = BLOCK // 4
    cells = img[:2 * BLOCK, :BITS * BLOCK].reshape(2, BLOCK, BITS, BLOCK, -1)
    bits = cells[:, q:BLOCK - q, :, q:BLOCK - q].mean(axis=(1, 3, 4)) > 127.5
    if not np.all(bits[0] != bits[1]):
        return None
    return int(sum(1 << b for b in range(BITS) if bits[0, b]))


def augment(img: np.ndarray) -> None:
    """The server's stand-in for the AR overlay: a rectangle (clear of the index blocks)."""
    h, w = img.shape[:2]
    cv2.rectangle(img, (w // 4, h // 4), (3 * w // 4, 3 * h // 4), (0, 255, 0), max(2, w // 320))


class Tally:
    """Client-side bookkeeping: window/pacing gate, send times, replies, the measured interval."""

    def __init__(self, frames: list[np.ndarray], warmup: int, n: int, window: int, rate: float | None):
        self.frames, self.warmup, self.n, self.window, self.rate = frames, warmup, n, window, rate
        self.sem = asyncio.Semaphore(window)
        self.done = asyncio.Event()
        self.next_k = 0
        self.t0: float | None = None
        self.sent: dict[int, float] = {}
        self.outstanding: collections.deque[int] = collections.deque()
        self.latency: dict[int, float] = {}
        self.lost: set[int] = set()
        self.unreadable = 0
        self.resolved = self.received = 0
        self.keep: dict[int, np.ndarray] = {}
        self.first: tuple[float, float] | None = None  # (wall, cpu) at the first measured reply
        self.last: tuple[float, float] | None = None
        self.count_first = self.count_last = 0  # measured replies received at those instants
        self.probe = None  # async () -> (up bytes, up frames, down bytes, down frames)
        self.snaps: list[asyncio.Task] = []
        self.up_frames = 0

    def measured(self, k: int) -> bool:
        return self.warmup <= k < self.warmup + self.n

    async def next_frame(self) -> tuple[int, np.ndarray] | None:
        """Wait for a free slot (and the camera clock when paced); the next stamped frame, None when done."""
        await self.sem.acquire()
        if self.done.is_set():
            return None
        k = self.next_k
        if self.rate:
            now = time.perf_counter()
            if self.t0 is None:
                self.t0 = now
            delay = self.t0 + k / self.rate - now
            if delay > 0:
                await asyncio.sleep(delay)
        self.next_k += 1
        img = self.frames[k % len(self.frames)].copy()
        stamp(img, k)
        return k, img

    def on_sent(self, k: int, t: float) -> None:
        self.sent[k] = t
        self.outstanding.append(k)
        self.up_frames += 1

    def on_reply(self, k: int | None, t: float, img: np.ndarray, latency: float | None = None) -> None:
        if k is None or k not in self.sent:
            self.unreadable += 1
            return
        while self.outstanding and self.outstanding[0] <= k:  # replies come in order: older ones are lost
            j = self.outstanding.popleft()
            self.sem.release()
            if j < k:
                self._resolve(j, t, lost=True)
        if latency is None:
            latency = t - self.sent[k]
        self.latency[k] = latency
        if self.measured(k) and (k - self.warmup) % 10 == 0:
            self.keep[k] = img
        self._resolve(k, t, lost=False)

    def _resolve(self, k: int, t: float, lost: bool) -> None:
        if not self.measured(k):
            return
        if lost:
            self.lost.add(k)
        else:
            cpu = time.process_time()
            self.received += 1
            if self.first is None:
                self.first, self.count_first = (t, cpu), self.received
                self._snap()
            self.last, self.count_last = (t, cpu), self.received
        self.resolved += 1
        if self.resolved == self.n:
            self._snap()
            self.done.set()
            for _ in range(self.window + 1):
                self.sem.release()

    def _snap(self) -> None:
        if self.probe is not None:
            self.snaps.append(asyncio.ensure_future(self.probe()))

    async def result(self) -> dict:
        snaps = [await s for s in self.snaps]
        lat = np.array([v for k, v in self.latency.items() if self.measured(k)]) * 1e3
        frames = self.count_last - self.count_first
        wall = self.last[0] - self.first[0] if self.first else float("nan")
        cpu = self.last[1] - self.first[1] if self.first else float("nan")
        psnr = [cv2.PSNR(self._expected(k), img) for k, img in sorted(self.keep.items())]
        up = down = float("nan")
        if len(snaps) == 2:
            (ub0, uf0, db0, df0), (ub1, uf1, db1, df1) = snaps
            up = (ub1 - ub0) / max(1, uf1 - uf0)
            down = (db1 - db0) / max(1, df1 - df0)
        return {
            "frames": self.n, "received": int(lat.size), "lost": len(self.lost), "unreadable": self.unreadable,
            "latency_median_ms": float(np.median(lat)) if lat.size else None,
            "latency_p95_ms": float(np.percentile(lat, 95)) if lat.size else None,
            "fps": frames / wall if frames > 0 else None,
            "cpu_ms_per_frame": 1e3 * cpu / frames if frames > 0 else None,
            "cpu_cores": cpu / wall if frames > 0 else None,
            "up_kb_per_frame": up / 1e3, "down_kb_per_frame": down / 1e3,
            "psnr_db": float(np.mean(psnr)) if psnr else None,
        }

    def _expected(self, k: int) -> np.ndarray:
        ref = self.frames[k % len(self.frames)].copy()
        stamp(ref, k)
        augment(ref)
        return ref


def process(data: bytes) -> bytes:
    """The server's work on one message (both servers): decode the JPEG, draw, re-encode; the header kept."""
    img = cv2.imdecode(np.frombuffer(data, np.uint8, offset=8), cv2.IMREAD_COLOR)
    augment(img)
    return data[:8] + cv2.imencode(".jpg", img, JPEG)[1].tobytes()


def proc_status() -> dict:
    """This process's RSS and peak RSS [kB] and CPU time [s] (the reply to a text message)."""
    out = {"cpu_s": time.process_time()}
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(("VmRSS:", "VmHWM:")):
                    out[line[2:5].lower() + "_kb"] = int(line.split()[1])
    except OSError:
        pass
    return out


async def start_server(transport: str, uvicorn_ws: str = "auto") -> tuple[int, object, str]:
    """Start the WebSocket server of ``transport`` on 127.0.0.1 (a free port): (port, async stop(), info)."""
    if transport == "ws-fastapi":
        import uvicorn
        from fastapi import FastAPI, WebSocket

        async def endpoint(ws):
            await ws.accept()
            while True:
                msg = await ws.receive()
                if msg["type"] == "websocket.disconnect":
                    return
                if msg.get("bytes") is not None:
                    await ws.send_bytes(process(msg["bytes"]))
                elif msg.get("text") is not None:
                    await ws.send_text(json.dumps(proc_status()))

        # FastAPI resolves string annotations in the function's module globals; this one is imported locally
        endpoint.__annotations__["ws"] = WebSocket
        app = FastAPI()
        app.add_api_websocket_route("/ws", endpoint)
        config = uvicorn.Config(app, host="127.0.0.1", port=0, ws=uvicorn_ws, ws_max_size=1 << 30,
                                ws_per_message_deflate=False, lifespan="off", access_log=False,
                                log_level="warning")
        server = uvicorn.Server(config)
        task = asyncio.ensure_future(server.serve())
        while not server.started:
            if task.done():
                task.result()
                raise RuntimeError("uvicorn did not start")
            await asyncio.sleep(0.005)

        async def stop():
            server.should_exit = True
            await task

        port = server.servers[0].sockets[0].getsockname()[1]
        return port, stop, f"uvicorn {config.ws_protocol_class.__name__}"

    from aiohttp import WSMsgType, web

    async def handler(request):
        ws = web.WebSocketResponse(max_msg_size=0)  # compress=True (the default) accepts deflate if offered
        await ws.prepare(request)
        async for msg in ws:
            if msg.type == WSMsgType.BINARY:
                await ws.send_bytes(process(msg.data))
            elif msg.type == WSMsgType.TEXT:
                await ws.send_str(json.dumps(proc_status()))
        return ws

    app = web.Application()
    app.router.add_get("/ws", handler)
    runner = web.AppRunner(app, access_log=None)
    await runner.setup()
    await web.TCPSite(runner, "127.0.0.1", 0).start()
    return runner.addresses[0][1], runner.cleanup, "aiohttp"


async def run_ws(tally: Tally, transport: str, uvicorn_ws: str = "auto") -> dict:
    from aiohttp import ClientSession, WSMsgType

    deflate = transport == "ws-deflate"
    port, stop, server_info = await start_server(transport, uvicorn_ws)
    bytes_up = bytes_down = down_frames = 0

    async def probe():
        return bytes_up, tally.up_frames, bytes_down, down_frames

    tally.probe = probe
    try:
        async with ClientSession() as session:
            url = f"http://127.0.0.1:{port}/ws"
            async with session.ws_connect(url, max_msg_size=0, compress=15 if deflate else 0) as ws:
                async def send():
                    nonlocal bytes_up
                    while (item := await tally.next_frame()) is not None:
                        k, img = item
                        t = time.perf_counter()
                        tally.on_sent(k, t)
                        data = struct.pack("<d", t) + cv2.imencode(".jpg", img, JPEG)[1].tobytes()
                        bytes_up += len(data)
                        await ws.send_bytes(data)

                async def receive():
                    nonlocal bytes_down, down_frames
                    async for msg in ws:
                        if msg.type != WSMsgType.BINARY:
                            break
                        img = cv2.imdecode(np.frombuffer(msg.data, np.uint8, offset=8), cv2.IMREAD_COLOR)
                        t = time.perf_counter()
                        bytes_down += len(msg.data)
                        down_frames += 1
                        tally.on_reply(read_stamp(img), t, img, t - struct.unpack_from("<d", msg.data)[0])
                        if tally.done.is_set():
                            break

                await asyncio.gather(send(), receive())
    finally:
        await stop()
    codec = "JPEG q80" + (" + deflate" if deflate else "")
    return {"codec": codec + (f", {server_info}" if transport == "ws-fastapi" else "")}


async def run_webrtc(tally: Tally, codec: str) -> dict:
    import av
    from aiortc import MediaStreamTrack, RTCConfiguration, RTCPeerConnection, RTCRtpSender, VideoStreamTrack
    from aiortc.mediastreams import MediaStreamError

    class CameraTrack(VideoStreamTrack):
        """The browser's camera: stamped frames, as fast as the tally's gate lets them go."""

        def __init__(self):
            super().__init__()
            self.last_pts = -1

        async def recv(self):
            item = await tally.next_frame()
            if item is None:  # done: hold the sender until the connection closes
                await asyncio.Event().wait()
            k, img = item
            t = time.perf_counter()
            tally.on_sent(k, t)
            frame = av.VideoFrame.from_ndarray(img, format="bgr24")
            self.last_pts = max(self.last_pts + 1, int((t - t_start) * 90000))
            frame.pts, frame.time_base = self.last_pts, TIME_BASE
            return frame

    class ReturnTrack(MediaStreamTrack):
        kind = "video"

        def __init__(self):
            super().__init__()
            self.queue: asyncio.Queue = asyncio.Queue()

        async def recv(self):
            return await self.queue.get()

    cfg = RTCConfiguration(iceServers=[])
    client, server = RTCPeerConnection(cfg), RTCPeerConnection(cfg)
    back = ReturnTrack()
    tasks: list[asyncio.Task] = []
    down_frames = 0

    async def serve(track):
        nonlocal down_frames
        while True:
            try:
                f = await track.recv()
            except MediaStreamError:
                return
            img = f.to_ndarray(format="bgr24")
            augment(img)
            out = av.VideoFrame.from_ndarray(img, format="bgr24")
            out.pts, out.time_base = f.pts, f.time_base
            down_frames += 1
            back.queue.put_nowait(out)

    async def watch(track):
        while True:
            try:
                f = await track.recv()
            except MediaStreamError:
                return
            img = f.to_ndarray(format="bgr24")
            tally.on_reply(read_stamp(img), time.perf_counter(), img)

    @server.on("track")
    def _on_server_track(track):
        server.addTrack(back)
        tasks.append(asyncio.ensure_future(serve(track)))

    @client.on("track")
    def _on_client_track(track):
        tasks.append(asyncio.ensure_future(watch(track)))

    t_start = time.perf_counter()
    transceiver = client.addTransceiver(CameraTrack(), direction="sendrecv")
    caps = RTCRtpSender.getCapabilities("video").codecs
    transceiver.setCodecPreferences([c for c in caps if c.mimeType.lower() in (f"video/{codec}", "video/rtx")])

    async def probe():
        up = (await transceiver.sender.getStats()).values()
        down = (await server.getTransceivers()[0].sender.getStats()).values()
        ub = sum(s.bytesSent for s in up if s.type == "outbound-rtp")
        db = sum(s.bytesSent for s in down if s.type == "outbound-rtp")
        return ub, tally.up_frames, db, down_frames

    tally.probe = probe
    try:
        await client.setLocalDescription(await client.createOffer())
        await server.setRemoteDescription(client.localDescription)
        await server.setLocalDescription(await server.createAnswer())
        await client.setRemoteDescription(server.localDescription)
        negotiated = sdp_codec(server.localDescription.sdp)
        await tally.done.wait()
    finally:
        await client.close()
        await server.close()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
    return {"codec": negotiated + " (aiortc defaults)"}


def sdp_codec(sdp: str) -> str:
    """The first (chosen) codec of the SDP's video section."""
    lines = sdp.splitlines()
    pt = next(line.split()[3] for line in lines if line.startswith("m=video"))
    return next(line.split()[1].split("/")[0] for line in lines if line.startswith(f"a=rtpmap:{pt} "))


async def run_one(transport: str, mode: str, frames: list[np.ndarray], args) -> dict:
    rtc = transport.startswith("webrtc")
    window = PACED_WINDOW if mode == "paced" else (args.webrtc_window if rtc else 1)
    tally = Tally(frames, args.warmup, args.frames, window, args.rate if mode == "paced" else None)
    if rtc:
        coro = run_webrtc(tally, transport.split("-")[1])
    else:
        coro = run_ws(tally, transport, args.uvicorn_ws)
    try:
        info = await asyncio.wait_for(coro, args.timeout)
    except TimeoutError:
        info = {"codec": f"timed out after {args.timeout:g} s"}
    return {"transport": transport, "mode": mode, "window": window, **info, **(await tally.result())}


def combine(runs: list[dict]) -> dict:
    """One row from the repeats of a configuration: medians over the repeats, replies and losses summed."""
    row = dict(runs[0])
    for key, v in runs[0].items():
        if isinstance(v, float) and key != "rate":
            vals = [r[key] for r in runs if r[key] is not None and not math.isnan(r[key])]
            row[key] = float(np.median(vals)) if vals else None
    for key in ("frames", "received", "lost", "unreadable"):
        row[key] = sum(r[key] for r in runs)
    meds = [r["latency_median_ms"] for r in runs if r["latency_median_ms"] is not None]
    if len(runs) > 1 and meds:
        row["latency_median_range_ms"] = [min(meds), max(meds)]
    row["repeats"] = len(runs)
    row["load"] = f"{runs[0]['load']} .. {runs[-1]['load']}"
    return row


def fmt(v, spec=".1f"):
    return "–" if v is None or math.isnan(v) else format(v, spec)


def table(rows: list[dict]) -> str:
    head = ("| transport | mode | size | codec | replies / lost (all runs) | latency median [ms] | latency p95 [ms] | fps "
            "| CPU [ms/frame] | CPU [cores] | up / down [kB/frame] | PSNR [dB] |")
    out = [head, "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lo_hi = r.get("latency_median_range_ms")
        spread = f" ({lo_hi[0]:.1f}–{lo_hi[1]:.1f})" if lo_hi else ""
        mode = f"closed, window {r['window']}" if r["mode"] == "closed" else f"paced {r['rate']:g} fps"
        out.append(f"| {r['transport']} | {mode} | {r['size']} | {r['codec']} | {r['received']} / {r['lost']} "
                   f"| {fmt(r['latency_median_ms'])}{spread} | {fmt(r['latency_p95_ms'])} | {fmt(r['fps'])} "
                   f"| {fmt(r['cpu_ms_per_frame'])} | {fmt(r['cpu_cores'], '.2f')} "
                   f"| {fmt(r['up_kb_per_frame'])} / {fmt(r['down_kb_per_frame'])} | {fmt(r['psnr_db'])} |")
    return "\n".join(out)


IMPORT_SETS = {"ws": ("aiohttp.web",), "ws-fastapi": ("fastapi", "uvicorn")}
IMPORT_CHILD = """import asyncio, json, socket, ssl, sys, time
before = len(sys.modules)
t = time.perf_counter()
for name in sys.argv[1:]:
    __import__(name)
print(json.dumps([time.perf_counter() - t, len(sys.modules) - before]))
"""


def import_time(modules: tuple[str, ...]) -> tuple[float, int]:
    """Seconds to import ``modules`` in a fresh interpreter (after asyncio, json, socket, ssl), modules added."""
    out = subprocess.run([sys.executable, "-c", IMPORT_CHILD, *modules], capture_output=True, text=True,
                         check=True)
    seconds, added = json.loads(out.stdout)
    return seconds, added


def serve_child(transport: str, uvicorn_ws: str) -> None:
    """``--serve-child``: the server alone; one JSON line (port, RSS, start time) on stdout, then serve."""
    base = proc_status()

    async def main():
        t = time.perf_counter()
        port, _, info = await start_server(transport, uvicorn_ws)
        start_s = time.perf_counter() - t
        print(json.dumps({"port": port, "info": info, "start_s": start_s, "rss_base_kb": base.get("rss_kb"),
                          "rss_start_kb": proc_status().get("rss_kb")}), flush=True)
        await asyncio.Event().wait()  # until the parent kills this process

    asyncio.run(main())


async def footprint_run(transport: str, frames: list[np.ndarray], args) -> dict:
    """The server of ``transport`` in its own process: RSS, its CPU per frame, the closed-loop round trip."""
    from aiohttp import ClientSession, WSMsgType

    proc = await asyncio.create_subprocess_exec(
        sys.executable, os.path.abspath(__file__), "--serve-child", transport, "--uvicorn-ws", args.uvicorn_ws,
        stdout=asyncio.subprocess.PIPE)
    try:
        ready = json.loads(await asyncio.wait_for(proc.stdout.readline(), 60))
        async with ClientSession() as session:
            url = f"http://127.0.0.1:{ready['port']}/ws"
            async with session.ws_connect(url, max_msg_size=0, compress=0) as ws:
                async def status() -> dict:
                    await ws.send_str("status")
                    msg = await ws.receive()
                    assert msg.type == WSMsgType.TEXT, msg
                    return json.loads(msg.data)

                lat = []
                for k in range(args.warmup + args.frames):
                    if k == args.warmup:
                        s0, t0 = await status(), time.perf_counter()
                    t = time.perf_counter()
                    await ws.send_bytes(struct.pack("<d", t) + cv2.imencode(".jpg", frames[k % len(frames)], JPEG)[1]
                                        .tobytes())
                    msg = await ws.receive()
                    assert msg.type == WSMsgType.BINARY, msg
                    cv2.imdecode(np.frombuffer(msg.data, np.uint8, offset=8), cv2.IMREAD_COLOR)
                    lat.append(time.perf_counter() - t)
                wall = time.perf_counter() - t0
                s1 = await status()
    finally:
        if proc.returncode is None:
            proc.kill()
        await proc.wait()
    return {"transport": transport, "server": ready["info"], "start_ms": 1e3 * ready["start_s"],
            "rss_base_mb": ready["rss_base_kb"] / 1024, "rss_start_mb": ready["rss_start_kb"] / 1024,
            "rss_after_mb": s1["rss_kb"] / 1024, "rss_peak_mb": s1["hwm_kb"] / 1024,
            "server_cpu_ms_per_frame": 1e3 * (s1["cpu_s"] - s0["cpu_s"]) / args.frames,
            "latency_median_ms": 1e3 * float(np.median(lat[args.warmup:])), "fps": args.frames / wall}


def footprint(transports: list[str], pools: dict, args) -> dict:
    """Import times and the server-alone runs, ``--repeat`` times, the stacks interleaved."""
    stacks = [t for t in transports if t in STACKS]
    imports: dict[str, list] = {t: [] for t in stacks}
    runs: list[dict] = []
    for t in stacks:  # once untimed: the files into the page cache
        import_time(IMPORT_SETS[t])
    for rep in range(args.repeat):
        for _ in range(args.import_runs):
            for t in stacks:
                imports[t].append(import_time(IMPORT_SETS[t]))
        for wh, pool in pools.items():
            for t in stacks:
                r = asyncio.run(footprint_run(t, pool, args))
                r.update(size=f"{wh[0]}×{wh[1]}", repeat=rep, load=loadavg())
                runs.append(r)
                print(footprint_table([r]).splitlines()[-1] + f"  (run {rep + 1}, load {r['load']})", flush=True)
    import_rows = []
    for t in stacks:
        ms = np.array([s for s, _ in imports[t]]) * 1e3
        import_rows.append({"transport": t, "modules": ", ".join(IMPORT_SETS[t]), "runs": len(ms),
                            "import_median_ms": float(np.median(ms)), "import_min_ms": float(ms.min()),
                            "import_max_ms": float(ms.max()), "modules_added": imports[t][0][1]})
    rows = []
    for wh in pools:
        for t in stacks:
            sel = [r for r in runs if r["transport"] == t and r["size"] == f"{wh[0]}×{wh[1]}"]
            row = dict(sel[0])
            for key, v in sel[0].items():
                if isinstance(v, float):
                    row[key] = float(np.median([r[key] for r in sel]))
            row["repeats"] = len(sel)
            rows.append(row)
    return {"imports": import_rows, "rows": rows, "runs": runs}


def import_table(rows: list[dict]) -> str:
    out = ["| server | imports | import time median [ms] (min–max) | modules added |", "|---|---|---|---|"]
    for r in rows:
        out.append(f"| {STACKS[r['transport']]} | `{r['modules']}` | {r['import_median_ms']:.0f} "
                   f"({r['import_min_ms']:.0f}–{r['import_max_ms']:.0f}) | {r['modules_added']} |")
    return "\n".join(out)


def footprint_table(rows: list[dict]) -> str:
    head = ("| server | size | import + start to listening [ms] | RSS before stack / listening / after frames / "
            "peak [MB] | server CPU [ms/frame] | latency median [ms] | fps |")
    out = [head, "|---|---|---|---|---|---|---|"]
    for r in rows:
        name = STACKS[r["transport"]] + (f" ({r['server'].split()[-1]})" if r["transport"] == "ws-fastapi" else "")
        out.append(f"| {name} | {r['size']} | {r['start_ms']:.0f} | {r['rss_base_mb']:.1f} / "
                   f"{r['rss_start_mb']:.1f} / {r['rss_after_mb']:.1f} / {r['rss_peak_mb']:.1f} "
                   f"| {r['server_cpu_ms_per_frame']:.2f} | {r['latency_median_ms']:.1f} | {r['fps']:.1f} |")
    return "\n".join(out)


def loadavg() -> str:
    try:
        with open("/proc/loadavg") as f:
            return " ".join(f.read().split()[:3])
    except OSError:
        return "n/a"


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            return next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or platform.machine()


def transport_list(text: str) -> list[str]:
    """``--transports`` items: names, or comma-separated names (``ws,ws-fastapi``)."""
    names = [t for t in text.split(",") if t]
    for t in names:
        if t not in TRANSPORTS:
            raise argparse.ArgumentTypeError(f"unknown transport {t!r} (choose from {', '.join(TRANSPORTS)})")
    return names


def version(dist: str) -> str:
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "n/a"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", default=["640x360", "1280x720"])
    ap.add_argument("--transports", nargs="+", type=transport_list,
                    default=[[t for t in TRANSPORTS if t != "ws-fastapi"]],
                    help=f"any of {', '.join(TRANSPORTS)}, space- or comma-separated (default: all but ws-fastapi)")
    ap.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    ap.add_argument("--frames", type=int, default=300, help="measured frames per configuration")
    ap.add_argument("--warmup", type=int, default=30)
    ap.add_argument("--rate", type=float, default=30.0, help="camera rate of the paced mode [fps]")
    ap.add_argument("--webrtc-window", type=int, default=3,
                    help="frames in flight in the closed loop of WebRTC (aiortc needs 3, see above)")
    ap.add_argument("--uvicorn-ws", default="auto", choices=("auto", "websockets", "websockets-sansio", "wsproto"),
                    help="uvicorn's WebSocket implementation for ws-fastapi (auto: websockets-sansio if installed)")
    ap.add_argument("--footprint", action="store_true",
                    help="also measure import time, RSS and server CPU of the WebSocket servers (ws, ws-fastapi)")
    ap.add_argument("--import-runs", type=int, default=5, help="fresh interpreters per stack and repeat")
    ap.add_argument("--repeat", type=int, default=1,
                    help="runs of every configuration (round robin); the table gives medians over them")
    ap.add_argument("--timeout", type=float, default=300.0, help="per configuration [s]")
    ap.add_argument("--json", type=str, default=None, help="also write the results here")
    ap.add_argument("--serve-child", choices=tuple(STACKS), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.serve_child:
        serve_child(args.serve_child, args.uvicorn_ws)
        return
    args.transports = list(dict.fromkeys(t for group in args.transports for t in group))
    if args.warmup + args.frames + 2 * PACED_WINDOW >= 1 << BITS:
        ap.error(f"warmup + frames must stay below {(1 << BITS) - 2 * PACED_WINDOW}")

    dists = ["aiohttp", "aiortc", "av", "fastapi", "starlette", "uvicorn", "websockets"]
    meta = {"date": time.strftime("%Y-%m-%d %H:%M"), "cpu": cpu_model(), "cores": os.cpu_count(),
            "python": platform.python_version(), **{d: version(d) for d in dists}, "opencv": cv2.__version__,
            "load_before": loadavg()}
    print(f"{meta['date']}, {meta['cpu']}, {meta['cores']} cores, load before {meta['load_before']}, "
          + ", ".join(f"{d} {meta[d]}" for d in dists) + f", opencv {meta['opencv']}", flush=True)
    sizes = [tuple(int(v) for v in size.lower().split("x")) for size in args.sizes]
    pools = {wh: camera_frames(*wh) for wh in sizes}
    configs = [(wh, mode, transport) for wh in sizes for mode in args.modes for transport in args.transports
               if not (transport == "ws-deflate" and mode == "paced")]  # deflate: CPU, shown by the closed loop
    runs = []
    for rep in range(args.repeat):  # round robin, so that a change of load hits every configuration alike
        for wh, mode, transport in configs:
            r = asyncio.run(run_one(transport, mode, pools[wh], args))
            r.update(size=f"{wh[0]}×{wh[1]}", rate=args.rate, repeat=rep, load=loadavg())
            runs.append(r)
            print(table([r]).splitlines()[-1] + f"  (run {rep + 1}, load {r['load']})", flush=True)
    rows = [combine([r for r in runs if (r["size"], r["mode"], r["transport"]) == (f"{w}×{h}", mode, transport)])
            for (w, h), mode, transport in configs]
    meta["load_after_transports"] = loadavg()
    foot = None
    if args.footprint and any(t in STACKS for t in args.transports):
        print("\nserver footprint", flush=True)
        foot = footprint(args.transports, pools, args)
    meta["load_after"] = loadavg()
    print(f"\nload before {meta['load_before']}, after {meta['load_after']}\n")
    print(table(rows))
    if foot:
        print("\n" + import_table(foot["imports"]) + "\n\n" + footprint_table(foot["rows"]))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"meta": meta, "rows": rows, "runs": runs, "footprint": foot}, f, indent=1)


if __name__ == "__main__":
    main()
