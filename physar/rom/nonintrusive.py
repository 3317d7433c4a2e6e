r"""Non-intrusive PGD (seed 000 §5.3): the full model is a black box :math:`u = \mathrm{solve}(\mu)`; the
separated approximation :math:`u(x, \mu) \approx \sum_i F_i(x) \prod_j G_i^j(\mu_j)` is built from snapshots
at collocation points
of the parameter domain, sampled adaptively, with snapshots computed in parallel on Dask.

Sampling (a tensor grid refined interval by interval, in the spirit of the adaptive collocation of the
seed's reference [50]): every parameter starts with ``initial_points`` equispaced values. In each
round, for every parameter :math:`j` and every interval :math:`[a, b]` of its current values not yet
converged, the black box is run at the midpoint :math:`m = (a + b)/2` crossed with the current values of the
other parameters. These runs first serve as out-of-sample checks: the interval is converged when

.. math::

    \frac{\max_q \|u_h(\mu_q) - u(\mu_q)\|}{\max_{\text{samples}} \|u\|} \le \mathrm{tol}

for the approximation :math:`u_h` built before they were run; either way the runs become samples (a tensor grid
needs them) and a failing interval is split into two that are checked in the next round. Sampling stops
when no interval fails or ``max_points`` values per parameter are reached; the last round's maximum is
reported as the error estimate.

Separated approximation (collocation) on the tensor grid of samples, data tensor :math:`T`
(n_dof, n_1..n_p): greedy rank-one enrichment, each term by alternating least squares (seed §3 fixed point,
here on point values instead of the weak form)

.. math::

    F = \frac{R \times_1 G^1 \cdots \times_p G^p}{\prod_j |G^j|^2}, \qquad
    G^j = \frac{R \times_0 F \times_{k \ne j} G^k}{|F|^2 \prod_{k \ne j} |G^k|^2},

with :math:`R` the residual tensor (:math:`\times_k` the mode-:math:`k` product), each new term followed by an
update of all terms (joint ALS sweeps over the space and every parameter direction, CP-ALS), until
:math:`|R| / |T| \le` fit_tol (default tol / 10) or
``max_modes``. The space direction is compressed first by a thin SVD of the snapshot matrix (exact up to
fit_tol / 100), so the ALS runs on a small coefficient tensor. For one parameter the greedy rank-one
ALS converges to the truncated SVD, which is used directly. Between samples the 1-D modes are
interpolated by the cubic splines of :class:`SeparatedModel`.

Parallel snapshots: ``workers=N`` starts a ``distributed.LocalCluster`` of N single-threaded worker
processes with OMP/OPENBLAS/MKL_NUM_THREADS=1 (an untuned cluster oversubscribes BLAS threads and
runs each task several times slower than serial); ``scheduler=ADDRESS`` uses an existing cluster; with
neither (or fewer than ``min_parallel`` runs in a batch) snapshots run serially in-process. The black
box is sent to the workers once (scattered) and must be picklable.
"""
from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Sequence

import numpy as np

from physar.errors import ConfigError, SolverError
from physar.rom._threads import single_blas_thread
from physar.rom.separated import SeparatedModel

BLAS_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def _run_blackbox(blackbox, mu):
    return np.asarray(blackbox(np.asarray(mu, float)), float)


