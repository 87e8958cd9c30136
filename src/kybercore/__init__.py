"""KyberCore: a fleet manager for Klipper 3D printers, through Moonraker."""

__version__ = "0.1.0"
