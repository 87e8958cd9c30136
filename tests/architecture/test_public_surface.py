"""What ``import kybercore`` offers a script, and what it does not load."""

from __future__ import annotations

import subprocess
import sys

import kybercore


def test_every_public_name_resolves() -> None:
    for name in kybercore.__all__:
        assert getattr(kybercore, name) is not None, name


def test_importing_kybercore_loads_neither_fastapi_nor_the_moonraker_client() -> None:
    code = (
        "import sys, kybercore; "
        "print(sorted(m for m in ('fastapi', 'kybercore.moonraker.client', 'kybercore.sim')"
        " if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
