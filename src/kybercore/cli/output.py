"""What the ``kybercore`` command prints: one place for its consoles, tables and errors.

Messages are never wrapped: an error names a file and a line ("line 3, column 14") that
a person reads and a script greps, whatever the terminal's width or whether stdout is a
terminal at all. Messages are plain text, so a ``[bracket]`` in a path is printed as is.
Tables fit a terminal; piped into a file or another program they are never cut.
"""

from __future__ import annotations

import typer
from rich.console import Console
from rich.table import Table
from rich.text import Text

console = Console(soft_wrap=True)
err = Console(stderr=True, soft_wrap=True)


def fail(message: str, *, code: int = 1) -> typer.Exit:
    """Print ``Error: message`` in red on stderr and return the exit to raise."""
    err.print(Text.assemble(("Error:", "red"), " ", message))
    return typer.Exit(code)


def done(message: str) -> None:
    """Print a success line in green."""
    console.print(Text(message, style="green"))


def print_table(table: Table) -> None:
    """Print ``table``: fitted to a terminal, whole (no ``…``) anywhere else."""
    # Made here, not at import: the terminal and $COLUMNS are those of this call.
    out = Console()
    if not out.is_terminal:
        natural = out.measure(table, options=out.options.update_width(1_000_000)).maximum
        out = Console(width=max(out.width, natural))
    out.print(table)
