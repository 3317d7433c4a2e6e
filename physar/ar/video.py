"""Video input/output: PyAV (FFmpeg) H.264 in yuv420p (plays in browsers), live cameras via OpenCV,
background threads so that decoding and encoding overlap computing, atomic output files. Decoding goes through
:mod:`physar.media`: frames in their displayed orientation (a phone's portrait clip is portrait), each frame's
size checked, a truncated file reported."""
from __future__ import annotations

import contextlib
import queue
import threading
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from physar import media
from physar.errors import PhysarError, PhysarWarning
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
        writer = (stack.enter_context(VideoWriter(vtmp, *size, fps, name=str(video), **writer_options)) if vtmp
                  else None)
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

    yuv420p stores colour at half resolution, so H.264 needs an even width and height: frames of an odd size
    (a 641x479 camera) are padded by one column / row, replicating the last one (the video is then 642x480;
    the frames given keep their size). ``name``: the path messages name (default ``path``; e.g. the final
    path when ``path`` is a temporary).

    ``timestamps=True``: each frame is stored at the time given to :meth:`write` (s from the first frame; a
    variable-frame-rate source keeps its timing and duration), in a 1/90000 s time base; a frame without a time,
    or not later than the previous one, gets the next tick. Else frame k is at k / ``fps``.

    ``threads``: libx264 threads (0: its default, 1.5 per core). ``convert``: BGR -> yuv420p by FFmpeg's
    swscale ("ffmpeg") or by ``cv2.cvtColor(COLOR_BGR2YUV_I420)`` ("opencv": BT.601 limited range like
    swscale, within one grey level of it, about a third of its CPU time here).
    """

    def __init__(self, path, width: int, height: int, fps: float, crf: int = 20, preset: str = "veryfast",
                 threaded: bool = False, threads: int = 0, convert: str = "ffmpeg", name: str | None = None,
                 timestamps: bool = False):
        from fractions import Fraction

        import av

        if convert not in ("ffmpeg", "opencv"):
            raise PhysarError(f"colour conversion must be 'ffmpeg' or 'opencv', got {convert!r}")
        self.convert = convert
        self.path = str(path)
        self.name = str(name) if name is not None else self.path
        if not (int(width) >= 1 and int(height) >= 1):
            raise PhysarError(f"{self.name}: video frame size must be positive, got {width}x{height}")
        self._pad = (int(width) % 2, int(height) % 2)  # columns, rows replicated to an even size
        self._c = av.open(self.path, "w", format="mp4")
        rate = Fraction(fps).limit_denominator(1001)
        self._s = self._c.add_stream("libx264", rate=rate)
        self._s.width, self._s.height, self._s.pix_fmt = width + self._pad[0], height + self._pad[1], "yuv420p"
        self._s.options = {"preset": preset, "crf": str(int(crf))}
        if threads:
            self._s.codec_context.thread_count = int(threads)
        self._tb = Fraction(1, 90000) if timestamps else None
        if self._tb is not None:
            self._s.codec_context.time_base = self._tb
        self._fps, self._pts = float(fps), -1
        self.size = (width, height)
        self.frames = 0
        self._q = queue.Queue(maxsize=16) if threaded else None
        self._err = None
        self._thread = None
        if threaded:
            self._thread = threading.Thread(target=self._run, daemon=True)
            self._thread.start()

    def _encode(self, img, t=None):
        import av

        if any(self._pad):
            import cv2

            img = cv2.copyMakeBorder(img, 0, self._pad[1], 0, self._pad[0], cv2.BORDER_REPLICATE)
        if self.convert == "opencv":
            import cv2

            f = av.VideoFrame.from_ndarray(cv2.cvtColor(img, cv2.COLOR_BGR2YUV_I420), format="yuv420p")
        else:
            f = av.VideoFrame.from_ndarray(img, format="bgr24")
        if self._tb is not None:
            pts = round(float(t) * 90000) if t is not None else self._pts + round(90000 / self._fps)
            self._pts = f.pts = max(pts, self._pts + 1)
            f.time_base = self._tb
        for p in self._s.encode(f):
            self._c.mux(p)

    def _run(self):
        while True:
            item = self._q.get()
            if item is None:
                return
            img, t = item
            if self._err is None:
                try:
                    if callable(img):  # deferred frame (e.g. an overlay to draw in this thread)
                        img = self._check(img())
                    self._encode(img, t)
                except Exception as e:  # noqa: BLE001 - re-raised in the caller's thread
                    self._err = e

    def _check(self, img):
        if img.shape[:2] != (self.size[1], self.size[0]) or img.dtype != np.uint8:
            raise PhysarError(f"{self.name}: frame {self.frames} of shape {img.shape} {img.dtype} does not match the "
                              f"video's {self.size[0]}x{self.size[1]} uint8 (BGR)")
        return np.ascontiguousarray(img)

    def write(self, img, t: float | None = None) -> None:
        """Queue a frame (BGR uint8) or, on a threaded writer, a callable returning one: it is called in the
        encoder thread, so drawing can overlap the caller's next frame. ``t``: its time (s from the first
        frame), used with ``timestamps=True``."""
        if self._err is not None:
            raise self._err
        if callable(img):
            if self._q is None:
                img = img()
            else:
                self.frames += 1
                self._q.put((img, t))
                return
        img = self._check(img)
        self.frames += 1
        if self._q is not None:
            self._q.put((img, t))
        else:
            self._encode(img, t)

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


_to_bgr = media.to_bgr  # moved to physar.media (frames in their displayed orientation); kept for its users
_luma = media.luma


class VideoReader:
    """Frames (BGR uint8) of a video file in their displayed orientation (:mod:`physar.media`: a rotated phone
    clip comes out as it plays); ``threaded=True`` decodes ahead in a background thread.

    Iterating yields BGR frames; :meth:`frames_with_luma` yields (BGR, Y) pairs, Y being the decoder's own
    luma plane (h, w) (limited range, 16-235; None for non-YUV streams), so that grey-level work needs no
    colour conversion. ``width``, ``height``: the displayed size; ``rotation``: the display rotation applied
    (degrees counter-clockwise); ``grey``: the stream holds grey levels only (no colour); ``duration``: the
    header's duration (s) or None.

    ``last_time``: the presentation time (s) of the frame last yielded (None before the first, or when the
    stream has no timestamps: variable frame rate clips are timed by it); ``live`` is False and ``dropped`` 0
    (a file is read frame by frame; see :func:`physar.ar.sources.open_source` for live sources with the same
    interface).

    Raises PhysarError for a missing, empty or undecodable file (checked on open: the first frame is decoded);
    while iterating, :class:`physar.media.VideoChanged` at a frame whose size differs from the first's (the
    frames before it were yielded), PhysarError naming the frame when decoding fails; a file that ends
    clearly before its header's duration gives a PhysarWarning (truncated?).
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
            dec = self._c.decode(self._s)
            first = next(dec)
        except PhysarError:
            raise
        except StopIteration:
            raise PhysarError(f"{path}: the video has no decodable frame") from None
        except (av.FFmpegError, OSError, ValueError) as e:  # av.error.InvalidDataError and friends
            raise PhysarError(f"{path}: cannot decode video ({type(e).__name__}: {e})") from None
        self._frames = media.Checked(dec, self.path, first=first)
        self._it = iter(self._frames)
        next(self._it)  # the first frame: sets the size the others are checked against
        self.width, self.height = self._frames.size
        self.rotation = self._frames.rotation
        self.grey = first.format.name.startswith("gray")
        rate = self._s.average_rate or self._s.guessed_rate
        self.fps = float(rate) if rate else 30.0
        self.frames_hint = int(self._s.frames or 0)
        self.duration = media.duration_of(self._c, self._s)
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
        except PhysarError as e:  # a size change, a frame that does not decode: named already
            self._err = e
            self._q.put(None)
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
        short = media.shortfall(self._frames, self.duration, self.fps)
        if short:
            warnings.warn(short, PhysarWarning, stacklevel=2)

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
