"""The `physar` command. Each topic module in physar/cli/ exposes `register(app)`."""

from __future__ import annotations

import importlib

import typer

import physar

app = typer.Typer(
    name="physar",
    help="physar: physics-based visual computing (FEM, reduced models, AR, MPM, Gaussians).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

# Topic modules registering their commands; each is physar.cli.<name> with a `register(app)` function.
TOPICS = ["mesh", "fem", "rom", "dynamics", "denoise", "ar", "synth", "mpm", "recon", "demo"]


def _version(value: bool) -> None:
    if value:
        typer.echo(f"physar {physar.__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool | None = typer.Option(
        None, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """physar: physics-based visual computing."""


for _name in TOPICS:
    importlib.import_module(f"physar.cli.{_name}").register(app)


def main() -> None:  # console-script entry point
    from physar.output import sigterm_as_interrupt

    with sigterm_as_interrupt():  # SIGTERM unwinds like Ctrl-C: no temporary is left behind
        app()


if __name__ == "__main__":  # pragma: no cover
    main()
