"""BLAS thread limits for the reduced-model loops.

The PGD fixed point and the Newton snapshots interleave CHOLMOD solves (system OpenBLAS + libgomp) with
small numpy products (numpy's own OpenBLAS). Two thread pools that spin-wait on a small, shared machine
slow each solve down many times (measured here: a 9k-dof PGD build 5 s with numpy's BLAS limited to one
thread, 45-85 s without, at load average 6-11 on 2 cores). Vector-sized products gain nothing from
threads, so these loops run with one BLAS/OpenMP thread (``threadpoolctl``; a no-op without it).
"""
from __future__ import annotations

import contextlib


def single_blas_thread():
    """Context manager: one BLAS and one OpenMP thread in every loaded library for its duration."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - optional
        return contextlib.nullcontext()
    return threadpool_limits(1)


def blas_single_threaded(func):
    """Decorator form of :func:`single_blas_thread`."""
    import functools

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with single_blas_thread():
            return func(*args, **kwargs)

    return wrapper
