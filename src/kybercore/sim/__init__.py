"""Simulated printer hardware: a virtual Klipper MCU and the printer.cfg that matches it."""
