"""What the AR pipeline does around its per-frame step: :func:`run_video` (open the source, check its size,
write the augmented video and the per-frame CSV progressively and atomically, stop cleanly on SIGINT/SIGTERM,
time the frames), and :func:`pipeline_stats` (the entries of its summary that a demo's report.json carries)."""
from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

import cv2
import numpy as np

from physar.errors import ConfigError, PhysarError


def _saving(job: Callable[[], np.ndarray], path) -> Callable[[], np.ndarray]:
    """The deferred frame ``job`` that also saves the image it returns as the PNG ``path``."""
    def run():
        img = job()
        cv2.imwrite(str(path), img)
        return img
    return run


def run_video(process: Callable, camera, source, out_video=None, out_csv=None, fps: float | None = None,
              crf: int = 20, csv_header: Sequence[str] = (), csv_row: Callable | None = None,
              progress: Callable[[int, int], None] | None = None, snapshots: dict | None = None,
              max_frames: int | None = None, stage_names: Sequence[str] | None = None, *,
              preset: str = "veryfast", encoder_threads: int = 0, convert: str = "ffmpeg",
              frames: Callable[[object], Iterable] | None = None, time_io: bool = False,
              cpu: bool = False, keep_results: bool = True, stats_sample: int = 4096,
              handle_signals: bool = True) -> dict:
    """Run ``process`` on every frame of ``source`` (a video path, camera index or stream URL opened with
    :func:`physar.ar.sources.open_source` and closed at the end, or a VideoReader / LiveSource / CameraSource /
    iterable of BGR frames) whose size must be ``camera``'s.

    ``process(k, item, draw) -> (image, result)``: ``item`` is the k-th frame (or what ``frames(reader)``
    yields), ``draw`` whether the image is used (a video is written, or frame k is in ``snapshots``: {frame
    index: PNG path}). ``image`` may be a callable returning it, called in the encoder thread. ``result``
    has ``status``, ``latency_ms`` and ``stages_ms`` (a dict of stage name -> ms).

    Outputs, both optional, are written progressively to hidden temporaries next to them (CSV rows line
    buffered, video frames encoded as they come) and renamed when the loop ends; an exception removes them
    (no partial output). A live stream that closes ends the loop normally. With ``handle_signals`` (main
    thread only) the first SIGINT/SIGTERM stops the loop after the current frame: the encoder is flushed,
    the MP4 closed (playable), the CSV holds one row per processed frame and both are renamed; the summary
    then has ``interrupted``: True and ``signal`` (its name). A second signal aborts (KeyboardInterrupt, no
    outputs); a signal before the first frame raises KeyboardInterrupt with nothing written. Outputs:
    ``out_video`` (H.264 at ``fps``, default the source's; a file's frames are stored at their own timestamps,
    so a variable-frame-rate clip keeps its timing and duration; libx264 ``crf``/``preset``/``encoder_threads``,
    ``convert`` as in :class:`physar.ar.video.VideoWriter`, also used to open a path source) and ``out_csv``
    (columns frame, time_s, status, then ``csv_header``; a row per frame: k, t_k, status, then
    ``csv_row(result)``; t_k is the frame's timestamp (``source.last_time``: the presentation time of a file,
    so that a variable-frame-rate clip is timed right; the capture time of a live source) relative to the
    first frame's, or k / fps for a source without timestamps). A source that fails mid-way (a frame of
    another size: :class:`physar.media.VideoChanged`, a frame that does not decode) stops the loop like a
    signal: the outputs of the frames before it are kept, then its PhysarError is raised, with what was kept.
    ``time_io``: record in each result's stages_ms the wait for the frame ("decode")
    and for the writer ("encode"). Stops after ``max_frames`` frames; ``progress(done, total hint)``.

    Returns frames, wall_s, fps, latency_ms_median, latency_ms_p95, stages_ms_median (over ``stage_names``,
    default every stage met, sorted; a stage missing in a frame counts 0), process_cpu_ms_per_frame (with
    ``cpu``: CPU time of all threads per frame), dropped (a live source's dropped frames, when it counts
    them) and results (the ``result`` of every frame). With ``keep_results=False`` (live sources: memory
    bounded) there is no results entry and the latency and stage statistics are over a uniform random
    sample (reservoir, seed 0) of at most ``stats_sample`` frames, all of them when there are fewer.
    """
    from physar.ar.sources import open_source
    from physar.output import signal_guard
    from physar.rom._threads import single_blas_thread

    opened = isinstance(source, (str, Path, int)) and not isinstance(source, bool)
    reader = open_source(source, convert=convert, width=camera.width, height=camera.height) if opened else source
    try:
        # one BLAS thread: a frame's products are small, and idle OpenBLAS workers spin on the cores the decoder
        # and the encoder need (measured on the bracket at 17 Mbit/s: 29 -> 18 ms of CPU per frame, 68 -> 97 fps)
        with single_blas_thread():
            return _loop(process, camera, reader, source, out_video, out_csv, fps, crf, csv_header, csv_row,
                         progress, snapshots, max_frames, stage_names, preset, encoder_threads, convert, frames,
                         time_io, cpu, keep_results, stats_sample,
                         signal_guard() if handle_signals else contextlib.nullcontext())
    finally:
        if opened and hasattr(reader, "close"):
            reader.close()