class SnapshotRunner:
    """Runs the black box at many parameter points: serially, on a LocalCluster, or on a scheduler.

    Use as a context manager (the LocalCluster it starts is closed on exit).
    """

    def __init__(self, blackbox, workers: int | None = None, scheduler: str | None = None,
                 min_parallel: int = 4):
        if workers is not None and workers < 1:
            raise ConfigError(f"workers must be >= 1, got {workers}")
        self.blackbox = blackbox
        self.workers = workers
        self.scheduler = scheduler
        self.min_parallel = min_parallel
        self.client = None
        self.cluster = None
        self._bb_future = None

    @property
    def parallel(self):
        """True when snapshots go to Dask: a scheduler address, or ``workers`` given (even 1)."""
        return self.scheduler is not None or self.workers is not None

    def _start(self):
        if self.client is not None:
            return
        try:
            from distributed import Client, LocalCluster
        except ImportError as exc:  # pragma: no cover - dask is a dependency
            raise ConfigError(f"parallel snapshots need dask.distributed ({exc})") from None
        if self.scheduler is not None:
            try:
                self.client = Client(self.scheduler, timeout="10s")
            except (OSError, TimeoutError) as exc:
                raise ConfigError(f"cannot connect to the Dask scheduler at {self.scheduler!r} ({exc})") from None
        else:
            import dask

            with dask.config.set({"distributed.nanny.pre-spawn-environ": BLAS_ENV}):
                self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                            dashboard_address=None, env=BLAS_ENV)
            self.client = Client(self.cluster)
        self._bb_future = self.client.scatter(self.blackbox, broadcast=True)

    def run(self, points: Sequence[Sequence[float]], progress: Callable[[int], None] | None = None):
        """Snapshots (len(points), n_dof) at the given parameter points, in order."""
        points = [tuple(map(float, p)) for p in points]
        if not points:
            return []
        if not self.parallel or len(points) < self.min_parallel:
            out = []
            with single_blas_thread():
                for p in points:
                    out.append(_run_blackbox(self.blackbox, p))
                    if progress:
                        progress(1)
            return out
        self._start()
        from distributed import as_completed

        futures = [self.client.submit(_run_blackbox, self._bb_future, p, pure=False) for p in points]
        index = {f.key: i for i, f in enumerate(futures)}
        out = [None] * len(points)
        try:
            for fut in as_completed(futures):
                out[index[fut.key]] = fut.result()
                if progress:
                    progress(1)
        except Exception as exc:
            for f in futures:
                f.cancel()
            if isinstance(exc, (SolverError, ConfigError)):
                raise
            raise SolverError(f"snapshot failed on a Dask worker: {type(exc).__name__}: {exc}") from None
        return out

    def close(self):
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        self.client = self.cluster = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _khatri_rao(mats):
    """Column-wise Kronecker product, rows in C order of the matrices' row indices (first slowest)."""
    out = mats[0]
    for m in mats[1:]:
        out = (out[:, None, :] * m[None, :, :]).reshape(-1, out.shape[1])
    return out


def separated_fit(T: np.ndarray, max_modes: int = 30, fit_tol: float = 1e-6, max_als: int = 100,
                  als_tol: float = 1e-10, sweeps: int = 100):
    """Greedy rank-one / ALS separated approximation of a tensor T (n_dof, n_1, .., n_p).

    Returns (F (n, n_dof), [:math:`G^j` (n, n_j)], relative residuals after each mode).
    """
    T = np.asarray(T, float)
    p = T.ndim - 1
    norm_T = np.linalg.norm(T)
    if norm_T == 0:
        return np.zeros((1, T.shape[0])), [np.zeros((1, n)) for n in T.shape[1:]], [0.0]
    if p == 1:
        U, S, Vt = np.linalg.svd(T, full_matrices=False)
        rel = np.sqrt(np.maximum(np.cumsum((S**2)[::-1])[::-1] - S**2, 0.0)) / norm_T  # after i+1 modes
        n = int(min(max_modes, np.searchsorted(-rel, -fit_tol) + 1, S.size))
        return U[:, :n].T.copy(), [S[:n, None] * Vt[:n]], list(rel[:n])
    # compress the space direction first (thin SVD of the snapshot matrix, Frobenius norm preserved):
    # the greedy/ALS then runs on the r x n_1 x .. x n_p coefficient tensor, F = U_r F_c
    U, S, Vt = np.linalg.svd(T.reshape(T.shape[0], -1), full_matrices=False)
    tail = np.sqrt(np.maximum(np.cumsum((S**2)[::-1])[::-1], 0.0)) / norm_T  # tail[i] = |S[i:]| / |T|
    r = int(np.searchsorted(-tail, -0.01 * fit_tol)) or 1
    Ur = U[:, :r]
    F, G, rels = _separated_fit_nd((S[:r, None] * Vt[:r]).reshape(r, *T.shape[1:]), max_modes, fit_tol,
                                   max_als, als_tol, sweeps)
    # order the terms by decreasing amplitude |F_i| prod_j |G_i^j| (the joint update may reorder them)
    amp = np.linalg.norm(F, axis=1) * np.prod([np.linalg.norm(g, axis=1) for g in G], axis=0)
    order = np.argsort(-amp, kind="stable")
    return F[order] @ Ur.T, [g[order] for g in G], rels


