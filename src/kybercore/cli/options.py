"""Options every ``kybercore`` command spells the same way."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

PrintersFile = Annotated[
    Path | None,
    typer.Option(
        "--printers-file",
        envvar="KYBERCORE_PRINTERS",
        help="The fleet's printers.json (default: ./printers.json); tokens.json lives beside it.",
        show_default=False,
    ),
]
Host = Annotated[str, typer.Option(help="Address to listen on.")]
Port = Annotated[int, typer.Option(help="Port of the dashboard and API.")]