class _Sample:
    """The results of every frame (``keep``) or a uniform reservoir sample of at most ``size`` of them."""

    def __init__(self, keep: bool, size: int):
        if not keep and size < 1:
            raise ConfigError(f"stats_sample must be >= 1, got {size}")
        self.keep, self.size, self.n, self.items = keep, size, 0, []
        self._rng = np.random.default_rng(0)

    def add(self, r) -> None:
        self.n += 1
        if self.keep or len(self.items) < self.size:
            self.items.append(r)
        else:  # Algorithm R: frame n replaces a random entry with probability size / n
            j = int(self._rng.integers(0, self.n))
            if j < self.size:
                self.items[j] = r


def _loop(process, camera, reader, source, out_video, out_csv, fps, crf, csv_header, csv_row, progress, snapshots,
          max_frames, stage_names, preset, encoder_threads, convert, frames, time_io, cpu, keep_results,
          stats_sample, guard_cm) -> dict:
    from physar.ar.video import clip_outputs

    w, h = getattr(reader, "width", None), getattr(reader, "height", None)
    name = getattr(reader, "path", None) or getattr(reader, "name", None) or source
    if (w, h) != (None, None) and (w, h) != camera.size:
        turned = f" as displayed (stored turned {reader.rotation} deg)" if getattr(reader, "rotation", 0) else ""
        hint = camera.size_hint(w, h) if hasattr(camera, "size_hint") else ""
        raise ConfigError(f"{name}: video is {w}x{h}{turned} but the camera is for {camera.width}x{camera.height}"
                          + hint)
    live = bool(getattr(reader, "live", False))
    fps = fps or getattr(reader, "fps", 30.0)
    total = getattr(reader, "frames_hint", 0)
    sample = _Sample(keep_results, stats_sample)
    counts: dict[str, int] = {}
    t_first = None
    failed: list[PhysarError] = []
    with guard_cm as guard, clip_outputs(out_video, out_csv, camera.size, fps, ["frame", "time_s", "status", *csv_header], crf=crf,
                      preset=preset, threaded=True, threads=encoder_threads, convert=convert,
                      timestamps=not live and hasattr(reader, "last_time")) as (writer, rows):
        t_start, cpu_start = time.perf_counter(), time.process_time()
        t_prev = t_start
        for k, item in enumerate(_until_failure(frames(reader) if frames else reader, failed)):
            if max_frames is not None and k >= max_frames:
                break
            if guard is not None and guard.stopped:  # the signal came while waiting for this frame
                break
            snap = snapshots.get(k) if snapshots else None
            t_in = time.perf_counter()
            img, r = process(k, item, writer is not None or snap is not None)
            if time_io:
                r.stages_ms["decode"] = (t_in - t_prev) * 1e3  # waiting for the decoder
            t_out = time.perf_counter()
            if callable(img) and writer is None:
                img = img()
            if snap is not None:
                if callable(img):
                    img = _saving(img, snap)
                else:
                    cv2.imwrite(str(snap), img)
            t_src = getattr(reader, "last_time", None)
            if t_src is not None and t_first is None:
                t_first = t_src
            t_k = t_src - t_first if t_src is not None else k / fps
            if writer is not None:
                writer.write(img, t_k)
            t_prev = time.perf_counter()
            if time_io:
                r.stages_ms["encode"] = (t_prev - t_out) * 1e3  # waiting for the encoder queue
            sample.add(r)
            status = getattr(r, "status", None)
            if status is not None:
                counts[status] = counts.get(status, 0) + 1
            if rows:
                rows.writerow([k, f"{t_k:.4f}", r.status, *(csv_row(r) if csv_row else ())])
            if progress:
                progress(k + 1, total)
            if guard is not None and guard.stopped:
                break
        interrupted = guard is not None and guard.stopped
        if failed and not sample.n:
            raise failed[0]
        if not sample.n:
            if interrupted:
                raise KeyboardInterrupt(f"{guard.name} before the first frame of {source}; nothing written")
            raise PhysarError(f"{getattr(source, 'path', getattr(source, 'name', source))}: no frames")
        if writer is not None:
            writer.close()
        wall, cpu_s = time.perf_counter() - t_start, time.process_time() - cpu_start
    if failed:
        kept = [str(p) for p in (out_video, out_csv) if p]
        raise type(failed[0])(f"{failed[0]}; stopped after {sample.n} frames"
                              + (f" (kept for them: {', '.join(kept)})" if kept else ""))
    results, n = sample.items, sample.n
    lat = np.array([r.latency_ms for r in results])
    names = stage_names if stage_names is not None else sorted({s for r in results for s in r.stages_ms})
    summary = {"frames": n, "wall_s": wall, "fps": n / wall,
               "latency_ms_median": float(np.median(lat)), "latency_ms_p95": float(np.percentile(lat, 95)),
               "stages_ms_median": {s: float(np.median([r.stages_ms.get(s, 0.0) for r in results])) for s in names}}
    if cpu:
        summary["process_cpu_ms_per_frame"] = cpu_s / n * 1e3
    if hasattr(reader, "dropped") and live:
        summary["dropped"] = int(reader.dropped)
    if counts:
        summary["status_counts"] = counts
    if interrupted:
        summary["interrupted"] = True
        summary["signal"] = guard.name
    if keep_results:
        summary["results"] = results
    else:
        summary["stats_sample"] = len(results)
    return summary


def _until_failure(items: Iterable, failed: list) -> Iterator:
    """``items`` until the iteration raises a PhysarError (a source failing mid-way), which is appended to
    ``failed`` instead of propagating, so that the loop can close its outputs on what was done."""
    it = iter(items)
    while True:
        try:
            item = next(it)
        except StopIteration:
            return
        except PhysarError as e:
            failed.append(e)
            return
        yield item


def pipeline_stats(summary: dict) -> dict:
    """The entries of a pipeline summary that a demo's report.json carries: frames, fps, latency_ms_median,
    latency_ms_p95, stages_ms_median, and at_bound when the summary has it (a project pipeline's: the
    parameters whose estimate was at a bound of the model's range, :meth:`physar.ar.project_pipeline.
    ProjectPipeline.run`)."""
    keys = ("frames", "fps", "latency_ms_median", "latency_ms_p95", "stages_ms_median")
    return {k: summary[k] for k in keys} | ({"at_bound": summary["at_bound"]} if "at_bound" in summary else {})


__all__ = ["run_video"]
