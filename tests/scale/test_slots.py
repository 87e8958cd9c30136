"""Slots: the same printer lands in the same slot in every process; fair shares."""

from __future__ import annotations

import subprocess
import sys

from kybercore.scale.slots import fair_share, slot_key, slot_of


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
