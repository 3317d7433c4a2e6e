"""Command-line interface (typer): a thin shell over the Python API. Entry point: `physar`.

The command line is public (its commands, options and outputs); its Python functions are not: use the
packages the commands call. Hence the empty ``__all__`` (docs/api_policy.md).
"""

__all__: list[str] = []
