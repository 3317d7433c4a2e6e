"""Frame sources: video files, live cameras and network streams behind one interface.

:func:`open_source` takes a video file path, a camera index (an int or a string of digits) or a URL that
FFmpeg opens (anything of the form ``scheme://...``: rtsp, rtmp, tcp, udp, http(s), srt, ...).

Every source iterates BGR uint8 frames (``__iter__``), has :meth:`frames_with_luma` yielding (BGR, luma or
None), ``width``, ``height``, ``fps``, ``frames_hint``, ``live``, ``dropped``, ``last_time`` (timestamp in
seconds of the frame last yielded) and :meth:`close`.

* A file (``live`` False) is a :class:`physar.ar.video.VideoReader`: every frame, decoded ahead in a thread.
* A live source (:class:`LiveSource`: camera, URL, or a file with ``live=True`` replayed at its frame rate)
  is read by a background thread into a one-slot "latest" buffer: when the consumer is slower than the
  source the older frame is dropped (counted in ``dropped``), never queued, so at most one decoded frame
  waits. Timestamps are the stream's presentation times (PTS, s) for PyAV streams and the capture time
  (``time.time()``, s) for cameras. A stream that ends or closes ends the iteration; so does a stop request
  of a :class:`physar.output.SignalGuard` while waiting for a frame. A URL with ``live=False`` is read
  without dropping (a bounded queue of 8 frames that blocks the reader thread).
"""
from __future__ import annotations

import collections
import contextlib
import re
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from physar import media
from physar.errors import ConfigError, PhysarError
from physar.output import stop_requested

_URL = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*://")


def is_url(spec) -> bool:
    """True for a string of the form ``scheme://...``."""
    return isinstance(spec, str) and bool(_URL.match(spec))


class LiveSource:
    """Frames produced by ``producer`` (an iterator of (BGR, luma or None, timestamp s)) in a background thread.

    ``latest=True``: a one-slot buffer, a new frame replacing one not yet taken (``dropped`` counts those);
    ``latest=False``: a bounded queue of ``queue_size`` frames that makes the producer wait (nothing
    dropped). ``first``: a frame already produced (e.g. decoded on open to learn the size), delivered first.
    ``on_close()`` is called in the reader thread when the producer stops (e.g. closes the container).
    ``produced`` counts the frames the producer gave, ``delivered`` those yielded; ``ended_by`` says why the
    producer stopped early (an error of the stream, as text) or is None. A producer that fails ends the
    iteration with a PhysarError naming the source and the error, after the frames it gave (a frame loop
    keeps its outputs for them and exits non-zero: a network drop is not the end of a clip).
    """

    live = True

    def __init__(self, producer: Iterator, *, width: int, height: int, fps: float, name: str,
                 latest: bool = True, queue_size: int = 8, first=None, on_close: Callable | None = None):
        self.width, self.height, self.fps = int(width), int(height), float(fps)
        self.frames_hint = 0
        self.name = name
        self.live = bool(latest)
        self.dropped = self.produced = self.delivered = 0
        self.last_time = None
        self.ended_by: str | None = None
        self._error: Exception | None = None
        self._producer = producer
        self._cap = 1 if latest else max(1, int(queue_size))
        self._buf: collections.deque = collections.deque()
        self._cond = threading.Condition()
        self._done = False
        self._stop = threading.Event()
        self._on_close = on_close
        if first is not None:
            self._buf.append(first)
            self.produced = 1
        self._thread = threading.Thread(target=self._run, daemon=True, name=f"source {name}")
        self._thread.start()

    @property
    def buffered(self) -> int:
        """Frames waiting to be taken (at most 1 for a latest-frame source)."""
        return len(self._buf)

    def _run(self):
        try:
            for item in self._producer:
                with self._cond:
                    if self._cap == 1 and self.live:
                        if self._buf:
                            self._buf.clear()
                            self.dropped += 1
                    else:
                        while len(self._buf) >= self._cap and not self._stop.is_set():
                            self._cond.wait(0.1)
                    if self._stop.is_set():
                        break
                    self._buf.append(item)
                    self.produced += 1
                    self._cond.notify_all()
        except Exception as e:  # noqa: BLE001 - a live stream that fails ends; the reason is kept
            self.ended_by = f"{type(e).__name__}: {e}"
            self._error = e
        finally:
            if self._on_close is not None:
                with contextlib.suppress(Exception):  # best effort, like closing a file twice
                    self._on_close()
            with self._cond:
                self._done = True
                self._cond.notify_all()

    def frames_with_luma(self):
        """(BGR uint8 (h, w, 3), luma uint8 (h, w) or None) of the newest frame each time, until the source
        ends, :meth:`close` is called or a signal guard asks to stop."""
        while True:
            with self._cond:
                while not self._buf and not self._done:
                    if self._stop.is_set() or stop_requested():
                        return
                    self._cond.wait(0.1)
                if not self._buf:
                    self._raise_error()
                    return
                bgr, luma, t = self._buf.popleft()
                self._cond.notify_all()
            self.last_time = t
            self.delivered += 1
            yield bgr, luma
            if self._stop.is_set():
                return

    def _raise_error(self) -> None:
        """Raise the producer's error once (a PhysarError as it is, e.g. :class:`physar.media.VideoChanged`,
        anything else as a PhysarError naming the source), unless the source was closed or asked to stop."""
        e, self._error = self._error, None
        if e is None or self._stop.is_set():
            return
        if isinstance(e, PhysarError):
            raise e
        raise PhysarError(f"{self.name}: the stream failed after {self.produced} frames ({self.ended_by})")

    def __iter__(self):
        for bgr, _ in self.frames_with_luma():
            yield bgr

    def close(self, timeout: float = 2.0) -> None:
        """Stop the reader thread (waits up to ``timeout`` s for it: a blocked network read ends within the
        stream's read timeout)."""
        self._stop.set()
        with self._cond:
            self._buf.clear()
            self._cond.notify_all()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _frames_of(frames: Iterator, convert: str) -> Iterator:
    """(BGR, luma, time s) of the checked frames (displayed orientation; the first frame already taken)."""
    for f in frames:
        yield (*media.to_bgr(f, convert), f.time)


