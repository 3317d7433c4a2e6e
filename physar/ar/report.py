"""Reports of an AR run against a reference: the table of dwell segments (seed 000 Table 1: actual value,
mean estimate, |difference|) and the plot of every parameter's estimate ± 2 sd against the truth with the
error below, for any project (the parameters' names and units come from the model).

Inputs are the columns of ``truth.csv`` (``{name}_true``, ``time_s``, optional ``at_rest`` and
``occluders``) and of the pipeline's ``estimates.csv`` (``{name}_est``, ``{name}_std``, ``status``, optional
``at_bound``), as read by :func:`physar.synth.score.read_columns` or any CSV reader. An estimate of NaN (a
"lost" frame, a frame before the first estimate) is a gap in the plot and left out of the table.
"""
from __future__ import annotations

import numpy as np

from physar.output import atomic_path


def dwell_table(truth: dict, est: dict, name: str, settle: int = 3, min_frames: int = 5) -> list[dict]:
    """Rows (actual, mean estimate, |difference|, frames) for each run of frames where the true value of
    ``name`` stays constant (a dwell), tracking frames only, the first ``settle`` frames of a run skipped."""
    t = np.asarray(truth[f"{name}_true"], float)
    e = np.asarray(est[f"{name}_est"], float)
    n = min(len(t), len(e))
    t, e = t[:n], e[:n]
    ok = np.asarray(est.get("status", np.array(["tracking"] * n)))[:n] == "tracking"
    rest = np.asarray(truth.get("at_rest", np.zeros(n)), float)[:n] > 0
    span = float(np.nanmax(t) - np.nanmin(t)) if n else 0.0
    same = np.r_[False, np.abs(np.diff(t)) <= 1e-9 * max(span, 1e-300)]
    starts = np.flatnonzero(~same)
    rows = []
    for a, b in zip(starts, np.r_[starts[1:], n]):
        sel = np.arange(a + settle, b)
        sel = sel[ok[sel] & ~rest[sel] & np.isfinite(e[sel])]
        if b - a < min_frames or sel.size == 0:
            continue
        m = float(np.mean(e[sel]))
        rows.append({"actual": float(t[a]), "mean_estimate": m, "abs_difference": abs(m - float(t[a])),
                     "frames": int(sel.size)})
    return rows


def plot_estimates(truth: dict, est: dict, names, units, path, title: str = "", tol: float = 0.01,
                   ranges=None) -> None:
    """One panel pair per parameter: truth and estimate ± 2 sd over time (NaN estimates: gaps), and the error
    with the ±tol x range band; frames at rest and with occluders shaded, estimates at a bound of the model's
    range (column ``at_bound``) marked. Written atomically to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = min(len(truth["time_s"]), len(est[f"{names[0]}_est"]))
    t = np.asarray(truth["time_s"], float)[:n]
    status = np.asarray(est.get("status", np.array(["tracking"] * n)))[:n]
    shade = {"at rest": np.asarray(truth.get("at_rest", np.zeros(n)), float)[:n] > 0,
             "occluded": np.asarray(truth.get("occluders", np.zeros(n)), float)[:n] > 0,
             "not tracking": status != "tracking"}
    fig, axes = plt.subplots(2 * len(names), 1, figsize=(10, 3.4 * len(names) + 0.6), sharex=True,
                             gridspec_kw={"height_ratios": [2, 1] * len(names)}, squeeze=False)
    for j, (name, unit) in enumerate(zip(names, units)):
        a1, a2 = axes[2 * j, 0], axes[2 * j + 1, 0]
        tv = np.asarray(truth[f"{name}_true"], float)[:n]
        ev = np.asarray(est[f"{name}_est"], float)[:n]
        sd = np.nan_to_num(np.asarray(est.get(f"{name}_std", np.zeros(n)), float)[:n], nan=0.0)
        lo, hi = (ranges or {}).get(name, (float(np.nanmin(tv)), float(np.nanmax(tv))))
        band = tol * max(hi - lo, 1e-300)
        for (label, m), col in zip(shade.items(), ("0.75", "tab:orange", "tab:purple")):
            if m.any():
                for ax in (a1, a2):
                    ax.fill_between(t, 0, 1, where=m, transform=ax.get_xaxis_transform(), color=col, alpha=0.25,
                                    lw=0, label=label if ax is a1 else None)
        a1.plot(t, tv, "k-", lw=2, label=f"true {name}")
        a1.plot(t, ev, "-", color="tab:blue", lw=1.2, label="estimate")
        sd = np.minimum(sd, 0.1 * (hi - lo))
        a1.fill_between(t, ev - 2 * sd, ev + 2 * sd, color="tab:blue", alpha=0.25, lw=0, label="estimate ± 2 sd")
        pinned = _at_bound(est, name, n)
        if pinned.any():
            a1.plot(t[pinned], ev[pinned], "x", color="tab:red", ms=4, label="at a bound of the model's range")
        a1.set_ylabel(f"{name} [{unit}]")
        a1.legend(loc="upper right", fontsize=8, ncol=3)
        err = np.where(status == "tracking", ev - tv, np.nan)
        a2.plot(t, err, color="tab:red", lw=1, label="estimate - truth")
        a2.axhline(band, color="0.3", ls="--", lw=1, label=f"±{tol:.0%} of the range")
        a2.axhline(-band, color="0.3", ls="--", lw=1)
        a2.set_ylim(-3 * band, 3 * band)
        a2.set_ylabel(f"error [{unit}]")
        a2.legend(loc="upper left", fontsize=8, ncol=2)
    axes[0, 0].set_title(title)
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)


def _at_bound(est: dict, name: str, n: int) -> np.ndarray:
    """Frames (bool, n) whose ``at_bound`` cell (``name:lower;other:upper``) names the parameter ``name``."""
    col = est.get("at_bound")
    if col is None:
        return np.zeros(n, bool)
    cells = [str(v) for v in np.asarray(col)[:n]]
    out = np.array([name in {x.split(":")[0] for x in c.split(";") if x} for c in cells], bool)
    return np.r_[out, np.zeros(n - out.size, bool)]


__all__ = ["dwell_table", "plot_estimates"]