def _separated_fit_nd(T, max_modes, fit_tol, max_als, als_tol, sweeps):
    p = T.ndim - 1
    norm_T = np.linalg.norm(T)
    letters = "abcdefgh"[:p]
    full = "z" + letters
    R = T.copy()
    Fs, Gs, rels = [], [[] for _ in range(p)], []
    unfold = [np.moveaxis(T, k, 0).reshape(T.shape[k], -1) for k in range(p + 1)]
    letters = "abcdefgh"[:p]
    full = "z" + letters
    for _ in range(max_modes):
        # initial guess: the parameter-direction profiles of the largest snapshot
        idx = np.unravel_index(np.argmax(np.linalg.norm(R, axis=0)), R.shape[1:])
        G = [np.ones(n) for n in R.shape[1:]]
        for j in range(p):
            sl = [int(i) for i in idx]
            sl[j] = slice(None)
            G[j] = np.linalg.norm(R[(slice(None), *sl)], axis=0) + 1e-12
        F = None
        for _ in range(max_als):
            F = np.einsum(f"{full}," + ",".join(letters) + "->z", R, *G) / np.prod([g @ g for g in G])
            change = 0.0
            for j in range(p):
                others = [G[k] for k in range(p) if k != j]
                subs = ",".join(letters[k] for k in range(p) if k != j)
                expr = f"{full},z" + ("," + subs if subs else "") + f"->{letters[j]}"
                gj = np.einsum(expr, R, F, *others) / ((F @ F) * np.prod([g @ g for g in others]))
                change = max(change, np.linalg.norm(gj - G[j]) / max(np.linalg.norm(gj), 1e-300))
                G[j] = gj
            if change < als_tol:
                break
        Fs.append(F)
        for j in range(p):
            Gs[j].append(G[j])
        # update of all terms (joint ALS sweeps over the space and every parameter direction, i.e. CP-ALS:
        # factor k <- T_(k) (Khatri-Rao of the others) (Hadamard product of their Gram matrices)^-1)
        factors = [np.array(Fs).T] + [np.array(g).T for g in Gs]  # (n_dof, r), (n_j, r)
        prev = None
        for _ in range(sweeps):
            for k in range(p + 1):
                others = [m for m in range(p + 1) if m != k]
                M = unfold[k] @ _khatri_rao([factors[m] for m in others])
                gram = np.prod([factors[m].T @ factors[m] for m in others], axis=0)
                factors[k] = np.linalg.lstsq(gram, M.T, rcond=None)[0].T
            approx = (factors[0] @ _khatri_rao(factors[1:]).T).reshape(T.shape)
            res = float(np.linalg.norm(T - approx) / norm_T)
            if res <= fit_tol or (prev is not None and prev - res <= 1e-4 * res):
                break
            prev = res
        # normalise each term: unit F and unit G^j for j >= 1, amplitude in G^0
        Fs, Gs = list(factors[0].T), [list(f.T) for f in factors[1:]]
        for i in range(len(Fs)):
            a = np.linalg.norm(Fs[i]) or 1.0
            Fs[i] = Fs[i] / a
            Gs[0][i] = Gs[0][i] * a
            for j in range(1, p):
                nj = np.linalg.norm(Gs[j][i]) or 1.0
                Gs[j][i] = Gs[j][i] / nj
                Gs[0][i] = Gs[0][i] * nj
        R = T - approx
        rels.append(res)
        if rels[-1] <= fit_tol:
            break
    return np.array(Fs), [np.array(g) for g in Gs], rels


