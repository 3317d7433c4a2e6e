"""`physar mpm run|identify` input checks and output folder (probe findings):

* a scene whose particles would not fit in memory (particles_per_cell = 1000000) is refused before sampling, in
  one line naming the scene file and the particle count (it started to allocate tens of GiB);
* an initial velocity moving particles more than a grid cell per substep (1e300 m/s) is refused up front,
  naming the scene file, without numpy RuntimeWarnings (it overflowed the energy and left out/ holding only
  frame_0000.ply); "outside the domain" and "no particles" name the scene file too;
* the output folder is written whole (physar.output.atomic_folder): an interrupted or failed run leaves no
  folder (nor temporary) behind; a run that diverges keeps frames 0..N with diagnostics.csv covering exactly
  them and says so;
* `identify` on a target where E has no effect (free fall) warns once and leaves E at its initial value (it
  reported E = 2500 Pa, the scan's first factor 1/4, with loss 0 and no warning).

References: particle counts and the CFL bound dx / dt computed by hand in the tests.
"""
import warnings

import numpy as np
import pytest
import typer
from test_mpm_cli import TINY  # the tiny falling box of the CLI tests
from typer.testing import CliRunner

import physar.output
from physar.cli.mpm import register
from physar.errors import ConfigError
from physar.mpm import build_model, parse_scene
from physar.mpm.identify import unconstrained_bodies
from physar.mpm.runner import run_scene


@pytest.fixture()
def app():
    a = typer.Typer()
    register(a)
    return a


def _invoke(app, tmp_path, text, *args, name="s.toml"):
    (tmp_path / name).write_text(text)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = CliRunner().invoke(app, ["mpm", *args])
    return r, [w for w in caught if issubclass(w.category, RuntimeWarning)]


