"""The optional AI advisor: a second opinion that may only add warnings. Off by default.

The spec lets the backend "use AI for advanced validations". Here that is an external
service speaking the OpenAI-compatible ``/v1/chat/completions`` API, configured by URL,
key and model. It receives a compact JSON of the facts (action, printer, parameters, file
metadata) and answers ``{"warnings": [{"en": ..., "es": ...}]}``.

What it can and cannot do:

* It never blocks and never unblocks: its findings are ``warn`` reasons of category
  ``advisor``, and :func:`combine` keeps the rules' verdict as the floor.
* It has a hard time budget (1.5 s by default). When it does not answer in time, cannot be
  reached, fails, or answers something unreadable, validation goes on with the rules alone
  and says so with one ``advisor_unavailable`` reason. That reason is a *warning*, not a
  silent note: whoever configured an advisor relies on it, so the user confirms knowingly
  that this action went without its review. With no advisor configured nothing is added.
* Only actions with content worth a second look are sent (start, upload, gcode,
  set_temperature); emergency stop and the like are never delayed by it.
* The API key travels only in the ``Authorization: Bearer`` header and is never logged.
"""

from __future__ import annotations

import asyncio
import json
import logging
import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any, Final

import httpx
from pydantic import SecretStr

from kybercore.core.messages import Reason
from kybercore.core.validation import PrinterFacts, Verdict

log = logging.getLogger(__name__)

ADVISED_ACTIONS: Final = frozenset({"start", "upload", "gcode", "set_temperature"})
MAX_WARNINGS: Final = 5
MAX_TEXT: Final = 300
_MAX_SCRIPT_CHARS: Final = 8000
# Metadata fields worth the advisor's attention; thumbnails, uuids and byte offsets are not.
_FILE_FIELDS: Final = (
    "slicer", "slicer_version", "object_height", "estimated_time", "nozzle_diameter",
    "layer_height", "first_layer_height", "first_layer_extr_temp", "first_layer_bed_temp",
    "chamber_temp", "filament_name", "filament_type", "filament_total", "printer_model",
)  # fmt: skip

SYSTEM_PROMPT: Final = (
    "You review one action that an operator of a 3D-printer farm is about to send to a "
    "Klipper printer through Moonraker. KyberCore's rules have already checked the "
    "connection, the printer state, the build volume, nozzle size, filament type and "
    "temperature limits. You may only ADD warnings about real risks those rules could miss, "
    "for example an unusual G-code script or file settings that look wrong for the material. "
    "You cannot allow or block anything. Answer with JSON only, exactly in this form: "
    '{"warnings": [{"en": "<one English sentence saying what to check>", '
    '"es": "<the same sentence in Spanish>"}]}. '
    'Answer {"warnings": []} when nothing deserves a warning. At most '
    f"{MAX_WARNINGS} warnings."
)


@dataclass(frozen=True)
class AdvisorConfig:
    """Where the advisor lives. ``url`` is the service's base URL (``/v1`` or the full
    ``/v1/chat/completions`` path may be included)."""

    url: str
    api_key: SecretStr | None = None
    model: str = "gpt-4o-mini"
    budget_seconds: float = 1.5


def chat_completions_url(url: str) -> str:
    """The chat-completions endpoint for a configured base URL."""
    base = url.rstrip("/")
    if base.endswith("/chat/completions"):
        return base
    if base.endswith("/v1"):
        return base + "/chat/completions"
    return base + "/v1/chat/completions"


def build_request(
    cfg: AdvisorConfig,
    action: str,
    printer: PrinterFacts,
    params: Mapping[str, Any] | None,
    file_meta: Mapping[str, Any] | None,
) -> dict[str, Any]:
    """The JSON body sent to the advisor: the system prompt and the facts, compactly."""
    facts: dict[str, Any] = {"action": action, "printer": asdict(printer)}
    if params:
        facts["params"] = {k: _trim(v) for k, v in params.items()}
    if file_meta is not None:
        facts["file"] = {k: file_meta[k] for k in _FILE_FIELDS if file_meta.get(k) is not None}
    return {
        "model": cfg.model,
        "temperature": 0,
        "max_tokens": 400,
        "messages": [
            {"role": "system", "content": SYSTEM_PROMPT},
            {"role": "user", "content": json.dumps(facts, separators=(",", ":"), default=str)},
        ],
    }


