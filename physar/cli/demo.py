"""`physar demo`: the project's main example."""

from __future__ import annotations

from pathlib import Path

import typer

from physar.cli._common import log, print_json, user_errors


def demo(
    out: Path = typer.Option(Path("demo_out"), "--out", "-o", help="output folder"),
    json_out: bool = typer.Option(False, "--json", help="print the report as JSON on stdout"),
) -> None:
    """Run the verified cantilever example: VTU result, PNG picture and report.json."""
    from physar.fem.examples import run_cantilever_demo

    report = run_cantilever_demo(out)
    if json_out:
        print_json(report)
    else:
        log(f"cantilever tip deflection {report['tip_deflection_m'] * 1e3:.4f} mm, Timoshenko "
            f"{report['timoshenko_m'] * 1e3:.4f} mm (relative difference {report['relative_error']:.2%})")
        log(f"wrote {', '.join(str(out / f) for f in report['files'])}")


def register(app: typer.Typer) -> None:
    app.command("demo")(user_errors(demo))
