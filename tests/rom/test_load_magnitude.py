"""A load_magnitude parameter P is |load| in N along the configured load vector (its sign included):
the reduced model at P is the full FEM solve with the configured load scaled to |load| = P.

Cantilever 1 x 0.1 x 0.1 m, E = 69 GPa, clamped at x = 0; a point load of radius 0.05 m on the top face at
x = a = 0.9 m (the bump kernel wholly on the face), configured as load = [0, 0, -1000] N with
range = [500, 1500] N. References, both independent of the reduced model:

* the full FE solve of the same problem through its own `fem` problem file ([[load]] type = "point" with
  total = [0, 0, -P]): the reduced model's error there is its truncation error, < 1e-6 (pgd, pod, the
  parametric pgd) or 1e-2 (non-intrusive, adaptive sampling to tol = 1e-3);
* Euler-Bernoulli: the centre-line deflection under a tip-side load P at a is w(a) = -P a^3 / (3 E I),
  I = h^4 / 12 (P L^3 / (3 E I) with L = a). The P2 mesh of 10 x 2 x 2 cells gives 0.99 of it (shear
  flexibility +1 %, the 3D clamp and the coarse mesh stiffer; 0.998 on 20 x 4 x 4 cells): within 2 %.

Mutants caught (each applied to physar/rom/config.py or problem.py, test run, reverted):
the configured magnitude ignored (a unit 1 N load: G = 1 / |load| instead of P / |load|; or P times the
configured vector: G = P), the sign dropped (|load| componentwise), P squared; the refusals and the warning
removed.
"""
import json
import warnings

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from physar.cli import fem, rom
from physar.errors import ConfigError, PhysarWarning
from physar.fem import probe, solve_static
from physar.fem.config import build_problem, load_config
from physar.rom.config import build_rom, load_rom_config

E, H, A, LOAD, RADIUS = 69e9, 0.1, 0.9, -1000.0, 0.05
I = H ** 4 / 12
CENTRE = [A, 0.05, 0.05]           # centre line under the load

BASE = """
[mesh]
box = [1.0, 0.1, 0.1]
cells = [10, 2, 2]

[material]
model = "linear"
E = 69e9
nu = 0.3

[[fix]]
box = [[0, 0, 0], [0, 0.1, 0.1]]

[fem]
element = "P2"
"""
PARAMS = f"""
[[parameter]]
name = "s"
kind = "load_position"
path = [[0.0, 0.05, 0.1], [1.0, 0.05, 0.1]]
points = 11
load = [0, 0, {LOAD}]
radius = {RADIUS}

[[parameter]]
name = "P"
kind = "load_magnitude"
range = [500, 1500]
"""
E_PARAM = """
[[parameter]]
name = "E"
kind = "youngs_modulus"
range = [5e10, 9e10]
points = 5
"""
METHODS = {"pgd": ("", 'method = "pgd"\nmax_modes = 20\ntol = 1e-8\n', 1e-6),
           "pod": ("", 'method = "pod"\nmax_modes = 20\ntol = 1e-10\n', 1e-6),
           "parametric_pgd": (E_PARAM, 'method = "pgd"\nmax_modes = 30\ntol = 1e-8\n', 1e-6),
           "pgd_nonintrusive": ("", 'method = "pgd_nonintrusive"\nmax_modes = 10\ntol = 1e-3\nmax_points = 9\n',
                                1e-2)}

app = typer.Typer()
rom.register(app)
fem.register(app)
runner = CliRunner(mix_stderr=False) if "mix_stderr" in CliRunner.__init__.__code__.co_varnames else CliRunner()


def _fem_solve(tmp_path, P):
    """The full solve of the `fem` problem file with the configured load scaled to |load| = P (downwards)."""
    f = tmp_path / f"fem_{P:g}.toml"
    f.write_text(BASE + f'\n[[load]]\ntype = "point"\npoint = [{A}, 0.05, 0.1]\ntotal = [0, 0, {-P}]\n'
                        f"radius = {RADIUS}\n")
    pr = build_problem(load_config(f))
    return pr.model.space, solve_static(pr.model, pr.f_ext, pr.fixed).u


def _mu(model, P):
    return np.array([{"s": A, "P": P, "E": E}[n] for n in model.names])


@pytest.fixture(scope="module", params=list(METHODS))
def built(request, tmp_path_factory):
    extra, rom_table, tol = METHODS[request.param]
    f = tmp_path_factory.mktemp("lm") / "rom.toml"
    f.write_text(BASE + PARAMS + extra + "\n[rom]\n" + rom_table)
    model, space, _ = build_rom(load_rom_config(f), source=str(f))
    return model, space, tol


@pytest.mark.parametrize("P", [600.0, 1000.0, 1400.0])
def test_rom_at_P_is_the_fem_solve_with_the_load_scaled_to_P(built, tmp_path, P):
    """Mutants: unit load (1e-3 x), P times the vector (1000 x), sign dropped (-1 x), P squared (P x)."""
    model, _, tol = built
    space_f, u_ref = _fem_solve(tmp_path, P)
    assert space_f.n_dofs == model.F.shape[1]
    u = model.evaluate(_mu(model, P))
    assert np.linalg.norm(u - u_ref) <= tol * np.linalg.norm(u_ref)