def test_huge_particle_count_is_refused_before_sampling(app, tmp_path, monkeypatch):
    """A 0.25 m box on a 64-cell grid at 125 = 5^3 particles per cell: (0.25 / (1/64/5))^3 = 80^3 = 512,000
    particles, about 0.7 GiB, refused when 64 MiB are available. Mutant caught: no estimate (the run samples and
    simulates the half million particles and exits 0)."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(physar.output, "available_memory", lambda: 64 * 2**20)
    text = TINY.replace("resolution = 8", "resolution = 64").replace("particles_per_cell = 8",
                                                                     "particles_per_cell = 125")
    r, _ = _invoke(app, tmp_path, text, "run", "s.toml", "-o", "out")
    assert r.exit_code == 2, r.output
    assert r.output.strip().splitlines()[-1].startswith(
        "error: s.toml: about 5.12e+05 particles (125 per cell on a 64^3 grid) needs about"), r.output
    assert not (tmp_path / "out").exists()


def test_particle_estimate_of_the_probe_scene():
    """particles_per_cell = 1000000 (100 per axis) on 64 cells: 1600^3 = 4.1e9 particles, over 6 TiB; refused
    whatever the machine (no memory is touched). Mutant caught: the estimate left out (the sampling's meshgrid of
    4.1e9 points fails with MemoryError or worse)."""
    sc = parse_scene({"grid": {"size": 1.0, "resolution": 64},
                      "body": [{"shape": "box", "min": [0.375, 0.375, 0.5], "max": [0.625, 0.625, 0.75],
                                "particles_per_cell": 1000000}]})
    with pytest.raises(ConfigError, match=r"s\.toml: about 4\.1e\+09 particles .* TiB of memory"):
        build_model(sc, source="s.toml")


def test_cfl_bound_on_the_initial_velocity(tmp_path):
    """dx = 1/8 m, dt = 0.02 / 20 = 1e-3 s: at most dx / dt = 125 m/s. Mutant caught: no bound (1e300 m/s runs,
    overflows the kinetic energy with a RuntimeWarning and fails after writing frame 0)."""
    for v, ok in ((124.0, True), (126.0, False)):
        sc = parse_scene({"grid": {"size": 1.0, "resolution": 8}, "time": {"frame_dt": 0.02, "substeps": 20},
                          "body": [{"shape": "box", "min": [0.375] * 3, "max": [0.625] * 3,
                                    "velocity": [0, -v, 0]}]})
        if ok:
            build_model(sc, source="s.toml")
        else:
            with pytest.raises(ConfigError, match=r"s\.toml: body\[0\] starts particles at up to 126 m/s .* 1\.01 "
                                                  r"grid cells per substep"):
                build_model(sc, source="s.toml")


def test_divergent_velocity_is_one_line_naming_the_scene(app, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r, runtime = _invoke(app, tmp_path, TINY.replace("velocity = [0.3, 0, 0.5]", "velocity = [1e300, 0, 0]"),
                         "run", "div.toml", "-o", "od", name="div.toml")
    assert r.exit_code == 2, r.output
    assert r.output.strip().splitlines()[-1].startswith("error: div.toml: body[0] starts particles"), r.output
    assert not runtime, [str(w.message) for w in runtime]
    assert not (tmp_path / "od").exists() and sorted(p.name for p in tmp_path.iterdir()) == ["div.toml"]


@pytest.mark.parametrize("edit,needle", [
    (("max = [0.625, 0.625, 0.75]", "max = [0.625, 0.625, 1.5]"), "body[0] extends outside the domain"),
    # a box in cm on a 1 m grid: 1.3e10 particles, but the unit slip is named, not the memory (mutant: the
    # bounds checked only after the memory estimate)
    (("min = [0.375, 0.375, 0.5]\nmax = [0.625, 0.625, 0.75]", "min = [15, 40, 40]\nmax = [40, 56, 56]"),
     "body[0] extends outside the domain [0, 1.0]^3 (its bounds [15.0, 40.0, 40.0] - [40.0, 56.0, 56.0])"),
    (('shape = "box"\nmin = [0.375, 0.375, 0.5]\nmax = [0.625, 0.625, 0.75]',
      'shape = "sphere"\ncenter = [0.5, 0.5, 0.5]\nradius = 0.001'), "body[0] contains no particles"),
])
def test_body_errors_name_the_scene_file(app, tmp_path, monkeypatch, edit, needle):
    """Mutant caught: the messages without the file (as before). The sphere of radius 1 mm at the centre lies
    between the lattice points (1/16 + k/8 m), 0.108 m from the nearest."""
    monkeypatch.chdir(tmp_path)
    r, _ = _invoke(app, tmp_path, TINY.replace(*edit), "run", "s.toml", "-o", "o")
    assert r.exit_code == 2 and f"error: s.toml: {needle}" in r.output, r.output


def test_a_diverging_run_keeps_a_consistent_output(app, tmp_path, monkeypatch):
    """E = 1e10 Pa with one substep of 0.02 s blows up at frame 2: out/ holds frames 0 and 1 with a
    diagnostics.csv of exactly those two rows, the error names the scene and the frames written, and no
    temporary folder is left beside it. Mutant caught: the solver's SolverError not caught in the frame loop
    (out/ missing, or, writing in place as before, holding frame_0000.ply alone)."""
    monkeypatch.chdir(tmp_path)
    text = (TINY.replace("E = 1e4", "E = 1e10").replace("substeps = 20", "substeps = 1")
            .replace("frames = 4", "frames = 20")
            .replace("velocity = [0.3, 0, 0.5]",
                     "velocity = [0.3, 0, 0.5]\nvelocity_gradient = [[1, 0.5, 0], [0, 0, 0.3], [0, 0, 0]]"))
    r, _ = _invoke(app, tmp_path, text, "run", "s.toml", "-o", "a/out", "--no-preview")
    assert r.exit_code == 2, r.output
    last = r.output.strip().splitlines()[-1]
    assert last.startswith("error: s.toml: at frame 2 ") and last.endswith("wrote frames 0-1 to a/out"), r.output
    out = tmp_path / "a" / "out"
    assert sorted(p.name for p in out.iterdir()) == ["diagnostics.csv", "frame_0000.ply", "frame_0001.ply"]
    assert len((out / "diagnostics.csv").read_text().strip().splitlines()) == 1 + 2
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["out"]


def test_an_aborted_run_leaves_nothing_and_keeps_a_previous_output(tmp_path):
    """An exception during the frames (here from the progress callback, as a second Ctrl-C would raise) leaves
    no output folder and no temporary; over a previous run's folder, that folder stays as it was. Mutant
    caught: frames written straight into out/ (a folder with frame_0000.ply .. frame_0002.ply remains)."""
    scene = tmp_path / "s.toml"
    scene.write_text(TINY)

    def abort(frame, frames):
        if frame == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_scene(scene, tmp_path / "out", progress=abort, preview=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml"]
    run_scene(scene, tmp_path / "out", preview=False)
    before = {p.name: p.read_bytes() for p in (tmp_path / "out").iterdir()}
    with pytest.raises(KeyboardInterrupt):
        run_scene(scene, tmp_path / "out", progress=abort, preview=False)
    assert {p.name: p.read_bytes() for p in (tmp_path / "out").iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "s.toml"]


def test_identify_warns_when_the_target_does_not_constrain_E(app, tmp_path, monkeypatch):
    """The tiny block flies freely for 4 frames (no contact, F = I): its motion does not depend on E. One
    `warning:` line, and E stays at its initial 1e4 Pa. Mutants caught: no warning; the scan's argmin kept (E =
    2500 Pa, the first factor 1/4, as the probe found)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(TINY)
    run_scene(tmp_path / "s.toml", tmp_path / "o1", preview=False)
    r, _ = _invoke(app, tmp_path, TINY, "identify", "s.toml", "-t", "o1", "--iterations", "2")
    assert r.exit_code == 0, r.output
    warn = [ln for ln in r.output.splitlines() if ln.startswith("warning:")]
    assert len(warn) == 1 and "body 0: the target does not constrain E" in warn[0], r.output
    assert "body 0: E = 10000 Pa (initial 10000)" in r.output, r.output


