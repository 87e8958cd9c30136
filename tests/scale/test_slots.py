"""Slots: the same printer lands in the same slot in every process; fair shares."""

from __future__ import annotations

import subprocess
import sys

from kybercore.scale.slots import SlotRef, fair_share, slot_key, slot_of
from kybercore.scale.wire import patch_subject, slot_of_subject, snapshot_subject


def test_a_printers_slot_is_the_same_in_another_process() -> None:
    # Python's str hash is salted per process; crc32 is not.
    here = [slot_of(f"printer-{i}", 64) for i in range(20)]
    there = subprocess.run(
        [sys.executable, "-c",
         "from kybercore.scale.slots import slot_of;"
         "print([slot_of(f'printer-{i}', 64) for i in range(20)])"],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    assert str(here) == there.strip()
    assert slot_of("voron-1", 16) == 5  # zlib.crc32(b"voron-1") = 949776357


def test_fair_share_rounds_up_so_every_slot_has_an_owner() -> None:
    assert [fair_share(64, n) for n in (0, 1, 2, 3, 64, 100)] == [64, 64, 32, 22, 1, 1]
    assert fair_share(16, 3) * 3 >= 16
    assert slot_key(7) == "s7"


def test_a_sites_slots_have_keys_and_subjects_of_their_own() -> None:
    assert (slot_key(7), slot_key(7, "lab-b")) == ("s7", "lab-b.s7")
    assert (patch_subject(3), patch_subject(3, "lab-b")) == ("kc.s._.3.patch", "kc.s.lab-b.3.patch")
    assert snapshot_subject(3, "lab-b") == "kc.s.lab-b.3.snap"
    assert slot_of_subject("kc.s._.3.patch") == SlotRef("", 3)
    assert slot_of_subject("kc.s.lab-b.63.patch") == SlotRef("lab-b", 63)
    assert patch_subject("*", "*") == "kc.s.*.*.patch"  # what a front follows
