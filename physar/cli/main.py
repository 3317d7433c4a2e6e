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


def _reflow(doc: str | None) -> str | None:
    """A command docstring with each paragraph's lines joined (typer keeps the line breaks of the paragraphs
    after the first, so a docstring wrapped at 120 columns printed "A run" alone on a line); lines that start a
    list item ("- ", "* ", "1. ") keep their break."""
    import inspect
    import re

    if not doc:
        return doc
    paras = inspect.cleandoc(doc).split("\n\n")
    out = []
    for p in paras:
        lines = p.split("\n")
        joined = [lines[0]]
        for ln in lines[1:]:
            if re.match(r"\s*([-*]|\d+\.)\s", ln):
                joined.append(ln)
            else:
                joined[-1] = joined[-1].rstrip() + " " + ln.strip()
        out.append("\n".join(joined))
    return "\n\n".join(out)


def _reflow_all(t: typer.Typer) -> None:
    for c in t.registered_commands:
        if c.help is None and c.callback is not None and c.callback.__doc__:
            c.help = _reflow(c.callback.__doc__)
    for g in t.registered_groups:
        _reflow_all(g.typer_instance)


_reflow_all(app)


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
