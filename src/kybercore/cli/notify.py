"""``kybercore notify channels|add|remove|test|deliveries|settings``: the notification
channels of a running KyberCore, from a shell (through its REST API, like ``kybercore
jobs``: see :mod:`kybercore.cli.remote`).

A webhook's signing key is printed once, when the channel is added; nothing shows it
again. Errors print one red ``Error: ...`` line and exit 2 (the input) or 1.
"""

from __future__ import annotations

import json
from typing import Annotated, Any

import typer
from rich.table import Table
from rich.text import Text

from kybercore.cli.options import ServerUrl, Token
from kybercore.cli.output import console, done, fail, print_table
from kybercore.cli.remote import DEFAULT_URL, Remote, remote_errors

notify_app = typer.Typer(
    help="Notifications of a running KyberCore: webhooks and Apprise channels (ntfy, "
    "Telegram, Discord, Slack, e-mail…) told when a print ends, fails or a printer is lost.",
    no_args_is_help=True,
)

ChannelIdArg = Annotated[
    int, typer.Argument(metavar="ID", help="The channel's id (`kybercore notify channels`).")
]
AsJson = Annotated[bool, typer.Option("--json", help="Print the API's JSON.")]
Many = Annotated[list[str] | None, typer.Option(show_default=False)]
API = "/api/notifications"
SETTINGS = {
    "cooldown": ("cooldown_s", "Seconds before the same event of one printer is sent again."),
    "fold_window": ("fold_window_s", "Seconds offline and plate events wait to be folded."),
    "storm_threshold": ("storm_threshold", "More printers of a location offline: one message."),
    "offline_grace": ("offline_grace_s", "An idle printer offline this long alerts; 0: never."),
    "plate_wait": ("plate_wait_s", "Seconds a plate may wait to be cleared before an alert."),
    "job_blocked": ("job_blocked_s", "Seconds a queued job may be stuck before an alert."),
    "unreported_grace": (
        "unreported_grace_s",
        "On NATS: seconds a printer may go unreported by every worker before an alert; 0: never.",
    ),
}


@notify_app.command("channels")
def channels(as_json: AsJson = False, url: ServerUrl = DEFAULT_URL, token: Token = None) -> None:
    """The channels: what each sends, where (masked), and to whom it belongs."""
    with remote_errors(), Remote(url, token) as remote:
        found = remote.call("GET", f"{API}/channels")
    if as_json:
        typer.echo(json.dumps(found, indent=2, ensure_ascii=False))
        return
    if not found:
        typer.echo("No channels. Add one with `kybercore notify add NAME URL`.")
        return
    table = Table()
    for column in ("id", "name", "kind", "target", "events", "filters", "on", "changed by"):
        table.add_column(column, justify="right" if column == "id" else "left")
    for channel in found:
        rules = channel["rules"]
        table.add_row(
            str(channel["id"]), Text(channel["name"]), channel["kind"], Text(channel["target"]),
            Text(", ".join(rules["events"])), Text(_filters(rules)),
            "yes" if channel["enabled"] else "no", rules["min_role"],
        )  # fmt: skip
    print_table(table)


@notify_app.command("add")
def add(
    name: Annotated[str, typer.Argument(help="A name for the channel, e.g. 'night shift'.")],
    target: Annotated[
        str,
        typer.Argument(
            metavar="URL",
            help="A webhook's http(s) URL, or an Apprise URL (ntfys://ntfy.sh/topic, "
            "tgram://token/chat, mailtos://…) with --kind apprise.",
        ),
    ],
    kind: Annotated[str, typer.Option(help="webhook or apprise.")] = "webhook",
    event: Many = None,
    printer: Many = None,
    location: Many = None,
    tag: Many = None,
    quiet: Annotated[
        str | None,
        typer.Option(help="Quiet hours, server local time: HH:MM-HH:MM, e.g. 22:00-07:00."),
    ] = None,
    quiet_critical: Annotated[
        bool, typer.Option(help="Critical events still go out in the quiet hours.")
    ] = True,
    language: Annotated[str, typer.Option(help="en or es.")] = "en",
    snapshot: Annotated[bool, typer.Option(help="Attach a webcam snapshot.")] = True,
    min_role: Annotated[
        str, typer.Option(help="Who may change the channel: operator or admin.")
    ] = "admin",
    secret: Annotated[
        str | None,
        typer.Option(
            help="The webhook's signing key (at least 16 characters); generated when omitted.",
            show_default=False,
        ),
    ] = None,
    disabled: Annotated[bool, typer.Option("--disabled", help="Add it switched off.")] = False,
    url: ServerUrl = DEFAULT_URL,
    token: Token = None,
) -> None:
    """Add a channel. --event, --printer, --location and --tag repeat (default: the
    usual events, every printer). A webhook's signing key is printed once."""
    rules: dict[str, Any] = {
        "printers": printer or [], "locations": location or [], "tags": tag or [],
        "language": language, "attach_snapshot": snapshot, "min_role": min_role,
    }  # fmt: skip
    if event:
        rules["events"] = event
    if quiet:
        start, _, end = quiet.partition("-")
        rules["quiet_hours"] = {"start": start, "end": end, "allow_critical": quiet_critical}
    body = {"name": name, "kind": kind, "target": target, "rules": rules, "enabled": not disabled}
    if secret is not None:
        body["secret"] = secret
    with remote_errors(), Remote(url, token) as remote:
        channel = remote.call("POST", f"{API}/channels", json=body)
    done(f"Added channel {channel['id']} ({channel['name']}, {channel['kind']}).")
    if channel.get("secret"):
        console.print(Text("Signing key (shown only now; keep it where the receiver checks "
                           "X-KyberCore-Signature):"))  # fmt: skip
        typer.echo(channel["secret"])


