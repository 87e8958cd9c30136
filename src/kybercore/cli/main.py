"""The ``kybercore`` command: serve the dashboard, run a demo fleet, manage printers, the
job queue and the notifications.

Only what every command needs is imported here; FastAPI, uvicorn and the simulator are
imported by the commands that use them, so ``kybercore printers list`` starts fast.
"""

from __future__ import annotations

import typer

from kybercore import __version__, native
from kybercore.cli import scale as scale_commands
from kybercore.cli import serve as serve_commands
from kybercore.cli.jobs import jobs_app
from kybercore.cli.notify import notify_app
from kybercore.cli.output import console
from kybercore.cli.printers import printers_app
from kybercore.cli.tokens import tokens_app

app = typer.Typer(
    help="KyberCore: one dashboard for a fleet of Klipper printers, through Moonraker.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)
app.add_typer(printers_app, name="printers")
app.add_typer(jobs_app, name="jobs")
app.add_typer(notify_app, name="notify")
app.add_typer(tokens_app, name="tokens")
for command in (serve_commands.serve, serve_commands.demo, serve_commands.sim):
    app.command()(command)
app.command()(scale_commands.ingest)
app.command()(scale_commands.front)
app.command()(scale_commands.export_printers)


@app.command()
def version() -> None:
    """Print KyberCore's version, and whether its hot path runs compiled."""
    state = native.STATE
    shown = "on" if state.active else "off"
    console.print(f"{__version__} (compiled hot path: {shown}, {state.reason})")
