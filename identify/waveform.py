"""Trapezoidal piston waveform of a squeeze-mode printhead (Wang & Chiu, Eq. 1 and Eq. 9).

Units follow the printhead's user interface: stroke velocity ``u1`` and instroke velocity
``u3`` in µm/ms, stroke ``u2`` in µm, hold time ``tH`` in µs; time in µs from the start
of the waveform. The firing trigger precedes the waveform by a dead time (220 µs in the
paper, Fig. 6), which callers add as ``t_us - dead_time_us``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Factory preset instroke velocity (µm/ms), Section 4.2.
U3_PRESET_UM_PER_MS = 2.0
#: Factory preset stroke hold time (µs), Section 4.2.
HOLD_PRESET_US = 20.0
#: Delay between the firing trigger and the piston motion seen in the data (µs), Fig. 6.
DEAD_TIME_US = 220.0
#: Strobe interval of the paper's data (µs), Section 4.2.
SAMPLE_INTERVAL_US = 10.0


@dataclass(frozen=True)
class Waveform:
    """Trapezoidal piston waveform, Eq. (1).

    Parameters
    ----------
    u1_um_per_ms : float
        Stroke velocity (µm/ms), > 0.
    u2_um : float
        Stroke (µm), > 0.
    u3_um_per_ms : float
        Instroke (retraction) velocity (µm/ms), > 0. Preset 2 µm/ms.
    hold_us : float
        Stroke holding time tH (µs), >= 0. Preset 20 µs.
    """

    u1_um_per_ms: float
    u2_um: float
    u3_um_per_ms: float = U3_PRESET_UM_PER_MS
    hold_us: float = HOLD_PRESET_US

    def __post_init__(self) -> None:
        for name in ("u1_um_per_ms", "u2_um", "u3_um_per_ms"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"waveform {name} must be a positive number, got {value!r}")
        if not np.isfinite(self.hold_us) or self.hold_us < 0:
            raise ValueError(f"waveform hold_us must be >= 0, got {self.hold_us!r}")

    @property
    def rise_us(self) -> float:
        """Duration of the stroke ramp u2/u1 (µs); the instant of maximum stroke."""
        return 1000.0 * self.u2_um / self.u1_um_per_ms

    @property
    def max_stroke_us(self) -> float:
        """Instant at which the piston reaches its maximum stroke (µs), = rise_us."""
        return self.rise_us

    @property
    def retract_start_us(self) -> float:
        """Instant at which the instroke (retraction) starts (µs)."""
        return self.rise_us + self.hold_us

    @property
    def end_us(self) -> float:
        """Instant at which the piston is back at zero (µs)."""
        return self.retract_start_us + 1000.0 * self.u2_um / self.u3_um_per_ms

    def displacement_um(self, t_us) -> np.ndarray:
        """Piston displacement u(t) of Eq. (1) in µm; zero before 0 and after the cycle."""
        t = np.asarray(t_us, dtype=float)
        u1 = self.u1_um_per_ms * 1e-3  # µm/µs
        u3 = self.u3_um_per_ms * 1e-3
        out = np.where(
            t <= self.rise_us,
            u1 * t,
            np.where(
                t <= self.retract_start_us,
                self.u2_um,
                self.u2_um - u3 * (t - self.retract_start_us),
            ),
        )
        out = np.where((t < 0) | (t > self.end_us), 0.0, out)
        return out

    def sampled_um(self, kp: int, ts_us: float = SAMPLE_INTERVAL_US) -> np.ndarray:
        """Sampled, truncated waveform of Eq. (9): u_p(k) for k = 0..kp (inclusive).

        Eq. (9) is Eq. (1) evaluated at t = k ts up to the pinch-off instant ``kp``;
        beyond kp the waveform is "not applicable" and is not returned.
        """
        if kp < 0:
            raise ValueError(f"pinch-off instant kp must be >= 0, got {kp}")
        k = np.arange(int(kp) + 1)
        return self.displacement_um(k * ts_us)
