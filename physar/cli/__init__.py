"""Command-line interface (typer): a thin shell over the Python API. Entry point: `physar`."""
