"""KyberCore: a fleet manager for Klipper 3D printers, through Moonraker.

The public surface, for scripts that use KyberCore as a library::

    from kybercore import FleetService, MoonrakerClient, PrinterRegistry, create_app
    from kybercore import KyberCoreError, PrinterUnreachable, ...   # the error tree

The errors are imported at once (they are small); the rest only when first used, so the
``kybercore`` command starts without FastAPI or the Moonraker client.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from kybercore import native

# First, before anything imports the modules a current compiled build stands in for.
native.install()

from kybercore.errors import (  # noqa: E402
    AccessDenied,
    ActionRejected,
    ConfigError,
    FileNotFound,
    InvalidInput,
    KlippyNotReady,
    KyberCoreError,
    LaunchError,
    MoonrakerRpcError,
    PrinterAuthFailed,
    PrinterError,
    PrinterTimeout,
    PrinterUnreachable,
    UnknownPrinter,
)

if TYPE_CHECKING:
    from kybercore.api.app import create_app
    from kybercore.fleet.service import FleetService
    from kybercore.moonraker.client import MoonrakerClient
    from kybercore.registry.models import PrinterConfig
    from kybercore.registry.store import PrinterRegistry

__version__ = "0.1.0"

_LAZY = {
    "create_app": "kybercore.api.app",
    "FleetService": "kybercore.fleet.service",
    "MoonrakerClient": "kybercore.moonraker.client",
    "PrinterConfig": "kybercore.registry.models",
    "PrinterRegistry": "kybercore.registry.store",
}

__all__ = [
    "AccessDenied",
    "ActionRejected",
    "ConfigError",
    "FileNotFound",
    "FleetService",
    "InvalidInput",
    "KlippyNotReady",
    "KyberCoreError",
    "LaunchError",
    "MoonrakerClient",
    "MoonrakerRpcError",
    "PrinterAuthFailed",
    "PrinterConfig",
    "PrinterError",
    "PrinterRegistry",
    "PrinterTimeout",
    "PrinterUnreachable",
    "UnknownPrinter",
    "__version__",
    "create_app",
]


def __getattr__(name: str) -> Any:
    """Import the heavier parts of the public surface when they are first used."""
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'kybercore' has no attribute {name!r}")