@notify_app.command("remove")
def remove(
    channel_id: ChannelIdArg,
    yes: Annotated[bool, typer.Option("--yes", "-y", help="Do not ask.")] = False,
    url: ServerUrl = DEFAULT_URL,
    token: Token = None,
) -> None:
    """Remove a channel and its delivery log."""
    with remote_errors(), Remote(url, token) as remote:
        found = {c["id"]: c for c in remote.call("GET", f"{API}/channels")}
        name = found[channel_id]["name"] if channel_id in found else str(channel_id)
        if not yes and not typer.confirm(f"Remove channel {channel_id} ({name})?"):
            typer.echo("Nothing removed.")
            raise typer.Exit(1)
        remote.call("DELETE", f"{API}/channels/{channel_id}")
    done(f"Removed channel {channel_id} ({name}).")


@notify_app.command("test")
def send_test(channel_id: ChannelIdArg, url: ServerUrl = DEFAULT_URL, token: Token = None) -> None:
    """Send a test message and say how it went (exit 1 unless it was delivered)."""
    with remote_errors(), Remote(url, token) as remote:
        delivery = remote.call("POST", f"{API}/channels/{channel_id}/test")
    if delivery["status"] == "delivered":
        code = f" (HTTP {delivery['response_code']})" if delivery["response_code"] else ""
        done(f"Delivered to {delivery['channel_name']}{code}.")
        return
    problem = delivery["last_error"] or "no answer yet"
    retry = f"; next try at {delivery['next_at']}" if delivery["next_at"] else ""
    raise fail(f"Not delivered to {delivery['channel_name']}: {problem}{retry}.")


@notify_app.command("deliveries")
def deliveries(
    channel: Annotated[
        int | None, typer.Option("--channel", metavar="ID", help="Only this channel's.")
    ] = None,
    limit: Annotated[int, typer.Option(min=1, max=1000, help="At most this many.")] = 20,
    as_json: AsJson = False,
    url: ServerUrl = DEFAULT_URL,
    token: Token = None,
) -> None:
    """The delivery log, newest first."""
    params: dict[str, Any] = {"limit": limit}
    if channel is not None:
        params["channel_id"] = channel
    with remote_errors(), Remote(url, token) as remote:
        found = remote.call("GET", f"{API}/deliveries", params=params)
    if as_json:
        typer.echo(json.dumps(found, indent=2, ensure_ascii=False))
        return
    if not found:
        typer.echo("No deliveries yet. Send a test with `kybercore notify test ID`.")
        return
    table = Table()
    for column in ("id", "when", "channel", "event", "printer", "status", "tries", "note"):
        table.add_column(column, justify="right" if column in ("id", "tries") else "left")
    for d in found:
        note = d["last_error"] or (f"HTTP {d['response_code']}" if d["response_code"] else "")
        table.add_row(
            str(d["id"]), d["created_at"], Text(d["channel_name"]), Text(d["title"] or d["kind"]),
            d["printer_id"] or "", d["status"], str(d["attempts"]), Text(note),
        )  # fmt: skip
    print_table(table)


@notify_app.command("settings")
def settings(
    cooldown: Annotated[float | None, typer.Option(help=SETTINGS["cooldown"][1])] = None,
    fold_window: Annotated[float | None, typer.Option(help=SETTINGS["fold_window"][1])] = None,
    storm_threshold: Annotated[
        int | None, typer.Option(help=SETTINGS["storm_threshold"][1])
    ] = None,
    offline_grace: Annotated[float | None, typer.Option(help=SETTINGS["offline_grace"][1])] = None,
    plate_wait: Annotated[float | None, typer.Option(help=SETTINGS["plate_wait"][1])] = None,
    job_blocked: Annotated[float | None, typer.Option(help=SETTINGS["job_blocked"][1])] = None,
    unreported_grace: Annotated[
        float | None, typer.Option(help=SETTINGS["unreported_grace"][1])
    ] = None,
    url: ServerUrl = DEFAULT_URL,
    token: Token = None,
) -> None:
    """Show the noise settings; with options, change those (admins)."""
    given = {
        "cooldown": cooldown, "fold_window": fold_window, "storm_threshold": storm_threshold,
        "offline_grace": offline_grace, "plate_wait": plate_wait, "job_blocked": job_blocked,
        "unreported_grace": unreported_grace,
    }  # fmt: skip
    changes = {SETTINGS[k][0]: v for k, v in given.items() if v is not None}
    with remote_errors(), Remote(url, token) as remote:
        current = remote.call("GET", f"{API}/settings")
        if changes:
            current = remote.call("PUT", f"{API}/settings", json={**current, **changes})
    for option, (field, _) in SETTINGS.items():
        console.print(Text(f"  {option.replace('_', '-')}: {current[field]:g}"))
    if changes:
        done("Settings saved; they apply now.")


def _filters(rules: dict[str, Any]) -> str:
    """'printers a, b; location Lab; quiet 22:00-07:00 (critical go); es'."""
    parts = [
        f"{label} {', '.join(rules[key])}"
        for key, label in (("printers", "printers"), ("locations", "locations"), ("tags", "tags"))
        if rules[key]
    ]
    quiet = rules.get("quiet_hours")
    if quiet:
        critical = " (critical go)" if quiet["allow_critical"] else ""
        parts.append(f"quiet {quiet['start']}-{quiet['end']}{critical}")
    if rules["language"] != "en":
        parts.append(rules["language"])
    return "; ".join(parts)