def _open_av(spec: str, what: str, timeout: float, options: dict | None):
    """(container, stream, first decoded frame) of ``spec``; PhysarError naming it on failure."""
    import av

    waited = (av.ExitError, TimeoutError)  # PyAV's interrupt callback ended a read after ``timeout`` s
    try:
        c = av.open(spec, options=dict(options or {}), timeout=(timeout, timeout))
    except waited:
        raise PhysarError(f"{spec}: cannot open {what}: nothing arrived within the {timeout:g} s timeout (is the "
                          "sender running, sending to this address and port?)") from None
    except (av.FFmpegError, OSError, ValueError) as e:
        raise PhysarError(f"{spec}: cannot open {what} ({type(e).__name__}: {e})") from None
    try:
        if not c.streams.video:
            raise PhysarError(f"{spec}: no video stream in the {what}")
        s = c.streams.video[0]
        s.thread_type = "AUTO"
        first = next(c.decode(s))
    except PhysarError:
        c.close()
        raise
    except StopIteration:
        c.close()
        raise PhysarError(f"{spec}: the {what} ended before its first frame") from None
    except waited:
        c.close()
        raise PhysarError(f"{spec}: no frame of the {what} arrived within the {timeout:g} s timeout") from None
    except (av.FFmpegError, OSError, ValueError) as e:
        c.close()
        raise PhysarError(f"{spec}: cannot decode the {what} ({type(e).__name__}: {e})") from None
    return c, s, first


def _paced(frames: Iterator, stop: Callable[[], bool]) -> Iterator:
    """``frames`` released at their timestamps' pace in real time (a file replayed as if live)."""
    t0 = None
    for bgr, luma, t in frames:
        now = time.perf_counter()
        if t is not None:
            if t0 is None:
                t0 = now - t
            wait = t0 + t - now
            if wait > 0:
                time.sleep(wait)
        if stop():
            return
        yield bgr, luma, t


def open_stream(url: str, *, convert: str = "opencv", live: bool = True, timeout: float = 5.0,
                options: dict | None = None) -> LiveSource:
    """A :class:`LiveSource` of an FFmpeg URL (or, with ``live=True``, a file replayed at its frame rate).

    ``timeout`` (s) bounds opening and each read (PyAV's interrupt callback), so a URL that does not answer
    fails within it with a PhysarError naming the URL; ``options``: FFmpeg format/protocol options. Frames are
    in their displayed orientation (:mod:`physar.media`); a frame of another size than the first ends the
    source with :class:`physar.media.VideoChanged` after the frames before it."""
    c, s, first = _open_av(url, "stream", timeout, options)
    rate = s.average_rate or s.guessed_rate
    fps = float(rate) if rate else 30.0
    checked = media.Checked(c.decode(s), url, "stream", first=first)
    it = iter(checked)
    next(it)  # the first frame: the size the others are checked against
    frames = _frames_of(it, convert)
    holder: dict = {}
    if not is_url(url):
        frames = _paced(frames, lambda: "src" in holder and holder["src"]._stop.is_set())  # set once built
    src = LiveSource(frames, width=checked.size[0], height=checked.size[1], fps=fps, name=url, latest=live,
                     first=(*media.to_bgr(first, convert), first.time), on_close=c.close)
    holder["src"] = src
    return src


def open_camera(index: int, width: int | None = None, height: int | None = None) -> LiveSource:
    """A :class:`LiveSource` of the OpenCV camera ``index`` (``width``/``height`` requested from the driver);
    timestamps are capture times (``time.time()``, s)."""
    import cv2

    cap = cv2.VideoCapture(int(index))
    if not cap.isOpened():
        raise PhysarError(f"cannot open camera {index}")
    if width:
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
    if height:
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
    ok, img = cap.read()
    if not ok:
        cap.release()
        raise PhysarError(f"camera {index} gives no frames")
    first = (img, None, time.time())

    def frames():
        while True:
            ok, im = cap.read()
            if not ok:
                return
            yield im, None, time.time()

    h, w = img.shape[:2]
    return LiveSource(frames(), width=w, height=h, fps=float(cap.get(cv2.CAP_PROP_FPS) or 30.0),
                      name=f"camera {index}", first=first, on_close=cap.release)


