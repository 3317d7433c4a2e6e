"""Video input/output: PyAV (FFmpeg) H.264 in yuv420p (plays in browsers), live cameras via OpenCV,
background threads so that decoding and encoding overlap computing, atomic output files."""
from __future__ import annotations

import contextlib
import queue
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from physar.errors import PhysarError
from physar.output import atomic_path  # moved to physar.output; re-exported for its users


@contextlib.contextmanager
def clip_outputs(video, table, size: tuple[int, int], fps: float, header: Sequence[str] = (), **writer_options):
    """Open the outputs of a frame loop, both optional: ``video`` (an H.264 :class:`VideoWriter` of ``size``
    (width, height) at ``fps``, ``writer_options`` passed on) and ``table`` (a CSV file, ``header`` written
    first).  Yields (VideoWriter or None, csv.writer or None).  Both are written to temporaries next to their
    paths and renamed only when the block completes: an error leaves no partial output. The CSV is line
    buffered (each row reaches the temporary as it is written), so a loop that stops early on a signal
    (:class:`physar.output.SignalGuard`) and leaves the block normally gets a closed, playable MP4 and one
    row per frame written."""
    import csv

    with contextlib.ExitStack() as stack:
        vtmp = stack.enter_context(atomic_path(video)) if video else None
        ctmp = stack.enter_context(atomic_path(table)) if table else None
        writer = stack.enter_context(VideoWriter(vtmp, *size, fps, **writer_options)) if vtmp else None
        rows = csv.writer(stack.enter_context(open(ctmp, "w", newline="", buffering=1))) if ctmp else None
        if rows is not None and header:
            rows.writerow(header)
        yield writer, rows


def write_clip(out_dir, video_name: str, camera, fps: float, crf: int, header: list[str], n_frames: int,
               frame: Callable[[int], tuple[np.ndarray, list]], progress: Callable[[int, int], None] | None = None,
               preset: str = "veryfast", threads: int = 0) -> dict:
    """Render a synthetic clip into ``out_dir``: ``video_name`` (H.264) and ``truth.csv`` (``header``, then one
    row per frame), both written to temporaries and renamed only when every frame is done (no partial outputs),
    then ``camera.toml``.  ``frame(k)`` returns the BGR image and the CSV row of frame k.  Returns the paths
    and the clip's size."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with clip_outputs(out / video_name, out / "truth.csv", camera.size, fps, header, crf=crf, preset=preset,
                      threads=threads) as (vw, rows):
        for k in range(n_frames):
            img, row = frame(k)
            vw.write(img)
            rows.writerow(row)
            if progress:
                progress(k + 1, n_frames)
    camera.save(out / "camera.toml")
    return {"video": str(out / video_name), "truth": str(out / "truth.csv"), "camera": str(out / "camera.toml"),
            "frames": n_frames, "width": camera.width, "height": camera.height, "fps": fps}


class VideoWriter:
    """H.264 (libx264, yuv420p) writer. ``threaded=True`` encodes in a background thread (bounded queue).

    ``threads``: libx264 threads (0: its default, 1.5 per core). ``convert``: BGR -> yuv420p by FFmpeg's
    swscale ("ffmpeg") or by ``cv2.cvtColor(COLOR_BGR2YUV_I420)`` ("opencv": BT.601 limited range like
    swscale, within one grey level of it, about a third of its CPU time here).
    """

    def __init__(self, path, width: int, height: int, fps: float, crf: int = 20, preset: str = "veryfast",
                 threaded: bool = False, threads: int = 0, convert: str = "ffmpeg"):
        from fractions import Fraction

        import av

        if convert not in ("ffmpeg", "opencv"):
            raise PhysarError(f"colour conversion must be 'ffmpeg' or 'opencv', got {convert!r}")
        self.convert = convert
        if width % 2 or height % 2:
            raise PhysarError(f"H.264 yuv420p needs an even frame size, got {width}x{height}")
        self.path = str(path)
        self._c = av.open(self.path, "w", format="mp4")
        rate = Fraction(fps).limit_denominator(1001)
        self._s = self._c.add_stream("libx264", rate=rate)
        self._s.width, self._s.height, self._s.pix_fmt = width, height, "yuv420p"
        self._s.options = {"preset": preset, "crf": str(int(crf))}
        if threads:
            self._s.codec_context.thread_count = int(threads)
        self.size = (width, height)
        self.frames = 0
        self._q = queue.Queue(maxsize=16) if threaded else None
        self._err = None
        self._thread = None
        if threaded:
            self._thread = threading.Thread(target=self._run, daemon=True)
            self._thread.start()

    def _encode(self, img):
        import av

        if self.convert == "opencv":
            import cv2

            f = av.VideoFrame.from_ndarray(cv2.cvtColor(img, cv2.COLOR_BGR2YUV_I420), format="yuv420p")
        else:
            f = av.VideoFrame.from_ndarray(img, format="bgr24")
        for p in self._s.encode(f):
            self._c.mux(p)

    def _run(self):
        while True:
            img = self._q.get()
            if img is None:
                return
            if self._err is None:
                try:
                    if callable(img):  # deferred frame (e.g. an overlay to draw in this thread)
                        img = self._check(img())
                    self._encode(img)
                except Exception as e:  # noqa: BLE001 - re-raised in the caller's thread
                    self._err = e

    def _check(self, img):
        if img.shape[:2] != (self.size[1], self.size[0]) or img.dtype != np.uint8:
            raise PhysarError(f"frame of shape {img.shape} {img.dtype} does not match the video "
                              f"{self.size[0]}x{self.size[1]} uint8")
        return np.ascontiguousarray(img)

    def write(self, img) -> None:
        """Queue a frame (BGR uint8) or, on a threaded writer, a callable returning one: it is called in the
        encoder thread, so drawing can overlap the caller's next frame."""
        if self._err is not None:
            raise self._err
        if callable(img):
            if self._q is None:
                img = img()
            else:
                self.frames += 1
                self._q.put(img)
                return
        img = self._check(img)
        self.frames += 1
        if self._q is not None:
            self._q.put(img)
        else:
            self._encode(img)

    def close(self) -> None:
        if self._c is None:
            return
        try:
            if self._thread is not None:
                self._q.put(None)
                self._thread.join()
                if self._err is not None:
                    raise self._err
            for p in self._s.encode():
                self._c.mux(p)
        finally:
            self._c.close()
            self._c = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def bits_per_pixel(path) -> tuple[float, float, int, int, float] | None:
    r"""(bits per pixel and frame :math:`b / (w h f)`, bit rate b [bit/s], width w, height h, frame rate f) of a
    video file's first video stream, from its container (the stream's own rate, else the file's size over its
    duration); None when the file cannot be read or does not say."""
    import av

    try:
        with av.open(str(path)) as c:
            s = c.streams.video[0]
            w, h = s.codec_context.width, s.codec_context.height
            fps = float(s.average_rate or s.guessed_rate or 0)
            rate = s.bit_rate or c.bit_rate or 0
            if not rate and c.duration:
                rate = Path(path).stat().st_size * 8 / (c.duration / 1e6)
    except (av.FFmpegError, OSError, ValueError, IndexError):
        return None
    if not (rate and w and h and fps):
        return None
    return rate / (w * h * fps), float(rate), w, h, fps


