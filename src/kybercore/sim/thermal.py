"""First-order heater model and the ADC reading of a "Generic 3950" thermistor.

Temperature follows ``dT/dt = heat_rate * duty - loss_rate * (T - ambient)``, solved exactly
between duty changes, so any speed-up factor stays stable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

KELVIN: Final = 273.15
# Klipper's "Generic 3950": 100 kOhm at 25 C, beta 3950, read through a 4.7 kOhm pull-up.
THERMISTOR_R25: Final = 100_000.0
THERMISTOR_BETA: Final = 3950.0
PULLUP_OHMS: Final = 4700.0


@dataclass(frozen=True)
class ThermalProfile:
    """Heating at full power (C/s) and heat loss (1/s, times the degrees above ambient)."""

    heat_rate: float
    loss_rate: float

    def scaled(self, heat_factor: float, cool_factor: float) -> ThermalProfile:
        """The same heater with its heating and cooling sped up by the given factors."""
        return ThermalProfile(self.heat_rate * heat_factor, self.loss_rate * cool_factor)


# Chosen so that from 25 C a hotend reaches 200 C in about 29 s and a bed 60 C in about 27 s,
# with peaks (ambient + heat/loss) far enough above max_temp that full power always gains.
HOTEND: Final = ThermalProfile(heat_rate=8.0, loss_rate=0.02)
BED: Final = ThermalProfile(heat_rate=1.5, loss_rate=0.01)


class HeaterModel:
    """One heater and the block it warms; time is in seconds on any monotonic base."""

    def __init__(self, profile: ThermalProfile, ambient: float, now: float) -> None:
        if profile.heat_rate < 0 or profile.loss_rate <= 0:
            raise ValueError("heat_rate must be >= 0 and loss_rate > 0")
        self.profile = profile
        self.ambient = ambient
        self._temp = ambient
        self._duty = 0.0
        self._time = now

    @property
    def duty(self) -> float:
        """Current heater power, 0..1."""
        return self._duty

    def set_duty(self, duty: float, at: float) -> None:
        """Switch the heater to `duty` (clamped to 0..1) from time `at` on."""
        self.advance(at)
        self._duty = min(1.0, max(0.0, duty))

    def temperature(self, at: float) -> float:
        """Temperature at time `at`."""
        self.advance(at)
        return self._temp

    def advance(self, at: float) -> None:
        """Integrate up to `at`; earlier times are ignored (the model never runs backwards)."""
        elapsed = at - self._time
        if elapsed <= 0:
            return
        loss = self.profile.loss_rate
        settle = self.ambient + self.profile.heat_rate * self._duty / loss
        self._temp = settle + (self._temp - settle) * math.exp(-loss * elapsed)
        self._time = at


def thermistor_fraction(temp_c: float) -> float:
    """ADC reading (0..1 of full scale) of a Generic 3950 thermistor at `temp_c`."""
    temp_k = max(temp_c + KELVIN, 1.0)
    resistance = THERMISTOR_R25 * math.exp(THERMISTOR_BETA * (1.0 / temp_k - 1.0 / (25.0 + KELVIN)))
    return resistance / (resistance + PULLUP_OHMS)


def adc_sum(temp_c: float, adc_max: int, sample_count: int) -> int:
    """What the MCU reports for `sample_count` summed samples, as Klipper's analog_in does."""
    return round(thermistor_fraction(temp_c) * adc_max) * sample_count
