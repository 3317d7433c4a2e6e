"""Live AR in a web browser (`physar ar serve`): a phone or laptop opens one page, grants its camera, and sees
its own video augmented by the project's physics (seed 000 §2.1: observe, assimilate, augment at video rate).

Transport (chosen by measurement, benchmarks/RESULTS.md "Live AR transport"): JPEG frames over one WebSocket
per page. The page crops its camera to the project camera's aspect ratio, scales it to the camera's size,
sends each frame as ``HEADER`` (capture time [ms, the page's clock], sequence number, flags) + JPEG, and keeps at
most two frames unanswered. The server decodes them into a :class:`physar.ar.sources.PushSource` (a one-slot
"latest" buffer: when the server is slower than the camera the older frame is dropped, never queued), runs
the project's one frame loop (:class:`physar.ar.project_pipeline.ProjectPipeline` through
:func:`physar.ar.runner.run_video`, which also records the augmented MP4 and the estimates CSV progressively
and atomically), and broadcasts each augmented frame to every page as one binary message: uint32 n, n bytes of
JSON (frame, seq, stamp, camera, status, mu, std, residual, server latency), then the JPEG. The camera page
(and any page opened with ``?overlay=page``; ``?overlay=server`` keeps the JPEG frames) draws the overlay
itself on its own live video instead (measured faster: RESULTS.md "Live AR in a browser"): it gets the surface triangles and
the colour table once (in the first "info" message) and per frame the JSON plus the geometry of
:meth:`physar.ar.surface.SurfaceOverlay.geometry` (float32 vertex pixels, uint32 visible faces far to near,
uint8 colour levels: a few kB instead of a JPEG); the server then renders and encodes an augmented frame
only when a page of the other kind is open or a recording is made. Each page has a one-slot send buffer,
so a slow viewer skips frames instead of growing a queue.

Sessions: one project, one filter; any number of viewers; the page that last pressed "Start camera" is the
camera (the previous one is told and stops), and a new camera stream resets the filter and the pose tracker.
A closed connection frees its slot at once.

Security: binds to 127.0.0.1 by default. On any other interface it needs TLS (``--tls CERT KEY`` or
``--self-signed``; browsers give the camera only to secure pages) and an access token, random per run, in
the URL (compared in constant time; the page and the WebSocket refuse requests without it). The server has
exactly two routes (the page, the WebSocket): nothing of the file system is reachable. Message sizes are
bounded (an oversized message closes the connection, code 1009), HTTP bodies too, and so is the number of
connections; a WebSocket from a page of another origin is refused.
"""
from __future__ import annotations

import asyncio
import contextlib
import hmac
import ipaddress
import itertools
import json
import math
import secrets
import socket
import ssl
import struct
import threading
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import cv2
import numpy as np

from physar.ar.project_pipeline import STAGES, ProjectPipeline
from physar.ar.runner import run_video
from physar.ar.sources import PushSource
from physar.errors import ConfigError, PhysarError

HEADER = struct.Struct("<dII")   # page capture time [ms], frame sequence number, flags (0)
MAX_PEERS = 32
MAX_TEXT = 4096                  # bytes of a page's command


def is_loopback(host: str) -> bool:
    """True for "localhost" and loopback addresses (127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def lan_address() -> str:
    """This machine's address on its default route (no packet is sent), or 127.0.0.1 without one."""
    with contextlib.suppress(OSError), socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.connect(("10.255.255.255", 1))
        return s.getsockname()[0]
    return "127.0.0.1"


