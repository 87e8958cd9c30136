"""``kybercore jobs add|list|show|cancel|requeue|pause|resume``: the job queue of a running
KyberCore, from a shell (through its REST API: see :mod:`kybercore.cli.remote`).

Errors print one red ``Error: ...`` line, the server's reasons below it, and exit 2 (the
input) or 1 (anything else).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table
from rich.text import Text

from kybercore.cli.options import ServerUrl, Token
from kybercore.cli.output import console, done, print_table
from kybercore.cli.remote import DEFAULT_URL, Remote, RemoteError, print_reasons, remote_errors

jobs_app = typer.Typer(
    help="Queue jobs on a running KyberCore: each copy goes to a compatible idle printer, "
    "and the next one only after the plate is cleared.",
    no_args_is_help=True,
)

JobIdArg = Annotated[
    int, typer.Argument(metavar="ID", help="The job's id (`kybercore jobs list`).")
]
AsJson = Annotated[bool, typer.Option("--json", help="Print the API's JSON.")]


@jobs_app.command("add")
def add(
    file: Annotated[
        Path,
        typer.Argument(exists=True, dir_okay=False, readable=True, help="The G-code file."),
    ],
    copies: Annotated[int, typer.Option("--copies", "-n", min=1, help="Good copies wanted.")] = 1,
    material: Annotated[
        str | None, typer.Option(help="Filament the printer must have loaded, e.g. PLA.")
    ] = None,
    nozzle: Annotated[float | None, typer.Option(help="Nozzle diameter needed, in mm.")] = None,
    model: Annotated[str | None, typer.Option(help="Printer model needed.")] = None,
    tag: Annotated[
        list[str] | None,
        typer.Option(
            "--tag", metavar="TAG", help="A tag the printer must carry; repeat.", show_default=False
        ),
    ] = None,
    printer: Annotated[
        str | None, typer.Option("--printer", metavar="ID", help="Print only on this printer.")
    ] = None,
    priority: Annotated[int, typer.Option(help="Higher runs first.")] = 0,
    not_before: Annotated[
        str | None,
        typer.Option(
            help="Start no copy before this time (ISO 8601 with zone, e.g. "
            "2026-05-01T08:00:00+02:00)."
        ),
    ] = None,
    max_attempts: Annotated[
        int, typer.Option(min=1, help="Failed attempts before the job is blocked.")
    ] = 3,
    allow_mismatch: Annotated[
        bool, typer.Option(help="Dispatch even where the file's metadata disagrees (logged).")
    ] = False,
    url: ServerUrl = DEFAULT_URL,
    token: Token = None,
) -> None:
    """Queue COPIES copies of a G-code file."""
    given = {
        "quantity": copies, "priority": priority, "material": material, "nozzle": nozzle,
        "model": model, "printer": printer, "not_before": not_before,
        "max_attempts": max_attempts, "allow_mismatch": allow_mismatch, "tags": tag or [],
    }  # fmt: skip
    form = {k: _form_value(v) for k, v in given.items() if v is not None}
    with remote_errors(), Remote(url, token) as remote, file.open("rb") as content:
        job = remote.call("POST", "/api/jobs", files={"file": (file.name, content)}, data=form)
    done(f"Queued job {job['id']}: {_copies(job)} of {job['file']['name']}{_needs_suffix(job)}.")


@jobs_app.command("list")
def list_jobs(
    all_jobs: Annotated[
        bool, typer.Option("--all", help="Include done and cancelled jobs.")
    ] = False,
    as_json: AsJson = False,
    url: ServerUrl = DEFAULT_URL,
    token: Token = None,
) -> None:
    """The queue in dispatch order: copies done, in flight and left."""
    with remote_errors(), Remote(url, token) as remote:
        jobs = remote.call("GET", "/api/jobs", params={"finished": all_jobs})
        queue = remote.call("GET", "/api/queue")
    if as_json:
        typer.echo(json.dumps(jobs, indent=2, ensure_ascii=False))
        return
    if queue["paused"]:
        console.print(
            Text(
                "The queue is paused: no new copy starts (`kybercore jobs resume`).", style="yellow"
            )
        )
    if queue["awaiting_clear"]:
        console.print(
            Text(
                "Awaiting a plate clear: "
                + ", ".join(queue["awaiting_clear"])
                + " (`kybercore printers clear ID --good`)."
            )
        )
    if not jobs:
        typer.echo("No jobs. Queue one with `kybercore jobs add FILE --copies N`.")
        return
    table = Table()
    counts = ("done", "printing", "to clear", "left", "of", "priority")
    for column in ("id", "file", *counts, "state", "needs"):
        table.add_column(column, justify="right" if column in counts else "left")
    for job in jobs:
        table.add_row(
            str(job["id"]), Text(job["file"]["name"]), str(job["done"]),
            str(job["in_flight"] - job["awaiting_clear"]), str(job["awaiting_clear"]),
            str(job["left"]), str(job["quantity"]), str(job["priority"]),
            Text(job["state"] + (f": {job['reason']}" if job["reason"] else "")),
            Text(_needs(job)),
        )  # fmt: skip
    print_table(table)


@jobs_app.command("show")
def show(
    job_id: JobIdArg, as_json: AsJson = False, url: ServerUrl = DEFAULT_URL, token: Token = None
) -> None:
    """One job: its copies, its attempts, and why it waits where it waits."""
    with remote_errors(), Remote(url, token) as remote:
        job = remote.call("GET", f"/api/jobs/{job_id}")
        attempts = remote.call("GET", f"/api/jobs/{job_id}/attempts")
        why = remote.call("GET", f"/api/jobs/{job_id}/why")
    if as_json:
        typer.echo(
            json.dumps({"job": job, "attempts": attempts, "why": why}, indent=2, ensure_ascii=False)
        )
        return
    console.print(Text(f"Job {job['id']}: {job['file']['name']}", style="bold"))
    copies = (
        f"{job['done']} done, {job['in_flight'] - job['awaiting_clear']} printing, "
        f"{job['awaiting_clear']} awaiting a clear, {job['left']} left, of {job['quantity']}"
    )
    for label, value in (
        ("state", job["state"] + (f" ({job['reason']})" if job["reason"] else "")),
        ("copies", copies),
        ("priority", str(job["priority"])),
        ("needs", _needs(job) or "any printer"),
        ("not before", job["not_before"] or "-"),
        ("failures", f"{job['failures']} of {job['max_attempts']} allowed"),
        ("queued", f"{job['created_at']} by {job['created_by']}"),
    ):
        console.print(Text(f"  {label}: {value}"))
    if attempts:
        table = Table(title="Attempts")
        for column in ("copy", "printer", "state", "verdict", "started", "ended", "note"):
            table.add_column(column)
        for a in attempts:
            note = "; ".join(x for x in (a["reason"], a["cause"]) if x)
            when = (a["started_at"] or "", a["ended_at"] or "")
            table.add_row(
                str(a["copy"]), a["printer"], a["state"], a["verdict"] or "", *when, Text(note)
            )
        print_table(table)
    if job["state"] == "queued":
        console.print(
            Text("Why it is not printing:" if why else "Nothing holds it back.", style="bold")
        )
        for line in why:
            console.print(Text(f"  {line['subject']}: {line['en']}"))


@jobs_app.command("cancel")
def cancel(
    job_id: JobIdArg,
    yes: Annotated[
        bool, typer.Option("--yes", "-y", help="Do not ask; also cancel its prints under way.")
    ] = False,
    url: ServerUrl = DEFAULT_URL,
    token: Token = None,
) -> None:
    """Cancel a job; its copies printing now are cancelled too, once confirmed."""
    with remote_errors(), Remote(url, token) as remote:
        job = remote.call("GET", f"/api/jobs/{job_id}")
        if not yes and not typer.confirm(f"Cancel job {job_id} ({job['file']['name']})?"):
            typer.echo("Nothing cancelled.")
            raise typer.Exit(1)
        path = f"/api/jobs/{job_id}"
        try:
            job = remote.call("DELETE", path, params={"confirm": yes})
        except RemoteError as exc:
            if exc.code != "confirmation_required":
                raise
            console.print(Text(exc.message))
            print_reasons(exc.reasons)
            if not typer.confirm("Cancel those prints too?"):
                typer.echo("Nothing cancelled.")
                raise typer.Exit(1) from None
            job = remote.call("DELETE", path, params={"confirm": True})
    done(f"Cancelled job {job_id} ({job['file']['name']}).")


@jobs_app.command("requeue")
def requeue(job_id: JobIdArg, url: ServerUrl = DEFAULT_URL, token: Token = None) -> None:
    """Put a blocked job back in the queue, its failures forgotten."""
    with remote_errors(), Remote(url, token) as remote:
        job = remote.call("POST", f"/api/jobs/{job_id}/requeue")
    done(f"Job {job_id} ({job['file']['name']}) is queued again: {job['left']} copies left.")


@jobs_app.command("pause")
def pause(url: ServerUrl = DEFAULT_URL, token: Token = None) -> None:
    """Stop starting new copies (prints under way go on)."""
    with remote_errors(), Remote(url, token) as remote:
        remote.call("POST", "/api/queue", json={"paused": True})
    done("The queue is paused: no new copy starts until `kybercore jobs resume`.")


@jobs_app.command("resume")
def resume(url: ServerUrl = DEFAULT_URL, token: Token = None) -> None:
    """Start dispatching copies again."""
    with remote_errors(), Remote(url, token) as remote:
        remote.call("POST", "/api/queue", json={"paused": False})
    done("The queue is running.")


def _form_value(value: Any) -> Any:
    """A form field's text (lists stay lists: repeated fields)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return value if isinstance(value, list) else str(value)


def _copies(job: dict[str, Any]) -> str:
    return "1 copy" if job["quantity"] == 1 else f"{job['quantity']} copies"


def _needs(job: dict[str, Any]) -> str:
    """What a printer must have: 'PLA, 0.4 mm nozzle, tags a+b, only printer-1'."""
    r = job["requirements"]
    parts = [
        r["material"] or "",
        f"{r['nozzle']:g} mm nozzle" if r["nozzle"] else "",
        r["model"] or "",
        "tags " + "+".join(r["tags"]) if r["tags"] else "",
        f"only {r['printer']}" if r["printer"] else "",
    ]
    return ", ".join(p for p in parts if p)


def _needs_suffix(job: dict[str, Any]) -> str:
    needs = _needs(job)
    return f" (needs {needs})" if needs else ""