def test_unconstrained_criterion():
    """Per body (columns), the misfit over the scan: constant (0 or not) -> unconstrained; a change of 1e-3
    relative, or a diverged (inf) factor -> constrained. Mutant caught: an absolute threshold (a misfit of
    1e-12 that doubles over the scan would count as unconstrained)."""
    mis = np.array([[0.0, 5.0, 1e-12, 1.0, 1.0],
                    [0.0, 5.0, 2e-12, 1.001, np.inf],
                    [0.0, 5.0 * (1 + 1e-9), 1e-12, 1.0, 1.0]])
    assert unconstrained_bodies(mis) == [0, 1]


def test_identify_on_a_stressed_body_does_not_warn():
    """A bar stretched by an initial velocity gradient vibrates at a rate set by E: the scan's misfits differ,
    no warning. Mutant caught: a criterion that flags every body."""
    from physar.mpm.identify import identify

    sc = parse_scene({"grid": {"size": 1.0, "resolution": 16},
                      "time": {"frame_dt": 2.5e-3, "substeps": 10, "frames": 4},
                      "gravity": {"g": [0.0, 0.0, 0.0]}, "boundary": {"ground": "none", "walls": "none"},
                      "body": [{"shape": "box", "min": [0.375, 0.4375, 0.4375], "max": [0.625, 0.5625, 0.5625],
                                "particles_per_cell": 1, "E": 5e4, "nu": 0.0, "density": 1000.0,
                                "velocity_gradient": [[2, 0, 0], [0, 0, 0], [0, 0, 0]]}]})
    model, x0, v0 = build_model(sc)
    target = [{"x": x0, "body": model.body}]
    from physar.mpm.model import MPMSolver
    solver = MPMSolver(model)
    a, b = model.state(x0, v0), model.state(x0, v0)
    for _ in range(4):
        a, b = solver.simulate_frame(a, b)
        target.append({"x": a.x.numpy().copy(), "body": model.body})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        guess = build_model(parse_scene({**sc.model_dump(), "body": [{**sc.body[0].model_dump(), "E": 2e4}]}))[0]
        identify(guess, x0, v0, 4, target, iterations=1)



def test_no_preview_keeps_no_positions_and_the_estimate_counts_them_only_with_a_preview(tmp_path, monkeypatch):
    """The preview needs every frame's positions (24 B per particle per frame); without it they were kept anyway
    while the memory estimate did not count them. Measured here: the peak of numpy allocations (tracemalloc) of
    a 32,768-particle run grows by < 1/4 of 30 frames' positions from 10 to 40 frames with --no-preview, and
    the estimate asks for exactly 24 (frames + 1) B more per particle with a preview. Mutants caught: positions
    appended whatever ``preview`` says; the preview's bytes left out of the estimate (or counted without it)."""
    import tracemalloc

    from physar.mpm import runner

    big = (TINY.replace("resolution = 8", "resolution = 32").replace("substeps = 20", "substeps = 1")
           .replace("frame_dt = 0.02", "frame_dt = 0.001").replace("min = [0.375, 0.375, 0.5]", "min = [0.25, 0.25, 0.25]")
           .replace("max = [0.625, 0.625, 0.75]", "max = [0.75, 0.75, 0.75]"))
    peaks = {}
    for frames in (10, 40):
        scene = tmp_path / f"s{frames}.toml"
        scene.write_text(big.replace("frames = 4", f"frames = {frames}"))
        tracemalloc.start()
        res = run_scene(scene, tmp_path / f"o{frames}", preview=False)
        peaks[frames] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    n = res.n_particles
    assert n == 16 ** 3 * 8
    assert peaks[40] - peaks[10] < 0.25 * 30 * 24 * n, (peaks, 30 * 24 * n)
    # the estimate: what build_model is asked to add per particle
    asked = []
    real = runner.build_model
    monkeypatch.setattr(runner, "build_model", lambda *a, **k: asked.append(k["bytes_per_particle"]) or real(*a, **k))
    monkeypatch.setattr(runner, "write_preview_mp4", lambda *a, **k: False)
    scene = tmp_path / "s4.toml"
    scene.write_text(TINY)
    run_scene(scene, tmp_path / "p", preview=True)
    run_scene(scene, tmp_path / "q", preview=False)
    assert asked == [24 * (4 + 1), 0]
