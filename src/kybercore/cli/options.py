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
AllowedHosts = Annotated[
    list[str] | None,
    typer.Option(
        "--allowed-host",
        envvar="KYBERCORE_ALLOWED_HOSTS",
        help="Another name browsers use to reach KyberCore (a reverse proxy's, a LAN name "
        "such as printers.lan); repeat it for more, or list them (commas or spaces) in the "
        "variable. localhost, the --host name and IP addresses are always served.",
        show_default=False,
    ),
]
