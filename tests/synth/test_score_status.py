"""`physar.synth.score`: a judged frame before the first frame with an estimate of its own ("tracking" or
"rest") carries the pipeline's starting value and counts as outside the tolerance, whatever that value is (a
review found `synth score` reporting 4/90 frames within 1 % for a run that tracked no frame: the mid-range
starting values happened to lie near the truth); later "hold"/"lost" frames are judged by the estimate they
hold; and `--json` output is strict JSON (no NaN / Infinity tokens).

Reference: counts by hand on 6-frame tables. Mutants caught: the status ignored (a run with no tracked frame
scores 5 within instead of 0), every hold/lost frame excluded (3 instead of 4 after tracking), the non-finite
maximum printed as Infinity (json.loads with a strict parse_constant fails).
"""
import json

import numpy as np
from typer.testing import CliRunner

from physar.cli.main import app
from physar.synth.score import score


def _tables():
    truth = {"s_true": np.full(6, 0.5)}
    est = {"s_est": np.array([0.5, 0.5, 0.5, 0.5, 0.6, 0.5]),
           "status": np.array(["hold", "lost", "tracking", "hold", "tracking", "lost"])}
    return truth, est


def test_frames_before_the_first_estimate_count_as_outside():
    truth, est = _tables()
    s = score(truth, est, {"s": (0.0, 1.0)})["parameters"]["s"]
    # frames 0, 1: the starting value (here equal to the truth), outside; 2 within; 3 and 5 hold 0.5, within;
    # 4 is 0.1 off
    assert s["judged"] == 6 and s["within"] == 3
    assert s["max_error"] == np.inf
    never = dict(est, status=np.array(["hold"] * 6))
    assert score(truth, never, {"s": (0.0, 1.0)})["parameters"]["s"]["within"] == 0


def test_score_json_is_strict(tmp_path):
    _truth, est = _tables()
    # without --project the tolerance is 1 % of the truth's span (a constant truth is refused): a ramp over
    # [0, 1], the estimates off by est - 0.5 as in _tables (frame 4 by 0.1)
    ramp = np.arange(6) / 5
    (tmp_path / "truth.csv").write_text("frame,s_true\n" + "".join(f"{k},{float(t)!r}\n" for k, t in enumerate(ramp)))
    (tmp_path / "est.csv").write_text("frame,status,s_est\n" + "".join(
        f"{k},{st},{float(t + v - 0.5)!r}\n" for k, (st, t, v) in enumerate(zip(est["status"], ramp, est["s_est"]))))
    r = CliRunner().invoke(app, ["synth", "score", str(tmp_path / "truth.csv"), str(tmp_path / "est.csv"),
                                 "--json"])
    assert r.exit_code == 0, r.output

    def refuse(name):
        raise AssertionError(f"non-strict JSON token {name}")

    line = next(ln for ln in r.output.splitlines() if ln.startswith("{"))
    out = json.loads(line, parse_constant=refuse)
    s = out["parameters"]["s"]
    assert s["within"] == 3 and s["max_error"] is None
