"""Accuracy of an AR run against the truth of a synthetic clip: ``truth.csv`` of :func:`physar.synth.render_project`
(columns ``{name}_true``, ``occluders``) against the estimates CSV of ``physar ar run`` (``{name}_est``,
``status``).

Judged frames: every frame both files have, except frames at rest (``at_rest`` = 1: the object undeformed, its
parameters unobservable), frames with an occluder in view and the ``recovery`` frames after one (those measure
recovery, reported separately as the frames until the error is back within the tolerance). The tolerance of a parameter is ``tol`` times the length of its range (for a load position: the
path length; 1 % is seed 000's accuracy goal, §5.1)."""
from __future__ import annotations

import numpy as np

from physar.errors import ConfigError


def read_columns(path, what: str = "CSV file") -> dict:
    """Columns of a CSV file with a header row: float arrays where every value parses, else str arrays.
    A missing, empty, binary or ragged file is one ConfigError naming it."""
    import csv
    from pathlib import Path

    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{path}: {what} not found")
    try:
        with open(p, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except (UnicodeDecodeError, csv.Error) as e:
        raise ConfigError(f"{path}: not a CSV {what} ({e.__class__.__name__})") from None
    if not rows or not rows[0]:
        raise ConfigError(f"{path}: empty {what}")
    head, body = rows[0], rows[1:]
    bad = next((i for i, r in enumerate(body) if len(r) != len(head)), None)
    if bad is not None:
        raise ConfigError(f"{path}: row {bad + 2} has {len(body[bad])} values, the header {len(head)}")
    cols = {}
    for j, h in enumerate(head):
        vals = [r[j] for r in body]
        try:
            cols[h] = np.array(vals, float)
        except ValueError:
            cols[h] = np.array(vals)
    return cols


def _numeric(cols: dict, source: str) -> None:
    """Every column the score reads must be numbers ("nan" is one): a word in one of them is one ConfigError
    naming the file, the column, the row and the value."""
    for name, v in cols.items():
        if name == "status" or np.asarray(v).dtype.kind in "fiu":
            continue
        if not (name.endswith(("_true", "_est")) or name in ("occluders", "in_view", "at_rest")):
            continue
        for i, x in enumerate(v):
            try:
                float(x)
            except ValueError:
                raise ConfigError(f"{source}: column {name}, row {i + 2}: {str(x)!r} is not a number") from None


def _rows(cols: dict, source: str, finite: list[str]) -> None:
    """A table with rows, finite values in the ``finite`` columns and no frame number twice (column
    ``frame``, when present); else one ConfigError naming the file, the row and the column."""
    if not any(len(v) for v in cols.values()):
        raise ConfigError(f"{source}: no rows")
    for name in finite:
        v = np.asarray(cols[name], float)
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            raise ConfigError(f"{source}: row {bad[0] + 2}, column {name}: {v[bad[0]]:g} is not a finite number")
    if "frame" in cols:
        seen: dict = {}
        for i, f in enumerate(cols["frame"]):
            if f in seen:
                raise ConfigError(f"{source}: row {i + 2}, column frame: frame {_fmt(f)} again (first in row "
                                  f"{seen[f] + 2})")
            seen[f] = i


def _fmt(v) -> str:
    return f"{v:g}" if isinstance(v, (float, np.floating)) else str(v)


def _same_frames(truth: dict, est: dict, n: int, truth_source: str, source: str) -> None:
    """Rows are compared by position: when both files number their frames, the first ``n`` must agree (an
    estimates file that skipped a frame would otherwise be scored against the wrong truth rows); when both give
    times, the first ``n`` must agree within half the truth's frame interval (a video that dropped frames is
    numbered anew by the pipeline, but its timestamps keep the gaps)."""
    if "frame" not in truth or "frame" not in est:
        return
    t, e = truth["frame"][:n], est["frame"][:n]
    if t.dtype.kind in "fiu" and e.dtype.kind in "fiu":
        differ = np.flatnonzero(t != e)
    else:
        differ = np.flatnonzero(t.astype(str) != e.astype(str))
    if differ.size:
        i = differ[0]
        raise ConfigError(f"{source}: row {i + 2}, column frame: frame {_fmt(e[i])} where {truth_source} has frame "
                          f"{_fmt(t[i])}; the files must list the same frames in the same order")
    if "time_s" in truth and "time_s" in est and n > 1:
        tt, te = (np.asarray(x["time_s"][:n], float) for x in (truth, est))
        dt = float(np.median(np.diff(tt))) if n > 1 else 0.0
        off = np.flatnonzero(np.abs(te - tt) > 0.5 * dt) if dt > 0 else np.zeros(0, int)
        if off.size:
            i = off[0]
            raise ConfigError(f"{source}: row {i + 2}, column time_s: {te[i]:.4g} s where {truth_source} has "
                              f"{tt[i]:.4g} s (more than half a frame apart): the estimates are not of this clip's "
                              "frames (another clip, or a video that dropped or added frames)")


def _hold_lost(e: np.ndarray, status: np.ndarray) -> np.ndarray:
    """A "lost" / "hold" row written without an estimate (nan) takes the last estimate before it: the value
    the pipeline holds on screen; rows before any estimate stay nan."""
    e = e.copy()
    gap = ~np.isfinite(e) & np.isin(status, ("lost", "hold"))
    idx = np.where(np.isfinite(e), np.arange(e.size), -1)
    last = np.maximum.accumulate(idx)
    fill = gap & (last >= 0)
    e[fill] = e[last[fill]]
    return e


def score(truth: dict, est: dict, ranges: dict[str, tuple[float, float]] | None = None, tol: float = 0.01,
          recovery: int = 5, source: str = "estimates", truth_source: str = "truth file") -> dict:
    r"""Per parameter: judged frames (not at rest, no occluder, what is observed in view (truth column
    in_view), not recovering after an occlusion or a look-away), frames within
    :math:`\mathtt{tol} \times \mathrm{range}` (a judged frame before the first "tracking" or "rest" frame
    carries the pipeline's starting value, not an estimate, and counts as outside whatever that value is;
    later "hold" / "lost" frames are judged by the estimate they hold), max / mean / median |error|, and the
    recovery frames after each occlusion. ``ranges`` {name: (lo, hi)} (default: the span of the truth)."""
    names = [c[:-5] for c in truth if c.endswith("_true")]
    if not names:
        raise ConfigError(f"{truth_source}: no <name>_true column (is it the truth.csv of `physar synth render`?)")
    _numeric(truth, truth_source)
    _numeric(est, source)
    missing = [n for n in names if f"{n}_est" not in est]
    if missing:
        raise ConfigError(f"{source}: no column {missing[0]}_est (the truth has parameters {', '.join(names)})")
    _rows(truth, truth_source, [f"{n}_true" for n in names])
    _rows(est, source, [])
    n = min(len(truth[f"{names[0]}_true"]), len(est[f"{names[0]}_est"]))
    _same_frames(truth, est, n, truth_source, source)
    occ = np.asarray(truth.get("occluders", np.zeros(n)), float)[:n] > 0
    occ |= np.asarray(truth.get("in_view", np.ones(n)), float)[:n] < 0.5     # what is observed left the image
    after = np.zeros(n, bool)
    ends = np.flatnonzero(occ[:-1] & ~occ[1:]) + 1
    for e in ends:
        after[e:e + recovery] = True
    status = np.asarray(est.get("status", np.array(["tracking"] * n)))[:n]
    rest = np.asarray(truth.get("at_rest", np.zeros(n)), float)[:n] > 0
    judged = ~occ & ~after & ~rest
    # a row before the first frame with an estimate of its own carries the pipeline's starting value
    estimated = np.cumsum(np.isin(status, ("tracking", "rest"))) > 0
    out = {"frames": int(n), "judged": int(judged.sum()), "at_rest": int(rest.sum()), "tol": tol, "parameters": {},
           "truth_frames": len(truth[f"{names[0]}_true"]), "estimate_frames": len(est[f"{names[0]}_est"])}
    spans = {}
    for name in names:
        t = np.asarray(truth[f"{name}_true"], float)[:n]
        spans[name] = (ranges or {}).get(name, (float(t.min()), float(t.max())))
    if not any(hi > lo for lo, hi in spans.values()):  # a tolerance of tol * 0 for every parameter: nothing to score
        name = names[0]
        raise ConfigError(f"{truth_source}: column {name}_true is constant ({truth[f'{name}_true'][0]:g}), so it "
                          "gives no range for the tolerance; give --project (the model's parameter ranges)")
    for name in names:
        t = np.asarray(truth[f"{name}_true"], float)[:n]
        e = _hold_lost(np.asarray(est[f"{name}_est"], float)[:n], status)
        lo, hi = spans[name]
        if not hi > lo:  # held constant while others vary (a scenario's default): no tolerance without --project
            out["parameters"][name] = {"tolerance": None, "within": None, "judged": 0, "constant": float(t[0]),
                                       "note": "constant truth: no range for the tolerance; give --project"}
            continue
        lim = tol * (hi - lo)
        err = np.abs(e - t)
        err[~np.isfinite(err) | ~estimated] = np.inf
        ej = err[judged]
        rec = []
        for s in ends:
            ok = np.flatnonzero(err[s:s + 30] <= lim)
            rec.append(int(ok[0]) + 1 if ok.size else None)
        out["parameters"][name] = {
            "tolerance": lim, "within": int(np.sum(ej <= lim)), "judged": int(ej.size),
            "max_error": float(ej.max()) if ej.size else float("nan"),
            "mean_error": float(ej.mean()) if ej.size else float("nan"),
            "median_error": float(np.median(ej)) if ej.size else float("nan"),
            "worst_frame": int(np.flatnonzero(judged)[np.argmax(ej)]) if ej.size else None,
            "recovery_frames": rec}
    out["tracking"] = int(np.sum(status[:n] == "tracking"))
    return out


__all__ = ["read_columns", "score"]