def self_signed_context(hosts: list[str], days: int = 30) -> tuple[ssl.SSLContext, str]:
    """A TLS server context with a fresh self-signed certificate (EC P-256) for ``hosts`` (names or IPs) and
    its SHA-256 fingerprint (to compare with the browser's warning page). The key never touches a file that
    outlives this call."""
    import datetime
    import os
    import tempfile

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    names = []
    for h in dict.fromkeys(hosts):
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            names.append(x509.DNSName(h))
    now = datetime.datetime.now(datetime.UTC)
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "physar ar serve")])
    cert = (x509.CertificateBuilder().subject_name(subject).issuer_name(subject).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.SubjectAlternativeName(names), critical=False)
            .sign(key, hashes.SHA256()))
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    with tempfile.TemporaryDirectory(prefix="physar-tls-") as d:
        kp, cp = os.path.join(d, "key.pem"), os.path.join(d, "cert.pem")
        fd = os.open(kp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                      serialization.NoEncryption()))
        with open(cp, "wb") as f:
            f.write(cert.public_bytes(serialization.Encoding.PEM))
        ctx.load_cert_chain(cp, kp)
    fp = cert.fingerprint(hashes.SHA256()).hex(":").upper()
    return ctx, fp


def tls_context(cert: Path, key: Path) -> ssl.SSLContext:
    """A TLS server context from the user's PEM certificate and key; ConfigError naming the file otherwise."""
    for p, what in ((cert, "certificate"), (key, "key")):
        if not Path(p).is_file():
            raise ConfigError(f"{p}: TLS {what} file " + ("is a folder" if Path(p).is_dir() else "not found"))
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    try:   # (an empty password: an encrypted key fails here instead of prompting on the terminal)
        ctx.load_cert_chain(str(cert), str(key), password=b"")
    except (ssl.SSLError, OSError, ValueError) as e:
        raise ConfigError(f"{cert} / {key}: not a PEM certificate and its unencrypted key ({e})") from None
    return ctx


def _finite(v) -> list:
    return [float(x) if math.isfinite(float(x)) else None for x in np.asarray(v, float)]


