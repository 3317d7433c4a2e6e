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
"""
from __future__ import annotations

import contextlib
import os
import signal
import tempfile
import threading
from collections.abc import Iterable
from pathlib import Path

from physar.errors import ConfigError


def check_destination(path, *, inputs: Iterable = (), suffixes: Iterable[str] | None = None,
                      kind: str = "file") -> Path:
    """Check that ``path`` can be written as a ``kind`` (e.g. "video", "CSV"); returns it as a Path.

    Raises ConfigError (one line naming ``path``) when: it is empty or an existing folder; ``suffixes`` is
    given and its suffix (case-insensitive) is not one of them; its nearest existing ancestor folder is not a
    writable folder (so the parent can neither be used nor created); it is the same file as one of ``inputs``
    (None entries ignored). Nothing is created.
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
    if not os.access(anc, os.W_OK | os.X_OK):
        where = "folder" if anc == parent else "folder's parent"
        raise ConfigError(f"{path}: the {kind}'s {where} {anc} is not writable")
    for inp in inputs:
        if inp is None or str(inp) == "":
            continue
        q = Path(inp)
        same = (os.path.samefile(p, q) if p.exists() and q.exists()
                else p.absolute().resolve() == q.absolute().resolve())
        if same:
            raise ConfigError(f"{path}: {kind} destination is the same file as the input {inp}")
    return p


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
def atomic_path(path):
    """Yield a hidden temporary path next to ``path`` (its parent folders created); on success it is renamed
    to ``path`` with the permissions a plain ``open`` would give (0666 minus the umask), on any exception
    (KeyboardInterrupt and SystemExit included) it is removed and the exception re-raised."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_umask())
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def atomic_write_text(path, text: str) -> None:
    """Write ``text`` to ``path`` through :func:`atomic_path`."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


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
