"""``kybercore tokens create|list|revoke``: who may use the dashboard and the API."""

from __future__ import annotations

import datetime
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from kybercore.api.auth import ROLES, TokenStore, tokens_path_for
from kybercore.cli.audit import CliAction, audited
from kybercore.cli.options import PrintersFile
from kybercore.cli.output import console, fail, print_table
from kybercore.errors import KyberCoreError
from kybercore.registry.store import default_printers_path

tokens_app = typer.Typer(
    help="Create, list and revoke access tokens (roles: viewer, operator, admin).",
    no_args_is_help=True,
)


def _store(printers_file: Path | None) -> TokenStore:
    return TokenStore(tokens_path_for(printers_file or default_printers_path()))


@tokens_app.command("create")
def create(
    name: Annotated[str, typer.Argument(help="Who or what uses the token, e.g. 'alice'.")],
    role: Annotated[str, typer.Option(help=f"One of: {', '.join(ROLES)}.")] = "viewer",
    printers_file: PrintersFile = None,
) -> None:
    """Create a token and print it once (only its hash is stored)."""
    try:
        asked = CliAction("token.create", params={"name": name, "role": role})
        with audited(printers_file, asked) as action:
            record, token = _store(printers_file).create(name, role)
            action.target = f"token:{record.id}"
    except KyberCoreError as exc:
        raise fail(exc.message, code=2) from None
    console.print(f"Created token {record.id} for {record.name} ({record.role}).")
    console.print("Copy it now; it is not shown again:\n")
    print(token)


@tokens_app.command("list")
def list_tokens(printers_file: PrintersFile = None) -> None:
    """List tokens (never the tokens themselves)."""
    table = Table()
    for column in ("id", "name", "role", "created"):
        table.add_column(column)
    for record in _store(printers_file).records():
        created = datetime.datetime.fromtimestamp(record.created).strftime("%Y-%m-%d %H:%M")
        table.add_row(record.id, record.name, record.role, created)
    print_table(table)


@tokens_app.command("revoke")
def revoke(
    token_id: Annotated[str, typer.Argument(help="The id shown by `kybercore tokens list`.")],
    printers_file: PrintersFile = None,
) -> None:
    """Revoke a token at once: a running server refuses it from its next request, ends the
    browser sessions made from it and closes its WebSockets within a second."""
    try:
        with audited(printers_file, CliAction("token.revoke", f"token:{token_id}")) as action:
            record = _store(printers_file).revoke(token_id)
            action.params = {"name": record.name, "role": record.role}
    except KyberCoreError as exc:
        raise fail(exc.message, code=2) from None
    console.print(f"Revoked {record.id} ({record.name}).")