class LiveSession:
    """The frame loop of one project fed by pushed frames (see the module doc). Runs in its own thread
    (:meth:`start`, :meth:`stop`); ``publish(meta: dict, jpeg: bytes)`` and ``notify(peer id, message: dict)``
    are called from that thread (the server makes them thread-safe). Recording: ``out_video`` (MP4) and
    ``out_csv`` as in :func:`physar.ar.runner.run_video` (progressive, renamed when the session stops)."""

    def __init__(self, project, out_video=None, out_csv=None, *, quality: int = 80, fps: float = 30.0,
                 crf: int = 20, preset: str = "ultrafast"):
        if not 1 <= int(quality) <= 100:
            raise ConfigError(f"JPEG quality must be within 1..100, got {quality}")
        self.project = project
        self.camera = project.camera
        self.pipe = ProjectPipeline(project)
        self.source = PushSource(self.camera.width, self.camera.height, fps, name="the browser camera")
        self.quality = int(quality)
        self.out_video, self.out_csv, self.fps, self.crf, self.preset = out_video, out_csv, fps, crf, preset
        self.publish = lambda meta, jpeg, geom: None
        self.wants = lambda: (True, False)      # (augmented JPEG, overlay geometry) wanted by the pages
        self.notify = lambda peer, msg: None
        self.summary: dict | None = None
        self.error: str | None = None
        self.resets = 0
        self.ready = threading.Event()          # set once the recording is open and frames are awaited
        self._last_camera = None
        self.failed = False
        self._thread = threading.Thread(target=self._run, daemon=True, name="physar live session")

    def info(self) -> dict:
        """What a page needs to lay itself out: the camera size, the parameters, their units and ranges."""
        rom = self.pipe.rom
        return {"type": "info", "width": self.camera.width, "height": self.camera.height,
                "names": list(rom.names), "units": list(rom.units), "ranges": [list(map(float, r)) for r in rom.ranges],
                "field": self.project.overlay.field, "recording": bool(self.out_video or self.out_csv),
                "mesh": self._mesh()}

    def _mesh(self) -> dict | None:
        """What a page needs to draw the overlay itself: the surface triangles (vertex ids), the colour table
        (RGB), the field's range, label and display unit, the opacity."""
        ov = self.pipe.overlay
        if ov is None:
            return None
        return {"faces": ov.faces.astype(int).ravel().tolist(), "n_vertices": len(ov.X0),
                "lut": ov.lut[:, ::-1].astype(int).tolist(), "range": list(ov.vrange), "label": ov.label,
                "unit": ov.unit, "scale": ov.scale, "alpha": ov.alpha}

    def _geometry(self) -> tuple[dict | None, bytes]:
        """The frame's overlay for a page that draws it: float32 vertex pixels (v, 2), uint32 visible face
        ids far to near, uint8 colour levels; (None, b"") when there is nothing to draw."""
        ov, pose = self.pipe.overlay, self.pipe.last_pose
        if ov is None or pose is None or self.pipe.last_status == "lost" or not self.pipe.has_estimate:
            return None, b""
        mu = self.pipe.mu
        p, ids, lev, vmax = ov.geometry(self.camera, pose, self.pipe.view_coefficients(), mu)
        arrow = ov.arrow(self.camera, pose, mu)
        meta = {"faces": 0 if ids is None else len(ids), "field_max": vmax,
                "arrow": None if arrow is None else arrow.tolist()}
        if ids is None:
            return meta, b""
        return meta, (np.asarray(p, np.float32).tobytes() + ids.astype(np.uint32).tobytes()
                      + lev.astype(np.uint8).tobytes())

    def feed(self, peer: int, data: bytes, stream: int = 0) -> None:
        """A camera message (``HEADER`` + encoded image) from page ``peer`` in its camera stream ``stream`` (a
        new stream resets the filter); the newest replaces one waiting."""
        stamp, seq, _flags = HEADER.unpack_from(data)
        stamp = stamp if math.isfinite(stamp) else None
        self.source.push(((peer, stream), stamp, seq, data[HEADER.size:]))

    def _frames(self, reader):
        w, h = self.camera.size
        self.ready.set()                          # (run_video has opened the recording)
        for (peer, stream), stamp, seq, blob in reader:
            img = cv2.imdecode(np.frombuffer(blob, np.uint8), cv2.IMREAD_COLOR)
            if img is None:
                self.notify(peer, {"type": "error", "seq": seq, "message": "the frame is not a JPEG/PNG/WebP image"})
                continue
            if img.shape[:2] != (h, w):
                self.notify(peer, {"type": "error", "seq": seq, "message": f"the frame is {img.shape[1]}x"
                                   f"{img.shape[0]} but the project's camera is for {w}x{h}"})
                continue
            yield img, ((peer, stream), stamp, seq, time.perf_counter())

    def _step(self, k, item, draw):
        img, (stream, stamp, seq, t_in) = item
        peer = stream[0]
        if stream != self._last_camera:          # a new camera stream (another page, or Start again): afresh
            if self._last_camera is not None:
                self.resets += 1
            self.pipe.reset()
            self._last_camera = stream
        want_jpeg, want_geom = self.wants()
        out, r = self.pipe.process(img, k, draw=draw or want_jpeg)
        t0 = time.perf_counter()
        jpeg = geom = None
        if want_jpeg:
            ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, self.quality])
            jpeg = buf.tobytes() if ok else None
        r.stages_ms["jpeg"] = (time.perf_counter() - t0) * 1e3
        meta = {"type": "frame", "frame": k, "seq": seq, "stamp": stamp, "camera": peer, "status": r.status,
                "mu": _finite(r.mu), "std": _finite(r.std), "residual_px": _finite([r.residual_px])[0],
                "dropped": self.source.dropped}
        if want_geom:
            t1 = time.perf_counter()
            gmeta, gbytes = self._geometry()
            geom = (gmeta, gbytes)
            r.stages_ms["geometry"] = (time.perf_counter() - t1) * 1e3
        meta["server_ms"] = (time.perf_counter() - t_in) * 1e3
        self.publish(meta, jpeg, geom)
        return out, r

    def _run(self):
        try:
            self.summary = run_video(self._step, self.camera, self.source, self.out_video, self.out_csv,
                                     self.fps, self.crf, self.pipe.csv_header(), self.pipe.csv_row, None, None,
                                     None, (*STAGES, "jpeg", "geometry"), preset=self.preset, convert="opencv",
                                     frames=self._frames, time_io=True, cpu=True, keep_results=False,
                                     handle_signals=False)
        except PhysarError as e:   # no frame came before the end (nothing recorded), or a failure
            self.summary, self.error = {"frames": 0}, str(e)
            if not self.source.closed:
                self.failed = True
                self.notify(None, {"type": "error", "message": f"the server's session stopped: {self.error}"})
        except Exception as e:  # noqa: BLE001 - reported to the pages; serve() then stops with the error
            self.summary, self.error = {"frames": 0}, f"{type(e).__name__}: {e}"
            self.failed = True
            self.notify(None, {"type": "error", "message": f"the server's session stopped: {self.error}"})
        finally:
            self.ready.set()

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float = 60.0) -> dict:
        """End the session: the frame source closes, the recording (if any) is finished and renamed."""
        self.source.close()
        if self._thread.ident is not None:      # (started)
            self._thread.join(timeout)
        return self.summary or {"frames": 0}


