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
    """Run the CLI. A usage error (a missing argument, an option value of the wrong type, an unknown option)
    is one line naming the command, exit 2, like every other bad input."""
    import sys

    from physar.output import sigterm_as_interrupt

    try:
        from typer._click import exceptions as cx  # (typer's own click; private, so optional)
    except ImportError:  # pragma: no cover - another typer: its boxed usage messages
        cx = None
    with sigterm_as_interrupt():  # SIGTERM unwinds like Ctrl-C: no temporary is left behind
        if cx is None:  # pragma: no cover
            app()
            return
        try:
            rv = app(standalone_mode=False, prog_name="physar")
        except cx.NoArgsIsHelpError:      # a group without its command: the help was printed
            sys.exit(2)
        except cx.UsageError as e:
            cmd = e.ctx.command_path if e.ctx is not None else "physar"
            typer.echo(f"error: {cmd}: {e.format_message()} (see {cmd} --help)", err=True)
            sys.exit(2)
        except typer.Abort:
            typer.echo("Aborted!", err=True)
            sys.exit(1)
    sys.exit(rv if isinstance(rv, int) else 0)


if __name__ == "__main__":  # pragma: no cover
    main()