def _to_bgr(frame, convert: str) -> tuple[np.ndarray, np.ndarray | None]:
    """(BGR, luma) of a decoded frame. ``convert="opencv"`` converts 8-bit yuv420p with
    ``cv2.cvtColor(COLOR_YUV2BGR_I420)`` (BT.601, about half the CPU time of FFmpeg's swscale here; values
    within 3 grey levels of it), anything else with swscale."""
    if convert == "opencv" and frame.format.name == "yuv420p" and frame.width % 2 == 0 and frame.height % 2 == 0:
        import cv2

        yuv = frame.to_ndarray()  # (3h/2, w): Y, then U and V
        return cv2.cvtColor(yuv, cv2.COLOR_YUV2BGR_I420), yuv[:frame.height]
    return frame.to_ndarray(format="bgr24"), _luma(frame)


def _luma(frame) -> np.ndarray | None:
    """The decoded frame's luma plane Y (h, w) uint8 when it is stored planar 8-bit YUV (a copy of the plane,
    no colour conversion), else None."""
    if frame.format.name not in ("yuv420p", "yuvj420p", "yuv422p", "yuvj422p", "yuv444p", "yuvj444p", "nv12"):
        return None
    p = frame.planes[0]
    return np.frombuffer(p, np.uint8).reshape(p.height, p.line_size)[:, :frame.width].copy()