@dataclass(eq=False)
class _Peer:
    ws: object
    id: int
    mode: str = "server"      # "server": augmented JPEG frames; "page": the overlay's geometry, drawn by the page
    pending: bytes | None = None
    wake: asyncio.Event = field(default_factory=asyncio.Event)


class LiveServer:
    """The web server of a :class:`LiveSession`: ``/`` (the page) and ``/ws`` (frames both ways).

    ``token``: required in the URL (``?token=...``) of both routes when given; ``max_message`` [bytes]: the
    largest WebSocket message accepted (default: an uncompressed frame of the camera's size)."""

    def __init__(self, session: LiveSession, *, token: str | None = None, max_message: int | None = None,
                 max_peers: int = MAX_PEERS):
        self.session, self.token, self.max_peers = session, token, int(max_peers)
        self.hosts: set[str] | None = None      # Host headers accepted (loopback binds; set by start())
        self.camera_stream = 0
        w, h = session.camera.size
        self.max_message = int(max_message or w * h * 3 + HEADER.size)
        self.peers: dict[int, _Peer] = {}
        self.camera_peer: int | None = None
        self._ids = itertools.count(1)
        self._tasks: set = set()
        self._loop: asyncio.AbstractEventLoop | None = None
        self.page = resources.files("physar.ar").joinpath("live_page.html").read_text(encoding="utf-8")

    # -- the app -------------------------------------------------------------------------------------------
    def app(self):
        from aiohttp import web

        app = web.Application(client_max_size=64 * 1024, middlewares=[self._middleware()])
        app.router.add_get("/", self._page)
        app.router.add_get("/ws", self._ws)
        app.on_startup.append(self._on_startup)
        return app

    async def _on_startup(self, app):
        self._loop = asyncio.get_running_loop()
        loop = self._loop

        def publish(meta, jpeg, geom):
            with contextlib.suppress(RuntimeError):      # the loop has closed: nobody to tell
                loop.call_soon_threadsafe(self._broadcast, meta, jpeg, geom)

        def wants():
            modes = [p.mode for p in list(self.peers.values())]
            return "server" in modes, "page" in modes

        def notify(peer, msg):                          # peer None: every page
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(self._send_text, peer, msg)

        self.session.publish, self.session.notify, self.session.wants = publish, notify, wants

    def _authorised(self, request) -> bool:
        if self.token is None:
            return True
        return hmac.compare_digest(request.query.get("token", "").encode(), self.token.encode())

    @staticmethod
    def _same_origin(request) -> bool:
        origin = request.headers.get("Origin")
        if origin is None:                # not a browser page (a script, a test client)
            return True
        from urllib.parse import urlsplit

        return urlsplit(origin).netloc == request.host

    def _middleware(self):
        from aiohttp import web

        @web.middleware
        async def guard(request, handler):
            if self.hosts is not None and request.host.lower() not in self.hosts:   # DNS rebinding
                return web.Response(status=403, text="physar: unexpected Host header; open the URL printed "
                                                     "when the server started\n")
            if not self._authorised(request):
                return web.Response(status=403, text="physar: missing or wrong access token (use the URL "
                                                     "printed when the server started)\n")
            resp = await handler(request)
            resp.headers.setdefault("Cache-Control", "no-store")
            resp.headers.setdefault("Referrer-Policy", "no-referrer")
            resp.headers.setdefault("X-Content-Type-Options", "nosniff")
            return resp

        return guard

    async def _page(self, request):
        from aiohttp import web

        nonce = secrets.token_urlsafe(16)
        csp = (f"default-src 'none'; script-src 'nonce-{nonce}'; style-src 'nonce-{nonce}'; img-src blob: data:; "
               f"media-src blob: mediastream:; connect-src 'self' ws://{request.host} wss://{request.host}; "
               "base-uri 'none'; form-action 'none'; frame-ancestors 'none'")
        return web.Response(text=self.page.replace("__NONCE__", nonce), content_type="text/html",
                            headers={"Content-Security-Policy": csp})

    async def _ws(self, request):
        from aiohttp import WSMsgType, web

        if not self._same_origin(request):
            return web.Response(status=403, text="physar: WebSocket from another origin refused\n")
        if len(self.peers) >= self.max_peers:
            return web.Response(status=503, text=f"physar: {self.max_peers} pages already connected\n")
        mode = request.query.get("overlay", "server")
        if mode not in ("server", "page"):
            return web.Response(status=400, text=f"physar: overlay must be 'server' or 'page', got {mode[:40]!r}\n")
        ws = web.WebSocketResponse(max_msg_size=self.max_message, heartbeat=20.0,
                                   compress=False)   # deflate on JPEG: no gain, 1.8x the CPU (RESULTS.md)
        await ws.prepare(request)
        peer = _Peer(ws, next(self._ids), mode)
        self.peers[peer.id] = peer
        sender = asyncio.create_task(self._sender(peer))
        try:
            await ws.send_json({**self.session.info(), "you": peer.id, "max_message": self.max_message})
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    if len(msg.data) > MAX_TEXT:
                        await ws.close(code=1009, message=b"command too long")
                        break
                    self._command(peer, msg.data)
                elif msg.type == WSMsgType.BINARY:
                    if peer.id == self.camera_peer and len(msg.data) > HEADER.size:
                        self.session.feed(peer.id, msg.data, self.camera_stream)
                elif msg.type == WSMsgType.ERROR:
                    break
        finally:
            self.peers.pop(peer.id, None)
            if self.camera_peer == peer.id:
                self.camera_peer = None
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await sender
        return ws

    def _command(self, peer: _Peer, text: str) -> None:
        try:
            cmd = json.loads(text)
        except ValueError:
            cmd = None
        kind = cmd.get("type") if isinstance(cmd, dict) else None
        if kind == "camera":                         # this page becomes the camera: a new stream
            old = self.camera_peer
            self.camera_peer = peer.id
            self.camera_stream += 1
            if old is not None and old != peer.id:
                self._send_text(old, {"type": "camera_taken", "by": peer.id})
        elif kind == "stop_camera" and self.camera_peer == peer.id:
            self.camera_peer = None
        elif kind == "overlay" and cmd.get("mode") in ("server", "page"):   # what this page gets per frame
            peer.mode = cmd["mode"]
        else:
            self._send_text(peer.id, {"type": "error", "message": f"unknown command {text[:80]!r}"})

    def _send_text(self, peer_id: int | None, msg: dict) -> None:
        """Send ``msg`` to page ``peer_id`` (None: to every page)."""
        text = json.dumps(msg, allow_nan=False)
        for p in ([self.peers.get(peer_id)] if peer_id is not None else list(self.peers.values())):
            if p is None or p.ws.closed:
                continue

            async def send(p=p):
                with contextlib.suppress(ConnectionError, RuntimeError):   # the page has just gone
                    await p.ws.send_str(text)

            task = asyncio.ensure_future(send())
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

    @staticmethod
    def _pack(meta: dict, body: bytes) -> bytes:
        head = json.dumps(meta, allow_nan=False).encode()
        return struct.pack("<I", len(head)) + head + body

    def _broadcast(self, meta: dict, jpeg: bytes | None, geom) -> None:
        """Each page gets what it draws: the augmented JPEG, or the overlay's geometry (meta["geometry"])."""
        payloads = {}
        if jpeg is not None:
            payloads["server"] = self._pack(meta, jpeg)
        if geom is not None:
            payloads["page"] = self._pack({**meta, "geometry": geom[0]}, geom[1])
        for p in self.peers.values():
            data = payloads.get(p.mode)
            if data is None:
                continue
            p.pending = data                 # (replaces a frame this page has not been sent yet)
            p.wake.set()

    async def _sender(self, peer: _Peer) -> None:
        while True:
            await peer.wake.wait()
            peer.wake.clear()
            data, peer.pending = peer.pending, None
            if data is None or peer.ws.closed:
                continue
            try:
                await peer.ws.send_bytes(data)
            except (ConnectionError, RuntimeError):
                return

    # -- running -------------------------------------------------------------------------------------------
    async def start(self, host: str, port: int, ssl_context=None):
        """Start serving; returns the aiohttp runner (``await runner.cleanup()`` to stop)."""
        from aiohttp import web

        runner = web.AppRunner(self.app(), access_log=None, handle_signals=False, shutdown_timeout=1.0)
        await runner.setup()
        site = web.TCPSite(runner, host, port, ssl_context=ssl_context)
        try:
            await site.start()
        except OSError as e:
            await runner.cleanup()
            raise ConfigError(f"cannot listen on {host}:{port} ({e.strerror or e})") from None
        self.port = site._server.sockets[0].getsockname()[1] if port == 0 else port
        if is_loopback(host):    # only this machine's names: a page of another site rebound to 127.0.0.1 is refused
            self.hosts = {f"{h}:{self.port}" for h in ("127.0.0.1", "localhost", "[::1]", host.lower())}
        return runner