def nonintrusive_pgd(blackbox: Callable[[np.ndarray], np.ndarray], ranges, names, units=None, *,
                     initial_points: int = 5, tol: float = 2e-3, max_points: int = 65, max_modes: int = 30,
                     fit_tol: float | None = None, workers: int | None = None, scheduler: str | None = None,
                     min_parallel: int = 4, progress: Callable[[int, int], None] | None = None,
                     metadata: dict | None = None):
    """Non-intrusive PGD of ``blackbox(mu) -> u`` (n_dof,) over the box ``ranges`` = [(lo, hi), ...].

    1 to 3 parameters. Returns (SeparatedModel, info) with info keys "n_solves", "grids" (sampled
    values per parameter), "error_estimate" (last round's out-of-sample relative error), "rounds"
    (per round: new samples, max error), "fit_residual", "time_s".
    ``progress(done, planned)`` is called after each snapshot.
    """
    ranges = [tuple(map(float, r)) for r in ranges]
    p = len(ranges)
    if not 1 <= p <= 3:
        raise ConfigError(f"non-intrusive PGD supports 1 to 3 parameters, got {p}")
    if len(names) != p:
        raise ConfigError(f"{p} ranges but {len(names)} names")
    for name, (lo, hi) in zip(names, ranges):
        if not hi > lo:
            raise ConfigError(f"parameter {name!r}: range must be increasing, got [{lo}, {hi}]")
    if initial_points < 2:
        raise ConfigError(f"initial_points must be >= 2, got {initial_points}")
    fit_tol = 0.1 * tol if fit_tol is None else fit_tol
    t0 = time.perf_counter()
    grids = [list(np.linspace(lo, hi, initial_points)) for lo, hi in ranges]
    data: dict[tuple, np.ndarray] = {}
    state = {"done": 0, "planned": 0}

    def tick(k=1):
        state["done"] += k
        if progress:
            progress(state["done"], state["planned"])

    def fit():
        axes = [np.array(g) for g in grids]
        T = np.stack([data[key] for key in itertools.product(*[tuple(a) for a in axes])], axis=1)
        T = T.reshape(T.shape[0], *[a.size for a in axes])
        F, G, rels = separated_fit(T, max_modes=max_modes, fit_tol=fit_tol)
        return SeparatedModel(F, axes, G, names, units, metadata), rels, T

    rounds = []
    with SnapshotRunner(blackbox, workers, scheduler, min_parallel) as runner:
        pts = list(itertools.product(*grids))
        state["planned"] += len(pts)
        for key, u in zip(pts, runner.run(pts, tick)):
            data[key] = u
        pending = [[(g[k], g[k + 1]) for k in range(len(g) - 1)] for g in grids]
        model, rels, T = fit()
        scale = float(np.linalg.norm(T, axis=0).max()) or 1.0
        err_est = np.inf
        while any(pending):
            round_err, new = 0.0, 0
            for j in range(p):
                if not pending[j]:
                    continue
                intervals = [iv for iv in pending[j] if len(grids[j]) < max_points]
                pending[j] = []
                if not intervals:
                    continue
                mids = [(a + b) / 2 for a, b in intervals]
                others = [grids[k] if k != j else [None] for k in range(p)]
                cand = []
                for m in mids:
                    for combo in itertools.product(*others):
                        cand.append(tuple(m if k == j else combo[k] for k in range(p)))
                state["planned"] += len(cand)
                snaps = runner.run(cand, tick)
                per_mid = {m: 0.0 for m in mids}
                for key, u in zip(cand, snaps):
                    e = np.linalg.norm(model.evaluate(key) - u) / scale
                    per_mid[key[j]] = max(per_mid[key[j]], e)
                    data[key] = u
                new += len(cand)
                for (a, b), m in zip(intervals, mids):
                    round_err = max(round_err, per_mid[m])
                    if per_mid[m] > tol:
                        pending[j] += [(a, m), (m, b)]
                grids[j] = sorted(grids[j] + mids)
                model, rels, T = fit()  # the other parameters' checks see the refined grid
                scale = max(scale, float(np.linalg.norm(T, axis=0).max()))
            if new:
                rounds.append({"new_samples": new, "max_error": round_err})
                err_est = round_err
    info = {"n_solves": len(data), "grids": [np.array(g) for g in grids], "error_estimate": err_est,
            "rounds": rounds, "fit_residual": rels, "time_s": time.perf_counter() - t0,
            "n_modes": model.n_modes}
    if any(len(g) >= max_points for g in grids) and err_est > tol:
        info["warning"] = f"max_points={max_points} reached before the error estimate met tol={tol}"
    model.metadata.setdefault("method", "pgd_nonintrusive")
    return model, info


