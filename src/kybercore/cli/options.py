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
MdnsInterfaces = Annotated[
    list[str] | None,
    typer.Option(
        "--mdns-interface",
        envvar="KYBERCORE_MDNS_INTERFACES",
        help='The IP address of an interface "Find printers" browses for Moonraker\'s mDNS '
        "announcements on; repeat it for more (default: every interface).",
        show_default=False,
    ),
]
DatabaseUrl = Annotated[
    str | None,
    typer.Option(
        "--database-url",
        envvar="KYBERCORE_DATABASE_URL",
        help="The job queue's database (default: SQLite kybercore.db beside printers.json), "
        "e.g. postgresql+asyncpg://user@host/kybercore for several KyberCore processes.",
        show_default=False,
    ),
]
WsCompress = Annotated[
    bool,
    typer.Option(
        "--ws-compress",
        envvar="KYBERCORE_WS_COMPRESS",
        help="Compress /ws frames for browsers that offer it (permessage-deflate): about 15x "
        "fewer bytes, for dashboards watched over a slow link (a VPN), at 13-15 % more CPU "
        "per printer event. Off: frames go out uncompressed, as Moonraker sends them.",
    ),
]
HeatingBudget = Annotated[
    int,
    typer.Option(
        "--heating-budget",
        min=0,
        help="At most this many printers heating at once per power group (a printer's "
        "location) when the queue starts prints; 0: no limit.",
    ),
]
ServerUrl = Annotated[
    str,
    typer.Option(
        "--url",
        envvar="KYBERCORE_URL",
        help="The running KyberCore to talk to.",
    ),
]
Token = Annotated[
    str | None,
    typer.Option(
        "--token",
        envvar="KYBERCORE_TOKEN",
        help="An access token (`kybercore tokens create`), when the server asks for one. "
        "Prefer the variable: a flag lands in shell history.",
        show_default=False,
    ),
]