async def advise(
    http: httpx.AsyncClient,
    cfg: AdvisorConfig | None,
    action: str,
    printer: PrinterFacts,
    params: Mapping[str, Any] | None,
    file_meta: Mapping[str, Any] | None,
) -> tuple[Reason, ...]:
    """Ask the advisor about ``action``; its warnings, or one ``advisor_unavailable``.

    Returns ``()`` when no advisor is configured or the action is not one it reviews.
    Never raises for the advisor's failures and never takes longer than the budget.
    """
    if cfg is None or action not in ADVISED_ACTIONS:
        return ()
    url = chat_completions_url(cfg.url)
    where = _loggable(url)
    headers = {"Authorization": f"Bearer {cfg.api_key.get_secret_value()}"} if cfg.api_key else {}
    body = build_request(cfg, action, printer, params, file_meta)
    try:
        async with asyncio.timeout(cfg.budget_seconds):
            response = await http.post(url, json=body, headers=headers)
    except TimeoutError:
        seconds = f"{cfg.budget_seconds:g}"
        log.warning("Advisor %s gave no answer within %s s; rules alone apply", where, seconds)
        why_es = f"no respondió en {seconds.replace('.', ',')} s"
        return (_unavailable(f"did not answer within {seconds} s", why_es),)
    except (httpx.HTTPError, httpx.InvalidURL) as exc:
        name = type(exc).__name__
        log.warning("Advisor %s could not be reached (%s); rules alone apply", where, name)
        return (_unavailable("could not be reached", "no estaba disponible"),)
    if response.status_code != httpx.codes.OK:
        status = response.status_code
        log.warning("Advisor %s answered HTTP %s; rules alone apply", where, status)
        return (
            _unavailable(f"answered with HTTP {status}", f"respondió con un error HTTP {status}"),
        )
    warnings = parse_answer(response.content)
    if warnings is None:
        log.warning("Advisor %s answered something unreadable; ignored", where)
        return (_unavailable("gave an unreadable answer", "dio una respuesta ilegible"),)
    return tuple(
        Reason("advisor_warning", "warn", "advisor", f"Advisor: {en}", f"Asesor: {es}")
        for en, es in warnings
    )


def parse_answer(raw: bytes | str) -> list[tuple[str, str]] | None:
    """The ``(en, es)`` warnings in a chat-completions response, or None when unreadable.

    Accepts the JSON object alone or wrapped in a Markdown code fence, as models often do.
    Items that are not two non-empty strings are skipped; texts are cut to ``MAX_TEXT``.
    """
    try:
        content = json.loads(raw)["choices"][0]["message"]["content"]
        fenced = re.fullmatch(r"\s*```(?:json)?\s*(.*?)\s*```\s*", content, re.DOTALL)
        answer = json.loads(fenced.group(1) if fenced else content)
        items = answer["warnings"]
    except (ValueError, KeyError, IndexError, TypeError):
        return None
    if not isinstance(items, list):
        return None
    found: list[tuple[str, str]] = []
    for item in items:
        en, es = (item.get("en"), item.get("es")) if isinstance(item, dict) else (None, None)
        if isinstance(en, str) and isinstance(es, str) and en.strip() and es.strip():
            found.append((en.strip()[:MAX_TEXT], es.strip()[:MAX_TEXT]))
        else:
            log.warning("Advisor warning without both 'en' and 'es' texts; skipped")
    return found[:MAX_WARNINGS]


def combine(verdict: Verdict, advisor_reasons: tuple[Reason, ...]) -> Verdict:
    """The rules' verdict plus the advisor's reasons, which can raise it to ``warn`` at most:
    a block stays a block, and nothing the advisor says becomes one."""
    extra = [
        replace(r, level="warn" if r.level == "block" else r.level, category="advisor")
        for r in advisor_reasons
    ]
    return Verdict.of([*verdict.reasons, *extra])


def _unavailable(why_en: str, why_es: str) -> Reason:
    return Reason(
        "advisor_unavailable",
        "warn",
        "advisor",
        f"The advisor {why_en}, so only KyberCore's rules were applied. Confirm to go on "
        "without its review.",
        f"El asesor {why_es}, así que solo se han aplicado las reglas de KyberCore. Confirme "
        "para continuar sin su revisión.",
    )


def _loggable(url: str) -> str:
    """``url`` without user:password or query, which may carry credentials."""
    try:
        return str(httpx.URL(url).copy_with(userinfo=b"", query=None))
    except (httpx.InvalidURL, TypeError):
        return "<invalid advisor URL>"


def _trim(value: Any) -> Any:
    # Long scripts would cost the advisor time we do not have; the head says enough.
    if isinstance(value, str) and len(value) > _MAX_SCRIPT_CHARS:
        return value[:_MAX_SCRIPT_CHARS] + "\n; [...truncated by KyberCore]"
    return value
