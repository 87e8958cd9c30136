"""The texts: every event reads as a sentence in English and Spanish, plurals right."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

import pytest

from kybercore.notify.models import EVENT_KINDS, EventKind, FleetEvent, PrinterRef
from kybercore.notify.texts import Language, display_file, listing, render

T0 = datetime(2026, 5, 1, 22, 0, tzinfo=UTC)
P7 = PrinterRef("printer-7", "printer-7", "Room B", ())
LANGUAGES: tuple[Language, ...] = ("en", "es")


def ev(kind: EventKind, who: PrinterRef | None = P7, **params: Any) -> FleetEvent:
    return FleetEvent(kind, T0, who, params)


def fold(n: int, **params: Any) -> dict[str, Any]:
    return {
        "count": n,
        "printers": [f"printer-{i}" for i in range(1, n + 1)],
        "names": [f"printer-{i}" for i in range(1, n + 1)],
        **params,
    }


# Every variant of every kind, as the detector, the filter and the queue make them.
EVENTS = [
    ev("print_started", filename="tower.gcode"),
    ev("print_completed", filename="kybercore/j12-c1-a34-tower.gcode"),
    ev("print_failed", filename="tower.gcode", message="Heater extruder not heating"),
    ev("print_cancelled", filename="tower.gcode"),
    ev("print_paused", filename="tower.gcode", reason="runout"),
    ev("print_paused", filename="tower.gcode", reason="unknown"),
    ev("first_layer_done", filename="tower.gcode", layer=2),
    ev("printer_offline", filename="tower.gcode", was="printing"),
    ev("printer_offline", filename="tower.gcode", was="paused"),
    ev("printer_offline", minutes=15),
    ev("printer_recovered", what="connection"),
    ev("printer_recovered", what="klippy"),
    ev("printer_recovered", None, **fold(12, what="connection", location="Room B")),
    ev("klippy_shutdown", message="MCU 'mcu' shutdown: Timer too close"),
    ev("klippy_error", message=""),
    ev("plate_waiting", minutes=31),
    ev("plate_waiting", None, **fold(3)),
    ev("job_blocked", None, job_id=4, job_name="Brackets", minutes=11, reason="3 failures."),
    ev("storm_offline", None, **fold(12, location="Room B")),
    ev("storm_offline", None, **fold(4, location=None)),
    ev("printer_unreported", seconds=31),
    ev("printer_unreported", None, **fold(3)),
    ev("printer_recovered", what="worker"),
    ev("printer_recovered", None, **fold(3, what="worker")),
    ev("test", None),
]


def test_every_kind_has_a_text() -> None:
    assert {event.kind for event in EVENTS} == set(EVENT_KINDS)


@pytest.mark.parametrize("event", EVENTS, ids=lambda e: f"{e.kind}-{sorted(e.params)}")
@pytest.mark.parametrize("language", LANGUAGES)
def test_every_event_reads_as_a_headline_and_a_sentence(
    event: FleetEvent, language: Language
) -> None:
    title, body = render(event, language)
    for text in (title, body):
        assert text.strip() == text
        assert "{" not in text
        assert "}" not in text
        assert "None" not in text
        assert "?" not in text
        assert ".." not in text
        assert "  " not in text
    assert 0 < len(title) <= 60
    assert not title.endswith(".")
    assert body.endswith(".")
    other = render(event, "en" if language == "es" else "es")
    assert other != (title, body)


@pytest.mark.parametrize(
    ("event", "en", "es"),
    [
        (
            ev("printer_offline", filename="tower.gcode", was="printing"),
            ("printer-7 went offline while printing", "while it was printing tower.gcode"),
            ("printer-7 se desconectó mientras imprimía", "mientras imprimía tower.gcode"),
        ),
        (
            ev("storm_offline", None, **fold(12, location="Room B")),
            ("Room B: 12 printers offline", "12 printers in Room B went offline together"),
            ("Room B: 12 impresoras sin conexión", "12 impresoras de Room B se desconectaron"),
        ),
        (
            ev("plate_waiting", None, **fold(3)),
            ("3 plates are waiting to be cleared", "printer-1, printer-2 and printer-3"),
            ("Hay 3 placas por despejar", "printer-1, printer-2 y printer-3"),
        ),
        (
            ev("plate_waiting", P7, minutes=31),
            ("plate waiting", "Clear the plate of printer-7 to let the queue continue"),
            ("placa por despejar", "Despeje la placa de printer-7 para que la cola continúe"),
        ),
        (
            ev("print_failed", filename="a.gcode", message="Heater extruder not heating."),
            ("printer-7: print failed", "with an error: Heater extruder not heating. Check"),
            ("printer-7: la impresión falló", "por un error: Heater extruder not heating. Revise"),
        ),
        (
            ev("printer_unreported", seconds=31),
            ("printer-7: no KyberCore worker reports it", "Check that the `kybercore ingest`"),
            ("ningún worker de KyberCore informa de ella", "Compruebe que los workers"),
        ),
        (
            ev("printer_unreported", None, **fold(3)),
            ("3 printers: no KyberCore worker reports them", "printer-1, printer-2 and"),
            ("3 impresoras sin ningún worker de KyberCore", "printer-1, printer-2 y printer-3"),
        ),
        (
            ev("printer_recovered", None, **fold(3, what="worker")),
            ("3 printers reported again", "KyberCore workers report these printers again"),
            ("3 impresoras vuelven a tener un worker", "vuelven a informar de estas"),
        ),
        (
            ev("print_paused", filename="a.gcode", reason="runout"),
            ("filament ran out", "Load filament and resume the print."),
            ("se acabó el filamento", "Cargue filamento y reanude la impresión."),
        ),
    ],
)
def test_what_the_operator_reads(
    event: FleetEvent, en: tuple[str, str], es: tuple[str, str]
) -> None:
    expected: dict[Language, tuple[str, str]] = {"en": en, "es": es}
    for language, (title_part, body_part) in expected.items():
        title, body = render(event, language)
        assert title_part in title
        assert body_part in body


@pytest.mark.parametrize(
    ("minutes", "en", "es"),
    [(1, "for 1 minute.", "lleva 1 minuto sin"), (2, "for 2 minutes.", "lleva 2 minutos sin")],
)
def test_minutes_are_plural_when_they_are_many(minutes: int, en: str, es: str) -> None:
    event = ev("printer_offline", minutes=minutes)
    assert en in render(event, "en")[1]
    assert es in render(event, "es")[1]


def test_one_printer_and_one_plate_are_singular() -> None:
    storm = ev("storm_offline", None, **fold(1, location="Room B"))
    assert render(storm, "en")[0] == "Room B: 1 printer offline"
    assert render(storm, "es") == (
        "Room B: 1 impresora sin conexión",
        "1 impresora de Room B se desconectó a la vez: printer-1. Revise su alimentación y su red.",
    )
    plate = ev("plate_waiting", None, **fold(1))
    assert render(plate, "en")[0] == "1 plate is waiting to be cleared"
    assert render(plate, "es")[0] == "Hay 1 placa por despejar"


def test_a_long_list_of_names_is_counted() -> None:
    names = [f"p{i}" for i in range(12)]
    assert listing(names, "en") == "p0, p1, p2, p3, p4 and 7 more"
    assert listing(names, "es") == "p0, p1, p2, p3, p4 y 7 más"
    assert listing(names[:6], "en") == "p0, p1, p2, p3, p4 and p5"
    assert listing(["p0"], "es") == "p0"


@pytest.mark.parametrize(
    ("filename", "shown"),
    [
        ("tower.gcode", "tower.gcode"),
        ("parts/tower.gcode", "tower.gcode"),
        ("kybercore/j12-c1-a34-tower.gcode", "tower.gcode"),
        ("j12-c1-a34-tower.gcode", "j12-c1-a34-tower.gcode"),
        (None, ""),
    ],
)
def test_files_are_shown_as_people_know_them(filename: str | None, shown: str) -> None:
    assert display_file(filename) == shown


@pytest.mark.parametrize("kind", EVENT_KINDS)
@pytest.mark.parametrize("who", [P7, None])
def test_missing_details_never_break_a_text(kind: EventKind, who: PrinterRef | None) -> None:
    for language in LANGUAGES:
        title, body = render(ev(kind, who), language)
        assert title
        assert body
