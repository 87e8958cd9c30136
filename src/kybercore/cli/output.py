"""What the ``kybercore`` command prints: one place for its consoles and its error line.

Messages are never wrapped: an error names a file and a line ("line 3, column 14") that
a person reads and a script greps, whatever the terminal's width or whether stdout is a
terminal at all. Messages are plain text, so a ``[bracket]`` in a path is printed as is.
"""

from __future__ import annotations

import typer
from rich.console import Console
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