class MovingLoadProblem:
    """The black box of the moving-load examples: the static (possibly nonlinear) response to a
    point load (regularised Dirac, :func:`physar.fem.point_load`) at arc length s along the polyline
    `path` (>= 2 points, :func:`physar.geometry.path_point`).

    Parameters, in order: ``s`` (m); with ``magnitude_range`` a load scale ``P`` (N, the magnitude
    of the load vector); with ``offset_dir`` a lateral offset ``t`` (m) of the load point along that
    unit vector. ``__call__(mu)`` runs :func:`physar.fem.solve_static` (Newton, ``steps`` load steps).
    """

    def __init__(self, model, fixed, path, load, radius, steps=4, tol=1e-10, max_iter=30,
                 magnitude=False, offset_dir=None):
        from physar.geometry.path import as_path, path_length

        path = as_path(path, "load path")
        self.length = path_length(path)
        self.model, self.fixed, self.path = model, np.asarray(fixed), path
        self.load = np.asarray(load, float)
        self.radius, self.steps, self.tol, self.max_iter = float(radius), int(steps), tol, max_iter
        self.magnitude = bool(magnitude)
        self.offset_dir = None if offset_dir is None else np.asarray(offset_dir, float) / np.linalg.norm(offset_dir)

    def point(self, mu):
        mu = np.atleast_1d(np.asarray(mu, float))
        from physar.geometry.path import path_point

        x = path_point(self.path, mu[0])
        if self.offset_dir is not None:
            x = x + mu[-1] * self.offset_dir
        return x

    def force(self, mu):
        from physar.fem import point_load

        mu = np.atleast_1d(np.asarray(mu, float))
        load = self.load * (mu[1] / np.linalg.norm(self.load) if self.magnitude else 1.0)
        return point_load(self.model.space, self.point(mu), load, self.radius)

    def __call__(self, mu):
        from physar.fem import solve_static

        try:
            res = solve_static(self.model, self.force(mu), self.fixed, steps=self.steps, tol=self.tol,
                               max_iter=self.max_iter)
        except SolverError as exc:
            raise SolverError(f"full solve at parameters {np.round(np.atleast_1d(mu), 6).tolist()}: {exc}") from None
        return res.u


def build_moving_load_nonintrusive(model, fixed, path, load=(0, 0, -1.0), radius=0.04, magnitude_range=None,
                                   offset_range=None, offset_dir=None, steps=4, **kwargs):
    """Non-intrusive PGD of the moving-load problem for any material (stvk, neohookean, ...).

    Parameters: s in [0, |path|] (m); optionally P in ``magnitude_range`` (N); optionally an offset t in
    ``offset_range`` (m) along ``offset_dir``. Other keywords go to :func:`nonintrusive_pgd`.
    """
    bb = MovingLoadProblem(model, fixed, path, load, radius, steps=steps,
                           magnitude=magnitude_range is not None,
                           offset_dir=offset_dir if offset_range is not None else None)
    if offset_range is not None and offset_dir is None:
        raise ConfigError("offset_range needs offset_dir (a unit vector for the lateral offset)")
    ranges, names, units = [(0.0, bb.length)], ["s"], ["m"]
    if magnitude_range is not None:
        ranges.append(tuple(magnitude_range))
        names.append("P")
        units.append("N")
    if offset_range is not None:
        ranges.append(tuple(offset_range))
        names.append("t")
        units.append("m")
    meta = {"kind": "load_position", "path": np.asarray(path, float).tolist(),
            "load": list(map(float, load)), "radius": float(radius),
            "material": type(model.material).__name__, "method": "pgd_nonintrusive"}
    kwargs.setdefault("metadata", meta)
    return nonintrusive_pgd(bb, ranges, names, units, **kwargs)


__all__ = [
    "BLAS_ENV",
    "MovingLoadProblem",
    "SnapshotRunner",
    "build_moving_load_nonintrusive",
    "nonintrusive_pgd",
    "separated_fit",
]