def test_downward_linear_and_euler_bernoulli(built):
    """P = 600 and 1400 N along load = [0, 0, -1000]: downward, u(1400) / u(600) = 7 / 3, and the
    centre-line deflection -P a^3 / (3 E I) within 2 %."""
    model, space, tol = built
    w = {}
    for P in (600.0, 1400.0):
        w[P] = probe(space, model.evaluate(_mu(model, P)), CENTRE)[2]
        eb = -P * A ** 3 / (3 * E * I)
        assert w[P] < 0                                   # dropping the sign pushes it up
        assert abs(w[P] / eb - 1) < 0.02, (P, w[P], eb)   # unit load: 1e-3; P squared: P
    assert w[1400.0] / w[600.0] == pytest.approx(1400 / 600, rel=max(tol, 1e-9))


def test_cli_rom_eval_at_the_configured_magnitude_equals_fem_solve(tmp_path):
    """`physar rom build` + `rom eval --param P=1000` vs `physar fem solve` with load [0, 0, -1000]."""
    f = tmp_path / "rom.toml"
    f.write_text(BASE + PARAMS + '\n[rom]\nmethod = "pgd"\ntol = 1e-8\n')
    res = runner.invoke(app, ["rom", "build", str(f), "--out", str(tmp_path / "m.npz")])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["rom", "eval", str(tmp_path / "m.npz"), "--param", f"s={A}", "--param", "P=1000",
                              "--probe", *map(str, CENTRE), "--json"])
    assert res.exit_code == 0, res.output
    u_rom = np.array(json.loads(res.stdout)["probes"][0]["u"])
    g = tmp_path / "fem.toml"
    g.write_text(BASE + f'\n[[load]]\ntype = "point"\npoint = [{A}, 0.05, 0.1]\ntotal = [0, 0, {LOAD}]\n'
                        f"radius = {RADIUS}\n\n[[probe]]\npoint = {CENTRE}\n")
    res = runner.invoke(app, ["fem", "solve", str(g), "--out", str(tmp_path / "fem.vtu"), "--json"])
    assert res.exit_code == 0, res.output
    u_fem = np.array(json.loads(res.stdout)["probes"][0]["u"])
    assert u_fem[2] < 0 and np.linalg.norm(u_rom - u_fem) <= 1e-6 * np.linalg.norm(u_fem)


@pytest.mark.parametrize("old, new, says", [
    ("range = [500, 1500]", "range = [-1500, -500]", ("[[parameter]] 'P': range = [-1500.0, -500.0] N: a load_magnitude "
                                                      "is |load| >= 0")),
    ("range = [500, 1500]", "range = [0.5, 2.0]", ("[[parameter]] 'P': range = [0.5, 2.0] N does not contain "
                                                   "|load| = 1000 N")),
    (f"load = [0, 0, {LOAD}]", "load = [0, 0, 0]", "[[parameter]] 's': load = [0.0, 0.0, 0.0] N has zero magnitude"),
])
def test_refused_in_one_line_naming_file_field_value(tmp_path, old, new, says):
    """Mutants: each refusal removed (a negative range flipped the load upwards; [0.5, 2] with a 1000 N load
    built 0.5-2 N; a zero load ran)."""
    f = tmp_path / "rom.toml"
    f.write_text((BASE + PARAMS + '\n[rom]\nmethod = "pgd"\n').replace(old, new))
    with pytest.raises(ConfigError) as exc:
        load_rom_config(f)
    assert str(exc.value).startswith(f"{f}: ") and says in str(exc.value)
    res = runner.invoke(app, ["rom", "build", str(f), "--out", str(tmp_path / "m.npz")])
    assert res.exit_code == 2 and says in res.stderr and not (tmp_path / "m.npz").exists()
    assert len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr


def test_unit_direction_takes_any_range(tmp_path):
    """load = [0, 0, -1] is a direction: range = [10, 60] (examples/rom_stvk_beam.toml) is accepted.
    Mutant: the contains-|load| rule applied to a unit vector too."""
    f = tmp_path / "rom.toml"
    f.write_text((BASE + PARAMS).replace(f"load = [0, 0, {LOAD}]", "load = [0, 0, -1.0]")
                 .replace("range = [500, 1500]", "range = [10, 60]"))
    assert [p.range for p in load_rom_config(f).parameter if p.kind == "load_magnitude"] == [(10.0, 60.0)]


def test_fem_load_kept_next_to_the_parameter_is_named(tmp_path):
    """The fem file's own [[load]] kept in the rom file is applied at every P on top of the load P scales
    (ROM(P = 1000) is twice the fem solve): one PhysarWarning naming the file and the [[load]]; none without it.
    Mutant: no warning."""
    f = tmp_path / "rom.toml"
    f.write_text(BASE + f'\n[[load]]\ntype = "point"\npoint = [{A}, 0.05, 0.1]\ntotal = [0, 0, {LOAD}]\n'
                        f'radius = {RADIUS}\n' + PARAMS + '\n[rom]\nmethod = "pgd"\nmax_modes = 3\n')
    with pytest.warns(PhysarWarning) as rec:
        build_rom(load_rom_config(f), source=str(f))
    msgs = [str(w.message) for w in rec if issubclass(w.category, PhysarWarning)]
    assert len(msgs) == 1 and msgs[0].startswith(f"{f}: [[load]] #1 (point, total [0.0, 0.0, -1000.0] N)")
    f.write_text(BASE + PARAMS + '\n[rom]\nmethod = "pgd"\nmax_modes = 3\n')
    with warnings.catch_warnings():
        warnings.simplefilter("error", PhysarWarning)
        build_rom(load_rom_config(f), source=str(f))