def page_url(host: str, port: int, tls: bool, token: str | None) -> str:
    """The URL to open: the machine's LAN address for a wildcard bind, the token in the query."""
    shown = lan_address() if host in ("0.0.0.0", "::", "") else host
    if ":" in shown:
        shown = f"[{shown}]"
    return f"{'https' if tls else 'http'}://{shown}:{port}/" + (f"?token={token}" if token else "")


def serve(project, *, host: str = "127.0.0.1", port: int = 8765, ssl_context=None, token: str | None = None,
          out_video=None, out_csv=None, quality: int = 80, max_message: int | None = None,
          ready=None, stop_event: threading.Event | None = None, log=print) -> dict:
    """Serve ``project`` live until SIGINT/SIGTERM (or ``stop_event``, for a caller in another thread).

    Off loopback a TLS context and a token are required. ``ready(url)`` is called once listening. Returns the
    session summary (frames, fps, latency, dropped, ...; frames 0 when no camera sent any)."""
    if not is_loopback(host):
        if ssl_context is None:
            raise ConfigError(f"--host {host} lets other machines in: give --tls CERT KEY or --self-signed "
                              "(a phone's browser opens its camera only on an https page)")
        token = token or secrets.token_urlsafe(16)
    session = LiveSession(project, out_video, out_csv, quality=quality)
    server = LiveServer(session, token=token, max_message=max_message)
    session.start()                      # opens the recording first: a destination that fails stops here
    session.ready.wait(60)
    if session.failed:
        raise PhysarError(f"cannot start the session: {session.error}")

    async def main():
        import signal

        runner = await server.start(host, port, ssl_context)
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                loop.add_signal_handler(s, stop.set)
        url = page_url(host, server.port, ssl_context is not None, token)
        if ready is not None:
            ready(url)
        try:
            while not (stop.is_set() or session.failed or (stop_event is not None and stop_event.is_set())):
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), 0.2)
        finally:
            session.source.close()       # no more frames; the frame in progress still reaches the pages
            await asyncio.to_thread(session.stop)
            await asyncio.sleep(0.05)
            for p in list(server.peers.values()):
                with contextlib.suppress(Exception):
                    await p.ws.close()
            await runner.cleanup()

    try:
        asyncio.run(main())
    finally:
        summary = session.stop()
    summary.pop("results", None)
    summary["resets"] = session.resets
    summary["dropped"] = session.source.dropped
    if session.failed:
        summary["error"] = session.error
    return summary


__all__ = ["HEADER", "LiveServer", "LiveSession", "is_loopback", "page_url", "self_signed_context", "serve",
           "tls_context"]
