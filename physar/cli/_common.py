"""Shared CLI plumbing: user errors become one line on stderr and exit code 2; JSON goes to stdout."""

from __future__ import annotations

import functools
import json
import sys
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import typer

from physar.errors import PhysarError, PhysarWarning


def _to_jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def print_json(obj: Any) -> None:
    """Print `obj` (numpy arrays allowed) as JSON on stdout."""
    sys.stdout.write(json.dumps(_to_jsonable(obj), indent=None) + "\n")
    sys.stdout.flush()


def log(msg: str) -> None:
    """Human-readable progress/info to stderr (stdout stays clean for --json)."""
    typer.echo(msg, err=True)


def _show_warning(message, category, filename, lineno, file=None, line=None, _default=warnings.showwarning):
    if issubclass(category, PhysarWarning):
        typer.echo(f"warning: {message}", err=True)
    else:
        _default(message, category, filename, lineno, file, line)


def user_errors(fn: Callable) -> Callable:
    """Decorator: a PhysarError (bad input) prints `error: <message>` to stderr and exits with code 2; a
    PhysarWarning (a result to doubt, e.g. a poor calibration) prints one `warning: <message>` line."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with warnings.catch_warnings():
            warnings.simplefilter("always", PhysarWarning)
            warnings.showwarning = _show_warning
            try:
                return fn(*args, **kwargs)
            except PhysarError as exc:
                typer.echo(f"error: {exc}", err=True)
                raise typer.Exit(code=2) from None

    return wrapper
