"""The one output module: every file a command writes goes through here.

* :func:`check_destination` checks a destination before any work is done (one ConfigError line naming the
  path: a folder, an unknown suffix, an unwritable or missing-and-uncreatable parent, the same file as an
  input).
* :func:`atomic_path` writes through a temporary next to the target, renamed on success and removed on an
  error or an interrupt, created with the permissions the umask gives (not mkstemp's 0600).
* :class:`SignalGuard` (``with signal_guard() as g``) turns the first SIGINT/SIGTERM into a flag
  (``g.stopped``) that a frame loop polls, so that it can finish the current frame, close its writers and
  rename its outputs; a second signal raises KeyboardInterrupt (abort: the temporaries are removed).
  :func:`stop_requested` lets blocking readers (live sources) see the flag.
* :func:`check_folder` / :func:`atomic_folder` do the same for a command that writes a folder: a folder
  holding files the command did not write is refused (never deleted), a previous output of the same command is
  replaced only once the new one is complete.
* :func:`write_text`, :func:`write_bytes`, :func:`write_json`, :func:`write_npz`, :func:`save_figure`: whole
  files through :func:`atomic_path`; ``atomic_path(path, companions=True)`` for formats that write companion
  files next to the named one (XDMF's ``.h5``).
* :func:`sigterm_as_interrupt` makes SIGTERM unwind like Ctrl-C (the temporaries are removed on the way out);
  :func:`check_memory` refuses a job whose estimated memory exceeds what the machine has available.
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import tempfile
import threading
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import numpy as np

from physar.errors import ConfigError


def _cannot_write(folder: Path) -> str | None:
    """Why a file cannot be created in the existing ``folder`` (None if it can): ``os.access``, a read-only
    mount, then a real probe (a temporary file created and removed at once, the folder's times put back),
    since root passes ``os.access`` on folders it still cannot write (a read-only mount, /proc, /sys)."""
    if not os.access(folder, os.W_OK | os.X_OK):
        return "is not writable"
    with contextlib.suppress(OSError, AttributeError):
        if os.statvfs(folder).f_flag & os.ST_RDONLY:
            return "is not writable (read-only file system)"
    st = os.stat(folder)
    try:
        fd, probe = tempfile.mkstemp(prefix=".physar-probe.", dir=folder)
    except OSError as exc:
        return f"is not writable ({exc.strerror or exc})"
    os.close(fd)
    with contextlib.suppress(OSError):
        os.remove(probe)
        os.utime(folder, ns=(st.st_atime_ns, st.st_mtime_ns))
    return None


def check_destination(path, *, inputs: Iterable = (), suffixes: Iterable[str] | None = None,
                      kind: str = "file", replaces=None) -> Path:
    """Check that ``path`` can be written as a ``kind`` (e.g. "video", "CSV"); returns it as a Path.

    Raises ConfigError (one line naming ``path``) when: it is empty or an existing folder; ``suffixes`` is
    given and its suffix (case-insensitive) is not one of them; its nearest existing ancestor folder is not a
    writable folder (so the parent can neither be used nor created; probed, see :func:`_cannot_write`); it is
    the same file as one of ``inputs``
    (None entries ignored); ``replaces`` is given (a function of the existing file's path: whether it is an
    earlier output of this kind) and the existing file is not one (a user's file at that path is never
    replaced by another kind of output). Nothing is created.
    """
    if path is None or str(path) == "":
        raise ConfigError(f"{kind} destination path is empty")
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{path}: {kind} destination is an existing folder")
    if suffixes is not None:
        allowed = [s.lower() for s in suffixes]
        if p.suffix.lower() not in allowed:
            raise ConfigError(f"{path}: unknown {kind} suffix {p.suffix or '(none)'!r}; use one of "
                              f"{', '.join(allowed)}")
    parent = p.absolute().parent
    anc = parent
    while not anc.exists():
        anc = anc.parent
    if not anc.is_dir():
        raise ConfigError(f"{path}: cannot create the {kind}'s folder {parent} ({anc} is a file)")
    why = _cannot_write(anc)
    if why:
        where = "folder" if anc == parent else "folder's parent"
        raise ConfigError(f"{path}: the {kind}'s {where} {anc} {why}")
    for inp in inputs:
        if inp is None or str(inp) == "":
            continue
        q = Path(inp)
        same = (os.path.samefile(p, q) if p.exists() and q.exists()
                else p.absolute().resolve() == q.absolute().resolve())
        if same:
            raise ConfigError(f"{path}: {kind} destination is the same file as the input {inp}")
    if replaces is not None and p.is_file() and not replaces(p):
        raise ConfigError(f"{path}: exists and does not look like an earlier {kind} of this command (physar "
                          "replaces only its own outputs): give a new path, or move that file away first")
    return p


def png_by_physar(path: Path) -> bool:
    """A ``replaces`` test for :func:`check_destination`: whether a PNG was written by :func:`save_figure` (its
    ``Software`` text chunk reads ``physar``)."""
    try:
        from PIL import Image

        with Image.open(path) as im:
            return str(im.info.get("Software", "")).startswith("physar")
    except (OSError, ValueError, SyntaxError):  # not an image PIL reads (UnidentifiedImageError is an OSError)
        return False


def csv_header_starts(*columns: str):
    """A ``replaces`` test for :func:`check_destination`: whether a file's first line starts with these CSV
    columns (an earlier output of a writer with that header)."""
    want = ",".join(columns)

    def test(path: Path) -> bool:
        try:
            if path.stat().st_size == 0:  # an empty file (touch, mktemp): nothing to lose
                return True
            with open(path, encoding="utf-8", errors="replace") as f:
                return f.readline(4096).startswith(want)
        except OSError:
            return False

    return test


@contextlib.contextmanager
def native_stderr_without(*drop: str) -> Iterator[None]:
    """Inside the block, what native code writes to file descriptor 2 is held back and, at the end, written to
    stderr without the lines containing any of ``drop`` (e.g. Warp's "Could not find or load the NVIDIA CUDA
    driver" on every CPU-only run, printed by its C library whatever ``wp.config.quiet`` says). Other lines pass."""
    import sys
    import tempfile

    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no descriptor 2 (or sys.stderr None): nothing to filter
        yield
        return
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            held.seek(0)
            text = held.read().decode("utf-8", errors="replace")
            keep = "".join(ln for ln in text.splitlines(keepends=True) if not any(d in ln for d in drop))
            if keep and sys.stderr is not None:
                sys.stderr.write(keep)
                sys.stderr.flush()


def _umask() -> int:
    """The process umask (read from /proc on Linux, else by setting and restoring it)."""
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    old = os.umask(0o022)
    os.umask(old)
    return old


@contextlib.contextmanager
def atomic_path(path, *, companions: bool = False) -> Iterator[Path]:
    """Yield a hidden temporary path next to ``path`` (its parent folders created); on success it is renamed
    to ``path`` with the permissions a plain ``open`` would give (0666 minus the umask), on any exception
    (KeyboardInterrupt and SystemExit included) it is removed and the exception re-raised.

    ``companions=True`` is for writers that create sibling files named after the file (XDMF + ``.h5``): the
    yielded path is ``path.name`` inside a hidden temporary folder beside ``path``; on success every file
    the writer left there is moved beside ``path`` (the companions first, the named file last), and the
    folder is removed in every case.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if companions:
        tmpdir = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
        try:
            yield tmpdir / path.name
            _interrupted_before_commit()
            files = sorted(tmpdir.iterdir(), key=lambda f: f.name == path.name)
            for f in files:
                os.chmod(f, 0o666 & ~_umask())
                _replace(f, path.parent / f.name)
        finally:
            shutil.rmtree(tmpdir, ignore_errors=True)
        return
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_umask())
    try:
        yield Path(tmp)
        _interrupted_before_commit()
        _replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def _replace(src, dst) -> None:
    """``os.replace`` whose failure (a read-only or immutable file in the way, another user's file in a sticky
    folder) is one ConfigError line naming the destination."""
    try:
        os.replace(src, dst)
    except OSError as e:
        raise ConfigError(f"{dst}: cannot be replaced ({e.strerror or e}): the file in its place is protected "
                          "(read-only, immutable or another user's); write elsewhere or remove it first") from None


def atomic_write_text(path, text: str) -> None:
    """Write ``text`` to ``path`` through :func:`atomic_path`."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


write_text = atomic_write_text


def write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` through :func:`atomic_path`; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def jsonable(obj):
    """``obj`` with numpy arrays and scalars (and Paths) turned into plain lists, numbers and strings."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json(path, obj, *, indent: int | None = 1) -> Path:
    """Write ``obj`` (numpy values allowed, see :func:`jsonable`) as JSON through :func:`atomic_path`."""
    return write_bytes(path, (json.dumps(jsonable(obj), indent=indent) + "\n").encode())


def write_npz(path, **arrays) -> Path:
    """``np.savez`` of ``arrays`` to ``path`` through :func:`atomic_path` (the name keeps its suffix)."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    return Path(path)


def save_figure(fig, path, dpi: int = 110, **kwargs) -> Path:
    """``fig.savefig`` to ``path`` through :func:`atomic_path` (format from the suffix); closes ``fig``."""
    import matplotlib.pyplot as plt

    path = Path(path)
    fmt = path.suffix.lstrip(".").lower() or "png"
    if fmt == "png":  # marked as physar's: a later run may replace it (png_by_physar), never a user's picture
        kwargs = {**kwargs, "metadata": {**kwargs.get("metadata", {}), "Software": "physar"}}
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, format=fmt, **kwargs)
    finally:
        plt.close(fig)
    return path


def _entries(folder: Path) -> list[str]:
    return sorted(e.name for e in folder.iterdir()) if folder.is_dir() else []


def check_folder(path, *, own: Callable[[str], bool] | None = None, inputs: Iterable = (),
                 kind: str = "output folder") -> Path:
    """Check that ``path`` can be written as a folder of outputs (``kind``); returns it as a Path.

    Raises ConfigError (one line naming ``path``) when: it is empty or an existing file; its nearest existing
    ancestor is not a writable folder; it is one of ``inputs``; ``own`` is given (a predicate on entry names:
    the files and folders the command writes) and the folder exists holding an entry it does not accept, so
    that a command never mixes its outputs with, or deletes, files it did not write. Nothing is created.
    """
    if path is None or str(path) == "":
        raise ConfigError(f"{kind} path is empty")
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise ConfigError(f"{path}: {kind} is an existing file; give a folder")
    anc = p.absolute()
    while not anc.exists():
        anc = anc.parent
    if not anc.is_dir():
        raise ConfigError(f"{path}: cannot create the {kind} ({anc} is a file)")
    why = _cannot_write(anc)
    if why:
        raise ConfigError(f"{path}: {'the ' + kind if anc == p.absolute() else 'its parent ' + str(anc)} {why}")
    for inp in inputs:
        if inp is not None and str(inp) != "" and Path(inp).absolute().resolve() == p.absolute().resolve():
            raise ConfigError(f"{path}: {kind} is the same as the input {inp}")
    if own is not None:
        foreign = [e for e in _entries(p) if not own(e)]
        if foreign:
            more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
            raise ConfigError(f"{path}: {kind} holds files this command did not write ({foreign[0]}{more}); "
                              "choose a new or empty folder")
    return p


def own_names(*patterns: str) -> Callable[[str], bool]:
    """A predicate for :func:`check_folder`: the name matches one of the regular ``patterns`` in full."""
    rx = re.compile("|".join(f"(?:{p})" for p in patterns))
    return lambda name: rx.fullmatch(name) is not None


@contextlib.contextmanager
def atomic_folder(path, *, own: Callable[[str], bool] | None = None) -> Iterator[Path]:
    """Yield a new hidden temporary folder beside ``path`` to fill; on success it takes the place of ``path``.

    An existing ``path`` (a previous output: every entry accepted by ``own``, checked again just before it
    is replaced, else ConfigError) is removed only once the new folder is in place. On any exception,
    interrupts included, the temporary folder is removed and ``path`` is left as it was.
    """
    path = Path(path)
    if path.name in ("", ".", "..") or Path.cwd().resolve().is_relative_to(path.resolve()):
        raise ConfigError(f"{path}: give a folder of its own for the output (it is replaced whole), not the "
                          "current folder or one above it")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    os.chmod(tmp, 0o777 & ~_umask())
    try:
        yield tmp
        _interrupted_before_commit()
        if path.exists():
            check_folder(path, own=own)
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old.", dir=path.parent))
            os.replace(path, old)  # onto an empty folder: allowed by rename(2)
            try:
                os.replace(tmp, path)
            except BaseException:
                os.replace(old, path)
                raise
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _size(n: float) -> str:
    """Bytes in MiB, GiB or TiB (three significant digits)."""
    for unit, scale in (("TiB", 2**40), ("GiB", 2**30)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n / 2**20:.3g} MiB"


def available_memory() -> int:
    """Bytes of memory the machine can give a new allocation (Linux MemAvailable; else physical memory)."""
    with contextlib.suppress(OSError, ValueError, IndexError):
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        return 2**63


def check_memory(nbytes: float, what: str) -> None:
    """Raise ConfigError when ``nbytes`` (an estimate of the memory ``what`` needs) exceeds the memory
    available now (:func:`available_memory`): one line with both figures, before anything is allocated."""
    avail = available_memory()
    if not nbytes <= avail:
        raise ConfigError(f"{what} needs about {_size(nbytes)} of memory, more than the {_size(avail)} "
                          "available")


_ACTIVE: list[SignalGuard] = []


def stop_requested() -> bool:
    """True when an active :class:`SignalGuard` has caught a signal (polled by blocking readers)."""
    return any(g.signum is not None for g in _ACTIVE)


class SignalGuard:
    """Context manager turning SIGINT/SIGTERM into a clean stop.

    Inside the block the first signal only records itself (``signum``, ``stopped``, ``name``); the caller
    polls ``stopped`` between units of work. A second signal raises KeyboardInterrupt in the main thread
    (an abort). Handlers are installed only from the main thread (elsewhere the guard is inert) and not for a
    signal the process ignores (SIG_IGN, e.g. SIGINT of a background job); the previous handlers are
    restored on exit.
    """

    def __init__(self, signals=(signal.SIGINT, signal.SIGTERM)):
        self.signals = tuple(signals)
        self.signum: int | None = None
        self._prev: dict = {}

    @property
    def stopped(self) -> bool:
        return self.signum is not None

    @property
    def name(self) -> str | None:
        return signal.Signals(self.signum).name if self.signum is not None else None

    def _handle(self, signum, frame):
        if self.signum is not None:
            raise KeyboardInterrupt(f"second {signal.Signals(signum).name}")
        self.signum = signum

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for s in self.signals:
                prev = signal.getsignal(s)
                if prev is signal.SIG_IGN:
                    continue
                self._prev[s] = prev
                signal.signal(s, self._handle)
        _ACTIVE.append(self)
        return self

    def __exit__(self, *exc):
        _ACTIVE.remove(self)
        for s, prev in self._prev.items():
            signal.signal(s, prev if prev is not None else signal.SIG_DFL)
        self._prev.clear()
        return False


def signal_guard(signals=(signal.SIGINT, signal.SIGTERM)) -> SignalGuard:
    """A :class:`SignalGuard` for ``signals`` (use as ``with signal_guard() as guard:``)."""
    return SignalGuard(signals)


_INTERRUPTS: list[str] = []  # signals raised as KeyboardInterrupt under sigterm_as_interrupt, not yet acted on


def _raise_interrupt(signum, frame):
    name = signal.Signals(signum).name
    _INTERRUPTS.append(name)
    raise KeyboardInterrupt(name)


def _interrupted_before_commit() -> None:
    """Raise KeyboardInterrupt when a signal of :func:`sigterm_as_interrupt` was raised but did not stop the
    work: Python drops an exception raised inside a ``__del__`` (e.g. a Warp array's, freed by the collector)
    with "Exception ignored in", so the command ran on. Called before an output takes its place, so that an
    interrupted command still writes nothing (seen: SIGTERM during ``recon synth`` left a complete DATA_DIR,
    exit 0)."""
    if _INTERRUPTS:
        name = _INTERRUPTS[-1]
        _INTERRUPTS.clear()
        raise KeyboardInterrupt(name)


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Inside the block SIGTERM raises KeyboardInterrupt (as Ctrl-C does), so that ``finally`` blocks, and
    with them :func:`atomic_path`'s cleanup, run instead of the process dying with its temporaries on disk.
    Ctrl-C (SIGINT with Python's default handler) goes through the same handler, which also remembers the
    signal for ``_interrupted_before_commit``. Only from the main thread and only where SIGTERM has its
    default action; restored on exit."""
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        yield
        return
    sigint = signal.getsignal(signal.SIGINT) is signal.default_int_handler
    signal.signal(signal.SIGTERM, _raise_interrupt)
    if sigint:
        signal.signal(signal.SIGINT, _raise_interrupt)
    _INTERRUPTS.clear()
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        if sigint:
            signal.signal(signal.SIGINT, signal.default_int_handler)
        _INTERRUPTS.clear()