class VideoReader:
    """Frames (BGR uint8) of a video file; ``threaded=True`` decodes ahead in a background thread.

    Iterating yields BGR frames; :meth:`frames_with_luma` yields (BGR, Y) pairs, Y being the decoder's own
    luma plane (h, w) (limited range, 16-235; None for non-YUV streams), so that grey-level work needs no
    colour conversion.

    ``last_time``: the presentation time (s) of the frame last yielded (None before the first, or when the
    stream has no timestamps); ``live`` is False and ``dropped`` 0 (a file is read frame by frame; see
    :func:`physar.ar.sources.open_source` for live sources with the same interface).

    Raises PhysarError for a missing, empty or undecodable file (checked on open: the first frame is decoded).
    """

    live = False
    dropped = 0

    def __init__(self, path, threaded: bool = True, prefetch: int = 8, convert: str = "ffmpeg"):
        import av

        if convert not in ("ffmpeg", "opencv"):
            raise PhysarError(f"colour conversion must be 'ffmpeg' or 'opencv', got {convert!r}")
        self.convert = convert
        self.path = Path(path)
        if not self.path.exists():
            raise PhysarError(f"{path}: video file not found")
        if self.path.is_dir():
            raise PhysarError(f"{path}: is a folder, not a video file")
        if self.path.stat().st_size == 0:
            raise PhysarError(f"{path}: video file is empty")
        try:
            self._c = av.open(str(self.path))
            streams = self._c.streams.video
            if not streams:
                raise PhysarError(f"{path}: no video stream in the file")
            self._s = streams[0]
            self._s.thread_type = "AUTO"
            self._it = self._c.decode(self._s)
            first = next(self._it)
        except PhysarError:
            raise
        except StopIteration:
            raise PhysarError(f"{path}: the video has no decodable frame") from None
        except (av.FFmpegError, OSError, ValueError) as e:  # av.error.InvalidDataError and friends
            raise PhysarError(f"{path}: cannot decode video ({type(e).__name__}: {e})") from None
        self.width, self.height = first.width, first.height
        rate = self._s.average_rate or self._s.guessed_rate
        self.fps = float(rate) if rate else 30.0
        self.frames_hint = int(self._s.frames or 0)
        self._first = (*_to_bgr(first, convert), first.time)
        self.last_time = None
        self._q = queue.Queue(maxsize=prefetch) if threaded else None
        self._err = None
        self._stop = threading.Event()
        self._thread = None
        if threaded:
            self._thread = threading.Thread(target=self._run, daemon=True)
            self._thread.start()

    def _next(self):
        try:
            f = next(self._it)
        except StopIteration:
            return None
        return (*_to_bgr(f, self.convert), f.time)

    def _run(self):
        try:
            while not self._stop.is_set():
                img = self._next()
                self._q.put(img)
                if img is None:
                    return
        except Exception as e:  # noqa: BLE001 - re-raised in the consumer's thread
            self._err = PhysarError(f"{self.path}: decoding failed ({type(e).__name__}: {e})")
            self._q.put(None)

    def __iter__(self):
        for bgr, _ in self.frames_with_luma():
            yield bgr

    def frames_with_luma(self):
        """(BGR uint8 (h, w, 3), luma uint8 (h, w) or None) for every frame."""
        self.last_time = self._first[2]
        yield self._first[:2]
        while True:
            img = self._q.get() if self._q is not None else self._next()
            if img is None:
                break
            self.last_time = img[2]
            yield img[:2]
        if self._err is not None:
            raise self._err
        self._c.close()

    def close(self):
        """Stop the decoding thread (it may be blocked on the full prefetch queue: drained here), then close
        the file. Closing the container under a running decoder would crash it."""
        import av

        if self._thread is not None:
            self._stop.set()
            while self._thread.is_alive():
                with contextlib.suppress(queue.Empty):
                    self._q.get(timeout=0.05)
            self._thread = None
        with contextlib.suppress(av.FFmpegError):  # best effort, like closing a file twice
            self._c.close()


class CameraSource:
    """Frames from a live camera (OpenCV VideoCapture index)."""

    def __init__(self, index: int, width: int | None = None, height: int | None = None):
        import cv2

        self._cap = cv2.VideoCapture(int(index))
        if not self._cap.isOpened():
            raise PhysarError(f"cannot open camera {index}")
        if width:
            self._cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
        if height:
            self._cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
        ok, first = self._cap.read()
        if not ok:
            raise PhysarError(f"camera {index} gives no frames")
        self._first = first
        self.height, self.width = first.shape[:2]
        self.fps = float(self._cap.get(cv2.CAP_PROP_FPS) or 30.0)
        self.frames_hint = 0

    def __iter__(self):
        yield self._first
        while True:
            ok, img = self._cap.read()
            if not ok:
                break
            yield img

    def close(self):
        self._cap.release()


__all__ = ["CameraSource", "VideoReader", "VideoWriter", "bits_per_pixel"]