def open_source(spec, *, width: int | None = None, height: int | None = None, convert: str = "opencv",
                live: bool | None = None, timeout: float = 5.0, options: dict | None = None):
    """Open ``spec``: a video file path, a camera index (int or digits) or an FFmpeg URL (``scheme://...``).

    ``live``: None for the default of the kind (file: every frame, a
    :class:`physar.ar.video.VideoReader`; camera and URL: a latest-frame :class:`LiveSource`); True replays
    a file at its frame rate with dropping; False reads a URL without dropping. ``width``/``height``: the
    size requested from a camera. ``convert``: "opencv" or "ffmpeg" colour conversion (see VideoReader).
    ``timeout`` (s) and ``options`` apply to URLs. Raises PhysarError (one line naming ``spec``) when it
    cannot be opened or gives no frame."""
    if convert not in ("ffmpeg", "opencv"):
        raise ConfigError(f"colour conversion must be 'ffmpeg' or 'opencv', got {convert!r}")
    if isinstance(spec, bool) or not isinstance(spec, (str, int, Path)):
        raise ConfigError(f"source must be a video file, a camera index or a URL, got {spec!r}")
    if isinstance(spec, int) or (isinstance(spec, str) and spec.isdigit()):
        if live is False:
            raise ConfigError(f"camera {spec} is live; live=False applies to files and URLs")
        return open_camera(int(spec), width, height)
    if is_url(str(spec)):
        if not timeout or timeout <= 0:
            raise ConfigError(f"{spec}: timeout must be > 0 s, got {timeout}")
        return open_stream(str(spec), convert=convert, live=live is not False, timeout=timeout, options=options)
    if live:
        from physar.ar.video import VideoReader

        VideoReader(spec, threaded=False).close()  # the file checks and their messages
        return open_stream(str(spec), convert=convert, live=True, timeout=timeout)
    from physar.ar.video import VideoReader

    return VideoReader(spec, convert=convert)


class PushSource:
    """Frames pushed by another thread or an event loop (e.g. a web page's camera, :mod:`physar.ar.live`):
    :meth:`push` puts an item in a one-slot "latest" buffer, replacing one not yet taken (counted in
    ``dropped``), so a consumer slower than the pusher sees the newest item and nothing queues.

    Items are whatever the pusher gives (the consumer decodes them); iteration yields them until
    :meth:`close`. ``width``, ``height``, ``fps`` (nominal, for a recording) describe the frames expected;
    ``last_time`` is the timestamp given with the item last yielded."""

    live = True

    def __init__(self, width: int, height: int, fps: float = 30.0, name: str = "pushed frames"):
        self.width, self.height, self.fps, self.name = int(width), int(height), float(fps), name
        self.frames_hint = 0
        self.dropped = self.pushed = self.delivered = 0
        self.last_time = None
        self._slot = None
        self._cond = threading.Condition()
        self._closed = False

    def push(self, item, timestamp: float | None = None) -> bool:
        """Offer ``item`` (timestamp in s, default now); False once closed."""
        with self._cond:
            if self._closed:
                return False
            if self._slot is not None:
                self.dropped += 1
            self._slot = (item, time.time() if timestamp is None else float(timestamp))
            self.pushed += 1
            self._cond.notify_all()
            return True

    def __iter__(self):
        while True:
            with self._cond:
                while self._slot is None and not self._closed:
                    if stop_requested():
                        return
                    self._cond.wait(0.1)
                if self._slot is None:
                    return
                item, t = self._slot
                self._slot = None
            self.last_time = t
            self.delivered += 1
            yield item

    def close(self) -> None:
        """End the iteration (an item not yet taken is discarded); pushes after this are refused."""
        with self._cond:
            self._closed = True
            self._slot = None
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed


def from_frames(frames, *, fps: float = 30.0, name: str = "frames", latest: bool = True) -> LiveSource:
    """A :class:`LiveSource` over an iterable of BGR frames or (BGR, timestamp s) pairs (e.g. a generator
    that produces faster than it is consumed); the size is the first frame's. Timestamps default to the
    production time."""
    it = iter(frames)

    def items():
        for f in it:
            img, t = f if isinstance(f, tuple) else (f, time.time())
            yield np.ascontiguousarray(img), None, t

    gen = items()
    try:
        first = next(gen)
    except StopIteration:
        raise PhysarError(f"{name}: no frames") from None
    h, w = first[0].shape[:2]
    return LiveSource(gen, width=w, height=h, fps=fps, name=name, latest=latest, first=first)


__all__ = ["LiveSource", "PushSource", "from_frames", "open_camera", "open_source", "open_stream"]
