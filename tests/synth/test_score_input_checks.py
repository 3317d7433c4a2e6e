"""`physar synth score` refuses tables it cannot score, in one `error:` line (exit 2) naming the file, and the row
and column where there is one: a truth with a header and no rows (was exit 1, "zero-size array to reduction
operation minimum"), an estimates file without rows, a NaN truth value, a frame number twice, estimates whose
frames are not the truth's (rows are compared by position), and a constant truth without --project (the
tolerance became 1 % of 1e-300: "within 1e-302").

References: the row numbers are counted by hand in the small CSV files written here (row 1 is the header).
"""
import pytest
from typer.testing import CliRunner

from physar.cli.main import app

TRUTH = "frame,time_s,s_true\n0,0.0,0.2\n1,0.1,0.4\n2,0.2,0.6\n"
EST = "frame,time_s,status,s_est\n0,0.0,tracking,0.2\n1,0.1,tracking,0.4\n2,0.2,tracking,0.6\n"


def _score(tmp_path, truth, est):
    (tmp_path / "t.csv").write_text(truth)
    (tmp_path / "e.csv").write_text(est)
    return CliRunner().invoke(app, ["synth", "score", "t.csv", "e.csv"])


@pytest.mark.parametrize("truth,est,line", [
    # mutant: no row check (ValueError from t.min(), exit 1)
    ("frame,time_s,s_true\n", EST, "t.csv: no rows"),
    # mutant: the estimates' rows unchecked (a score of 0 frames, exit 0)
    (TRUTH, "frame,time_s,status,s_est\n", "e.csv: no rows"),
    # mutant: NaN truth accepted (the NaN row counted as outside, the span taken over the rest)
    (TRUTH.replace("1,0.1,0.4", "1,0.1,nan"), EST, "t.csv: row 3, column s_true: nan is not a finite number"),
    # mutant: no duplicate check (row 3 scored as frame 0 again)
    (TRUTH.replace("1,0.1,0.4", "0,0.1,0.4"), EST, "t.csv: row 3, column frame: frame 0 again (first in row 2)"),
    (TRUTH, EST.replace("2,0.2,tracking", "1,0.2,tracking"), "e.csv: row 4, column frame: frame 1 again"),
    # mutant: rows compared by position whatever their frames (estimates that skipped frame 1)
    (TRUTH, EST.replace("1,0.1,tracking,0.4\n", ""), "e.csv: row 3, column frame: frame 2 where t.csv has frame 1"),
    # a video that dropped frame 1: the pipeline numbers its frames 0, 1 but frame 1 is at 0.2 s (mutant: times
    # not compared: frame 2's estimate scored against frame 1's truth)
    (TRUTH, "frame,time_s,status,s_est\n0,0.0,tracking,0.2\n1,0.2,tracking,0.6\n",
     "e.csv: row 3, column time_s: 0.2 s where t.csv has 0.1 s (more than half a frame apart)"),
    # mutant: max(hi - lo, 1e-300) kept (every frame "within 1e-302")
    (TRUTH.replace("0.4", "0.2").replace("0.6", "0.2"), EST, "t.csv: column s_true is constant (0.2)"),
])
def test_unscorable_tables_are_one_line(tmp_path, monkeypatch, truth, est, line):
    monkeypatch.chdir(tmp_path)
    r = _score(tmp_path, truth, est)
    assert r.exit_code == 2, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {line}"), r.output


def test_constant_truth_asks_for_the_project(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = _score(tmp_path, TRUTH.replace("0.4", "0.2").replace("0.6", "0.2"), EST)
    assert r.exit_code == 2 and "give --project" in r.output, r.output


def test_a_valid_table_still_scores(tmp_path, monkeypatch):
    """The checks refuse none of a valid pair: 3/3 frames within 1 % of the truth's span 0.4 = 0.004."""
    monkeypatch.chdir(tmp_path)
    r = _score(tmp_path, TRUTH, EST.replace("0.6\n", "0.603\n"))
    assert r.exit_code == 0, r.output
    assert "s: 3/3 judged frames within 0.004 (max 0.003 at frame 2" in r.output, r.output


def test_a_parameter_held_constant_is_reported_the_others_scored(tmp_path, monkeypatch):
    """A scenario sweeps s and holds P (its default): s is scored, P reported as not judged (mutant: the whole
    table refused, as a first version of the check did; or P judged against a tolerance of ~1e-302)."""
    monkeypatch.chdir(tmp_path)
    truth = "frame,time_s,s_true,P_true\n0,0.0,0.2,1.0\n1,0.1,0.4,1.0\n2,0.2,0.6,1.0\n"
    est = "frame,time_s,status,s_est,P_est\n0,0.0,tracking,0.2,1.1\n1,0.1,tracking,0.4,0.9\n2,0.2,tracking,0.603,1\n"
    r = _score(tmp_path, truth, est)
    assert r.exit_code == 0, r.output
    assert "s: 3/3 judged frames within 0.004 (max 0.003 at frame 2" in r.output, r.output
    assert "P: not judged: its truth is constant (1), which gives no range for the tolerance; give --project" \
        in r.output, r.output


def test_fewer_estimate_rows_are_said(tmp_path, monkeypatch):
    # estimates of the first 2 of 3 frames (a run stopped early): scored, with one warning naming both counts;
    # equal counts give none. mutant caught: the counts not compared (no warning)
    monkeypatch.chdir(tmp_path)
    r = _score(tmp_path, TRUTH, EST.rsplit("2,0.2", 1)[0])
    assert r.exit_code == 0, r.output
    warn = [ln for ln in r.output.splitlines() if ln.startswith("warning:")]
    assert len(warn) == 1 and "e.csv: 2 frames, t.csv: 3: only the first 2 are scored" in warn[0], r.output
    r = _score(tmp_path, TRUTH, EST)
    assert r.exit_code == 0 and "warning:" not in r.output, r.output
