"""Tables of seed 002 Table 3-style ablations over training seeds, from the ``results_RUN.json`` files that
``bench_recon_pillow.py --ablations`` writes: mean +- sample std per variant, and the paired difference
variant - full on the same seed (mean [min, max]); a variant "separates" in a metric when every seed's paired
difference has the sign of "worse" and its mean exceeds the full model's seed spread (std).

    .venv/bin/python benchmarks/ablation_table.py OUT/results_r0.json OUT/results_r1.json OUT/results_r2.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

# (column, getter, larger is better)
COLUMNS = (
    ("recon_large PSNR", lambda r: r["physics"]["recon_large"]["psnr"], True),
    ("pred_large PSNR", lambda r: r["physics"]["pred_large"]["psnr"], True),
    ("novel_large PSNR", lambda r: r["physics"]["novel_large"]["psnr"], True),
    ("recon_large IoU", lambda r: r["physics"]["recon_large"]["iou"], True),
    ("3-D err recon_large (mm)", lambda r: r["errors_3d_mm"]["recon_large"], False),
    ("3-D err pred_large", lambda r: r["errors_3d_mm"]["pred_large"], False),
    ("3-D err novel_large", lambda r: r["errors_3d_mm"]["novel_large"], False),
    ("E error", lambda r: r["material"]["mean_abs_log10_error"], False),
)


def rows(path: str) -> dict:
    d = json.loads(Path(path).read_text())
    e3 = {k: v["physics"] for k, v in d["errors_3d_mm"].items()}  # the full model's row keeps every method's errors
    out = {"full": {"physics": d["methods"]["physics"], "errors_3d_mm": e3, "material": d["material"]}}
    out.update(d.get("ablations", {}))
    return out


def main() -> None:
    runs = [rows(p) for p in sys.argv[1:]]
    names = list(runs[0])
    val = {n: np.array([[g(r[n]) for _, g, _ in COLUMNS] for r in runs]) for n in names}
    print(f"{len(runs)} seeds: " + ", ".join(sys.argv[1:]))
    print("| variant | " + " | ".join(c for c, _, _ in COLUMNS) + " |")
    print("|---" * (len(COLUMNS) + 1) + "|")
    for n in names:
        m, s = val[n].mean(0), val[n].std(0, ddof=1) if len(runs) > 1 else np.zeros(len(COLUMNS))
        print(f"| {n} | " + " | ".join(f"{a:.3f} ± {b:.3f}" for a, b in zip(m, s, strict=True)) + " |")
    spread = val["full"].std(0, ddof=1) if len(runs) > 1 else np.zeros(len(COLUMNS))
    print("\npaired difference variant - full, mean [min, max]; * = worse on every seed and by more than the full "
          "model's seed std")
    print("| variant | " + " | ".join(c for c, _, _ in COLUMNS) + " |")
    print("|---" * (len(COLUMNS) + 1) + "|")
    for n in names[1:]:
        d = val[n] - val["full"]
        cells = []
        for k, (_, _, up) in enumerate(COLUMNS):
            worse = d[:, k] < 0 if up else d[:, k] > 0
            sep = worse.all() and abs(d[:, k].mean()) > spread[k]
            cells.append(f"{d[:, k].mean():+.3f} [{d[:, k].min():+.3f}, {d[:, k].max():+.3f}]{' *' if sep else ''}")
        print(f"| {n} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
