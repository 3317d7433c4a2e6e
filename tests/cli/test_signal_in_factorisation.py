"""A SIGTERM that lands while CHOLMOD orders the matrix is not lost (issue 21).

METIS_NodeND (its GKlib) replaces the process's SIGTERM/SIGABRT handlers with its own for the length of the
call: a SIGTERM arriving then only aborts METIS (a ``longjmp``), CHOLMOD falls back to AMD, Python's C handler
is put back -- with ``SA_RESETHAND``, so the next SIGTERM kills the process outright -- and the run completes
with exit 0 and its output written. physar never lets CHOLMOD call METIS_NodeND
(``physar.fem.solvers.cholmod_ordering``: AMD below 5,000 rows, CHOLMOD's own nested dissection NESDIS, on
METIS's vertex separator and CAMD, which install no handler, above).

The signal is sent by a POSIX timer (``timer_create`` through ctypes): the CHOLMOD call holds the GIL, so no
Python thread could send it at a chosen moment inside the call. The delays sweep the first 40 % of a timed
call (the ordering comes first: analysis, then the numeric factorisation). Reference: each SIGTERM reaches the
Python handler (counted), the process survives the next one (the handler is not one-shot), and ``physar fem
solve`` exits as on any signal (130, no traceback, nothing written).

Mutant caught: ``cholmod_ordering`` returning CHOLMOD's default (AMD, then METIS_NodeND when AMD's fill is
high, as for a 3-D grid) above 5,000 rows: checked, 8 of the 9 SIGTERMs were swallowed (``got []``), then the process died of the
one-shot handler; ``fem solve`` exited 0 having written ``u.vtu``.
"""
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytest.importorskip("sksparse.cholmod")
if not sys.platform.startswith("linux"):  # pragma: no cover
    pytest.skip("POSIX timers through glibc", allow_module_level=True)

ROOT = Path(__file__).resolve().parents[2]

TIMER = r'''
import ctypes, signal, time

class Timer:
    """A POSIX timer sending SIGTERM to the process after a delay, with no Python code involved."""
    def __init__(self):
        self.libc = ctypes.CDLL(None, use_errno=True)
        ev = (ctypes.c_byte * 64)()  # struct sigevent: sigval (8 bytes), signo (int), notify = SIGEV_SIGNAL (0)
        ctypes.c_int.from_buffer(ev, 8).value = signal.SIGTERM
        self.tid = ctypes.c_void_p()
        if self.libc.timer_create(1, ev, ctypes.byref(self.tid)) != 0:  # CLOCK_MONOTONIC
            raise OSError(ctypes.get_errno(), "timer_create")

    def arm(self, delay):
        spec = (ctypes.c_long * 4)(0, 0, int(delay), int((delay % 1) * 1e9))  # it_interval 0, it_value
        assert self.libc.timer_settime(self.tid, 0, spec, None) == 0

    def pending(self):
        spec = (ctypes.c_long * 4)()
        assert self.libc.timer_gettime(self.tid, spec) == 0
        return spec[2] > 0 or spec[3] > 0
'''

SWEEP = TIMER + r'''
import scipy.sparse as sp
from physar.fem.solvers import factorize
from physar.integrators.linalg import SparseSolver

n = 30  # 7-point Laplacian on a 30^3 grid: AMD's fill is high enough for CHOLMOD's default to try METIS
T = sp.diags([-1, 2.0, -1], [-1, 0, 1], shape=(n, n))
I = sp.identity(n)
A = (sp.kron(sp.kron(T, I), I) + sp.kron(sp.kron(I, T), I) + sp.kron(sp.kron(I, I), T)).tocsc()
got = []
signal.signal(signal.SIGTERM, lambda s, f: got.append(s))
D = float("inf")
for _ in range(2):  # the shorter of two timed calls (the first one warms up)
    t = time.monotonic()
    factorize(A)
    D = min(D, time.monotonic() - t)
timer = Timer()
for k in range(1, 10):
    got.clear()
    timer.arm(D * k / 20)
    if k % 3:
        factorize(A)
    else:
        SparseSolver().factor(A)
    inside = not timer.pending()
    time.sleep(0.05)
    print(k, "inside" if inside else "after", "got", len(got), flush=True)
'''

CONFIG = """
[mesh]
box = [1.0, 0.3, 0.3]
cells = [14, 5, 5]

[material]
model = "linear"
E = 69e9
nu = 0.334

[[fix]]
box = [[0, 0, 0], [0, 0.3, 0.3]]

[[load]]
type = "traction"
box = [[1.0, 0, 0], [1.0, 0.3, 0.3]]
total = [0, 0, -1000]

[fem]
element = "P2"
"""

# the `physar` entry point with sksparse.cholmod.cholesky wrapped: timed once unwatched, then the timer armed
# at a tenth of that time (inside the ordering) before the real call
CLI = TIMER + r'''
signal.signal(signal.SIGINT, signal.default_int_handler)
from sksparse import cholmod
import physar.fem.solvers as solvers

orig = cholmod.cholesky

def cholesky(A, *args, **kw):
    t = time.monotonic()
    orig(A, *args, **kw)
    Timer().arm((time.monotonic() - t) / 10)
    return orig(A, *args, **kw)

cholmod.cholesky = cholesky
from physar.cli.main import main
main()
'''


def _run(code, *args, cwd):
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-c", code, *map(str, args)], cwd=cwd, env=env, check=False,
                          capture_output=True, text=True, timeout=300)


def test_every_sigterm_during_a_factorisation_reaches_python(tmp_path):
    p = _run(textwrap.dedent(SWEEP), cwd=tmp_path)
    assert p.returncode == 0, (p.returncode, p.stdout, p.stderr)  # -15: killed by a one-shot handler
    rows = [line.split() for line in p.stdout.splitlines()]
    assert len(rows) == 9, p.stdout
    assert sum(r[1] == "inside" for r in rows) >= 6, p.stdout  # the sweep did land inside the calls
    assert all(r[3] == "1" for r in rows), p.stdout  # each signal seen once by the Python handler


def test_fem_solve_stops_on_a_sigterm_in_the_ordering(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text(CONFIG)
    p = _run(CLI, "fem", "solve", cfg, "-o", tmp_path / "u.vtu", cwd=tmp_path)
    assert p.returncode == 130, (p.returncode, p.stderr)
    assert "Traceback" not in p.stderr, p.stderr
    assert "interrupted: nothing written" in p.stderr, p.stderr  # one line saying so (it exited silently)
    assert sorted(os.listdir(tmp_path)) == ["c.toml"]
