"""Shared CLI plumbing: user errors become one line on stderr and exit code 2; JSON goes to stdout."""

from __future__ import annotations

import contextlib
import functools
import json
import os
import sys
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import typer

from physar.errors import ConfigError, PhysarError, PhysarWarning


def _to_jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return _to_jsonable(obj.item())
    if isinstance(obj, float) and not np.isfinite(obj):
        return None            # strict JSON has no NaN / Infinity: null
    return obj


def print_json(obj: Any) -> None:
    """Print `obj` (numpy arrays allowed) as strict JSON on stdout (NaN and infinities as null)."""
    sys.stdout.write(json.dumps(_to_jsonable(obj), indent=None) + "\n")
    sys.stdout.flush()


def _open_bars() -> list:
    """The tqdm progress bars still open (drawn on stderr without a newline), none if tqdm is not loaded."""
    tq = sys.modules.get("tqdm")
    return [b for b in list(getattr(getattr(tq, "tqdm", None), "_instances", ())) if not b.disable]


def log(msg: str) -> None:
    """Human-readable progress/info to stderr (stdout stays clean for --json), on a line of its own: an open
    progress bar is cleared, the line printed and the bar drawn again below it (tqdm.write)."""
    if _open_bars():
        sys.modules["tqdm"].tqdm.write(msg, file=sys.stderr)
    else:
        typer.echo(msg, err=True)


def _show_warning(message, category, filename, lineno, file=None, line=None, _default=warnings.showwarning):
    if issubclass(category, PhysarWarning):
        log(f"warning: {message}")
    else:
        _default(message, category, filename, lineno, file, line)


def _close_bars() -> None:
    """Close the open progress bars, so that an error line starts a line of its own (a bar left open had the
    error printed after its last frame count, on the same line)."""
    for b in _open_bars():
        with contextlib.suppress(Exception):  # a bar whose stream is already gone
            b.close()


def user_errors(fn: Callable) -> Callable:
    """Decorator: a PhysarError (bad input) prints `error: <message>` to stderr and exits with code 2; a
    PhysarWarning (a result to doubt, e.g. a poor calibration) prints one `warning: <message>` line; an
    interrupt (Ctrl-C, SIGTERM) that the command does not handle itself prints one `interrupted` line, exit 130."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with warnings.catch_warnings():
            warnings.simplefilter("always", PhysarWarning)
            warnings.showwarning = _show_warning
            try:
                return fn(*args, **kwargs)
            except PhysarError as exc:
                _close_bars()
                typer.echo(f"error: {exc}", err=True)
                raise typer.Exit(code=2) from None
            except KeyboardInterrupt as exc:  # a command without its own stop: say so (typer would exit silently)
                _close_bars()
                how = str(exc).removeprefix("second ") or "SIGINT"
                typer.echo(f"interrupted ({how}): outputs not yet complete were not written (every output is "
                           "written whole or not at all)", err=True)
                raise typer.Exit(code=130) from None

    return wrapper


# ------------------------------------------------------------------------------------------------ inputs
#: a TOML input larger than this is refused before it is read (a video or a mesh given by mistake)
MAX_TOML_BYTES = 64 * 2**20


def check_input(path, what: str, *, folder: bool = False) -> Path:
    """One ConfigError line when an input is missing, a folder where a file is expected, or a file where a
    folder is expected (``folder=True``); returns it as a Path."""
    if path is None or str(path) == "":
        raise ConfigError(f"{what}: the path is empty")
    p = Path(path)
    if not p.exists():
        raise ConfigError(f"{path}: {what} not found")
    if folder and not p.is_dir():
        raise ConfigError(f"{path}: {what} must be a folder, and this is a file")
    if not folder and p.is_dir():
        raise ConfigError(f"{path}: {what} is a folder; give the file")
    return p


def check_toml(path, what: str = "TOML file") -> Path | None:
    """Refuse, in one ConfigError line naming the file, a TOML input that is a folder, unreadable, not UTF-8
    text (a binary file) or larger than :data:`MAX_TOML_BYTES`, before a TOML reader meets it (it would raise
    IsADirectoryError / UnicodeDecodeError). A missing file is left to the reader's own message; None passes."""
    if path is None:
        return None
    p = Path(path)
    if not p.exists():
        return p
    if p.is_dir():
        raise ConfigError(f"{path}: {what} is a folder; give the TOML file")
    try:
        size = p.stat().st_size
        if size > MAX_TOML_BYTES:
            raise ConfigError(f"{path}: {size / 2**20:.0f} MiB is far too large for a {what} (TOML); is it the "
                              "right file?")
        p.read_bytes().decode("utf-8")
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: not a {what}: byte {e.object[e.start]:#04x} at offset {e.start} is not UTF-8 "
                          "text (a binary file?)") from None
    except OSError as e:
        raise ConfigError(f"{path}: cannot read the {what} ({e.strerror})") from None
    return p


# ------------------------------------------------------------------------------------------------ outputs
def output_path(out: Path | None, positional: Path | None, usage: str) -> Path:
    """The output of a command that used to take it as a positional argument: ``--out`` (``out``) or the
    deprecated positional, not both (unless equal); one ConfigError line when neither is given. ``usage``
    names the command and its arguments for the message (e.g. "physar noise IN --out OUT")."""
    if out is not None and positional is not None and Path(out) != Path(positional):
        raise ConfigError(f"two outputs given, {positional} (positional, deprecated) and --out {out}; give "
                          f"--out only: {usage}")
    p = out if out is not None else positional
    if p is None:
        raise ConfigError(f"missing the output: {usage}")
    return Path(p)


def warn_positional(positional: Path | None, out: Path | None, command: str) -> None:
    """One ``warning:`` line when the output came as the deprecated positional argument (after success)."""
    if positional is not None and out is None:
        typer.echo(f"warning: the positional output of `physar {command}` is deprecated; write --out "
                   f"{positional}", err=True)


def whole_folder(out, example: str = "a new folder") -> Path:
    """The normalised absolute path of an output folder that is written whole (``physar.output.atomic_folder``:
    a complete new folder takes its place). ``.`` or ``..`` (the current folder or one above it) is refused in
    one ConfigError line before any work: replacing it would leave the shell in a deleted folder (and
    ``atomic_folder`` cannot name a temporary after ``.``)."""
    p = Path(os.path.abspath(out))
    cwd = Path(os.path.abspath(os.getcwd()))
    if p == cwd or p in cwd.parents:
        where = "the current folder" if p == cwd else "a folder above the current one"
        raise ConfigError(f"{out}: --out is {where}; it is replaced as a whole when the output is complete, so "
                          f"give {example}")
    return p


@contextlib.contextmanager
def created_parents(path, what: str = "output folder") -> Iterator[None]:
    """Create the missing parent folders of ``path`` (one ConfigError line when that fails); if the block
    raises, remove the folders created here that are still empty (never one that existed before)."""
    parent = Path(path).absolute().parent
    made = []
    anc = parent
    while not anc.exists():
        made.append(anc)
        anc = anc.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ConfigError(f"{path}: cannot create the {what} ({e.strerror})") from None
    try:
        yield
    except BaseException:
        for d in made:  # deepest first
            with contextlib.suppress(OSError):
                os.rmdir(d)
        raise
