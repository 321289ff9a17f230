"""Trapezoidal piston waveform of a squeeze-mode printhead (Wang & Chiu, Eq. 1 and Eq. 9), and
waveform templates: any printhead's drive as a piecewise-linear function of time in the lab's own
named parameters (:class:`WaveformTemplate`, :data:`TEMPLATES`: the trapezoid, a three-pulse
dispenser; :class:`Drive`, :func:`drive_from_document` for sequence.json's ``waveform``).

Units follow the printhead's user interface: stroke velocity ``u1`` and instroke velocity
``u3`` in µm/ms, stroke ``u2`` in µm, hold time ``tH`` in µs; time in µs from the start
of the waveform. The firing trigger precedes the waveform by a dead time (220 µs in the
paper, Fig. 6), which callers add as ``t_us - dead_time_us``.

Also the nozzle's flow formulas (:func:`nozzle_area_m2`, :func:`flow_velocity_m_s`). This is the
drive and flow vocabulary both packages stand on (issue 34): the measurement layer reads a
sequence's drive (sequence.json ``waveform``), its dead time and the nozzle's flow velocity from
here, without importing the modelling layer; :mod:`identify.waveform` and :mod:`identify.ecm`
re-export these names.
"""

from __future__ import annotations

from collections.abc import Mapping
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
#: 1 µm in m.
UM = 1e-6


def nozzle_area_m2(nozzle_inner_diameter_um: float) -> float:
    """Inner cross-section of the nozzle, π d^2 / 4.

    Parameters
    ----------
    nozzle_inner_diameter_um : float
        Nozzle inner diameter d (µm).

    Returns
    -------
    float
        Cross-section area (m^2).
    """
    return float(np.pi * (nozzle_inner_diameter_um * UM) ** 2 / 4.0)


def flow_velocity_m_s(flow_nl_per_us, nozzle_inner_diameter_um: float) -> np.ndarray:
    """Average flow velocity in the nozzle, flow / (π d^2 / 4).

    Parameters
    ----------
    flow_nl_per_us : array_like
        Volume flow (nl/µs; 1 nl/µs = 1e-6 m^3/s).
    nozzle_inner_diameter_um : float
        Nozzle inner diameter d (µm), see :func:`nozzle_area_m2`.

    Returns
    -------
    ndarray
        Average flow velocity (m/s), same shape as ``flow_nl_per_us``.
    """
    return np.asarray(flow_nl_per_us, dtype=float) * 1e-6 / nozzle_area_m2(nozzle_inner_diameter_um)


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


# --------------------------------------------------------------------------- templates
#
# A waveform template is the drive of a printhead as a piecewise-linear function of time written
# in the lab's own named parameters (issue 31). The paper's trapezoid (Eq. 1) is one template,
# with parameters u1_um_per_ms and u2_um (u3 and the hold time are its constants); the three-pulse
# drive of a MicroDrop-style dispenser (pulse amplitudes V1 V2 V3 in V, widths w1 w2 w3 and delays
# d1 d2 in µs) is another. The equivalent circuit takes the drive as its input u(t): the paper's
# piston displacement in µm, or a piezo voltage, whose unit the template states (`drive_unit`);
# the compliance ratio Kc of Eq. (5) then converts that unit into pressure (for a voltage drive it
# absorbs the piezo's displacement per volt: the ECM reads 1 V as 1 µm of equivalent stroke).


@dataclass(frozen=True)
class WaveformParameter:
    """One named waveform parameter in the user's unit.

    ``low``/``high``: accepted range (inclusive); ``positive``: the value must be > low.
    """

    name: str
    unit: str
    meaning: str
    low: float = -1e4
    high: float = 1e4
    positive: bool = False

    def check(self, value, where: str = "waveform") -> float:
        """The value as a float, or ValueError naming the parameter, its value and range."""
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ValueError(f"{where}: parameter {self.name} must be a number ({self.unit}), got {value!r}")
        v = float(value)
        if not np.isfinite(v) or v < self.low or v > self.high or (self.positive and v <= self.low):
            rng = f"> {self.low:g}" if self.positive else f">= {self.low:g}"
            raise ValueError(f"{where}: parameter {self.name} = {v!r} {self.unit} is outside the accepted range "
                             f"({rng} and <= {self.high:g} {self.unit})")
        return v


class WaveformTemplate:
    """A drive u(t) written as a piecewise-linear function of time in named parameters.

    Subclasses give ``name``, ``drive_unit``, ``parameters`` (a tuple of
    :class:`WaveformParameter`), :meth:`breakpoints` and :meth:`velocity_instant_us`, and their
    constants through :meth:`constants`. Time is in µs from the start of the drive (the firing
    trigger precedes it by the dead time, which callers add).
    """

    name: str = ""
    drive_unit: str = ""

    parameters: tuple = ()

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    def units(self) -> dict[str, str]:
        """Parameter name -> unit."""
        return {p.name: p.unit for p in self.parameters}

    def constants(self) -> dict:
        """The template's fixed constants (JSON-serialisable)."""
        return {}

    def check(self, values, where: str = "waveform") -> dict[str, float]:
        """Every declared parameter, checked, in declaration order; ValueError on a missing,
        unknown or out-of-range one."""
        if not isinstance(values, Mapping):
            raise ValueError(f"{where}: the {self.name} parameters must be an object name -> value")
        unknown = sorted(set(values) - set(self.parameter_names))
        if unknown:
            raise ValueError(f"{where}: unknown {self.name} parameter(s) {', '.join(map(str, unknown))} "
                             f"(declared: {', '.join(self.parameter_names)})")
        missing = [n for n in self.parameter_names if n not in values]
        if missing:
            raise ValueError(f"{where}: missing {self.name} parameter(s) {', '.join(missing)} "
                             f"(declared: {', '.join(self.parameter_names)})")
        out = {p.name: p.check(values[p.name], where) for p in self.parameters}
        self._check_shape(out, where)
        return out

    def _check_shape(self, values: dict, where: str) -> None:
        """Relations between parameters (subclasses)."""

    def breakpoints(self, values) -> tuple[np.ndarray, np.ndarray]:
        """Corners of the drive: times (µs from the start of the drive, non-decreasing, from 0)
        and levels (drive unit), first and last level 0; the drive is linear between them."""
        raise NotImplementedError

    def velocity_instant_us(self, values) -> float:
        """Instant (µs from the start of the drive) at which the hybrid model reads the ECM flow
        for the jetting velocity (the paper: the maximum stroke)."""
        raise NotImplementedError

    def end_us(self, values) -> float:
        """Instant at which the drive is back at rest (µs from its start)."""
        t, _ = self.breakpoints(values)
        return float(t[-1])

    def drive(self, values, t_us) -> np.ndarray:
        """The drive u(t) (``drive_unit``) at ``t_us`` (µs from its start); 0 outside the cycle."""
        t, level = self.breakpoints(values)
        x = np.asarray(t_us, dtype=float)
        return np.interp(x, t, level, left=0.0, right=0.0)

    def knots(self, values, dead_time_us: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Knot instants from the trigger (µs) and slope changes (drive unit per µs) of the drive,
        ``u(t) = sum_i c_i (t - t_i)_+``, for :func:`identify.ecm.pwl_response`."""
        t, level = _merge_corners(*self.breakpoints(values))
        slopes = np.diff(level) / np.diff(t)
        jumps = np.diff(np.concatenate([[0.0], slopes, [0.0]]))
        return dead_time_us + t, jumps

    def to_dict(self) -> dict:
        """``{"template": name, **constants}`` (inverse: :func:`template_from_dict`)."""
        return {"template": self.name, **self.constants()}

    def describe(self) -> str:
        """One line: the template and its parameters with their units."""
        return f"{self.name}: " + ", ".join(f"{p.name} ({p.unit})" for p in self.parameters)


def _merge_corners(t: np.ndarray, level: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Breakpoints without zero-length segments (equal times must carry equal levels: the drive
    is continuous)."""
    t = np.asarray(t, float)
    level = np.asarray(level, float)
    keep = np.ones(t.size, bool)
    same = np.diff(t) == 0
    if np.any(same & (np.diff(level) != 0)):
        raise ValueError("a waveform template's drive must be continuous (a step needs a ramp)")
    keep[1:] = ~same
    return t[keep], level[keep]


@dataclass(frozen=True)
class TrapezoidTemplate(WaveformTemplate):
    """The paper's trapezoidal piston stroke, Eq. (1): parameters ``u1_um_per_ms`` (stroke
    velocity) and ``u2_um`` (stroke); constants ``u3_um_per_ms`` and ``hold_us``. Its drive is
    :meth:`Waveform.displacement_um`, bit for bit."""

    u3_um_per_ms: float = U3_PRESET_UM_PER_MS
    hold_us: float = HOLD_PRESET_US

    name = "trapezoid"
    drive_unit = "um"
    parameters = (
        WaveformParameter("u1_um_per_ms", "um/ms", "stroke velocity u1", 0.0, 1e4, positive=True),
        WaveformParameter("u2_um", "um", "stroke u2", 0.0, 1e4, positive=True),
    )

    def __post_init__(self) -> None:
        Waveform(1.0, 1.0, self.u3_um_per_ms, self.hold_us)  # validates the constants

    def constants(self) -> dict:
        return {"u3_um_per_ms": float(self.u3_um_per_ms), "hold_us": float(self.hold_us)}

    def waveform(self, values) -> Waveform:
        v = values if isinstance(values, dict) and set(values) == set(self.parameter_names) else self.check(values)
        return Waveform(float(v["u1_um_per_ms"]), float(v["u2_um"]), self.u3_um_per_ms, self.hold_us)

    def breakpoints(self, values):
        w = self.waveform(values)
        return (np.array([0.0, w.rise_us, w.retract_start_us, w.end_us]),
                np.array([0.0, w.u2_um, w.u2_um, 0.0]))

    def drive(self, values, t_us) -> np.ndarray:
        return self.waveform(values).displacement_um(t_us)

    def knots(self, values, dead_time_us: float = 0.0):
        # the arithmetic of identify.ecm.waveform_knots (bit for bit)
        w = self.waveform(values)
        u1, u3 = w.u1_um_per_ms * 1e-3, w.u3_um_per_ms * 1e-3
        knots = dead_time_us + np.array([0.0, w.rise_us, w.retract_start_us, w.end_us])
        return knots, np.array([u1, -u1, -u3, u3])

    def velocity_instant_us(self, values) -> float:
        return self.waveform(values).max_stroke_us

    def end_us(self, values) -> float:
        return self.waveform(values).end_us


#: Rise and fall time of each pulse of the three-pulse template (µs): its constant ``edge_us``.
EDGE_PRESET_US = 2.0


@dataclass(frozen=True)
class ThreePulseTemplate(WaveformTemplate):
    """Three trapezoidal voltage pulses of a MicroDrop-style dispenser.

    Parameters ``V1 V2 V3`` (pulse amplitudes, V, any sign), ``w1 w2 w3`` (pulse widths, µs: the
    full width at half amplitude, >= ``edge_us``) and ``d1 d2`` (delays, µs >= 0: from the end of
    one pulse's fall to the start of the next one's rise). Pulse i starts at s_i (s_1 = 0,
    s_2 = s_1 + w1 + edge + d1, s_3 = s_2 + w2 + edge + d2), rises linearly to V_i in ``edge_us``,
    holds until s_i + w_i and falls back to 0 at s_i + w_i + edge.

    The jetting velocity is read from the ECM flow at the end of the first pulse's plateau
    (s_1 + w1: the end of the main push, as the paper reads it at the maximum stroke).
    """

    edge_us: float = EDGE_PRESET_US

    name = "three_pulse"
    drive_unit = "V"
    parameters = (
        WaveformParameter("V1", "V", "amplitude of pulse 1"),
        WaveformParameter("V2", "V", "amplitude of pulse 2"),
        WaveformParameter("V3", "V", "amplitude of pulse 3"),
        WaveformParameter("w1", "us", "width of pulse 1 (full width at half amplitude)", 0.0, 1e6),
        WaveformParameter("w2", "us", "width of pulse 2 (full width at half amplitude)", 0.0, 1e6),
        WaveformParameter("w3", "us", "width of pulse 3 (full width at half amplitude)", 0.0, 1e6),
        WaveformParameter("d1", "us", "delay from the end of pulse 1 to the start of pulse 2", 0.0, 1e6),
        WaveformParameter("d2", "us", "delay from the end of pulse 2 to the start of pulse 3", 0.0, 1e6),
    )

    def __post_init__(self) -> None:
        if isinstance(self.edge_us, bool) or not (np.isfinite(self.edge_us) and 0 < self.edge_us <= 1e4):
            raise ValueError(f"three_pulse edge_us must be a number in (0, 1e4] us, got {self.edge_us!r}")

    def constants(self) -> dict:
        return {"edge_us": float(self.edge_us)}

    def _check_shape(self, values: dict, where: str) -> None:
        for w in ("w1", "w2", "w3"):
            if values[w] < self.edge_us:
                raise ValueError(f"{where}: three_pulse {w} = {values[w]:g} us is shorter than the pulse edge "
                                 f"edge_us = {self.edge_us:g} us (a pulse needs w >= edge)")

    def starts_us(self, values) -> tuple[float, float, float]:
        """Start instants of the three pulses (µs from the start of the drive)."""
        v, e = values, self.edge_us
        s2 = v["w1"] + e + v["d1"]
        return 0.0, s2, s2 + v["w2"] + e + v["d2"]

    def breakpoints(self, values):
        v = self.check(values)
        e = self.edge_us
        t, level = [], []
        for s, amp, w in zip(self.starts_us(v), (v["V1"], v["V2"], v["V3"]), (v["w1"], v["w2"], v["w3"])):
            t += [s, s + e, s + w, s + w + e]
            level += [0.0, amp, amp, 0.0]
        return _merge_corners(np.array(t), np.array(level))

    def velocity_instant_us(self, values) -> float:
        return float(self.check(values)["w1"])


class SegmentsTemplate(WaveformTemplate):
    """A drive of straight segments declared by the lab itself (a Dimatix-style multi-segment
    voltage waveform, or any other), with its own named parameters.

    Parameters
    ----------
    declare : dict
        Parameter name -> unit, in order: ``"us"`` for a duration, the drive's ``unit`` for a level.
    segments : list of [duration, level]
        From rest (level 0 at t = 0), each segment ramps linearly to its level over its duration
        (µs); the last level must be 0. Each entry is a number, a declared parameter's name, or
        ``"-name"`` (its negative). A duration must be a number >= 0 or a parameter in us, a level
        a number or a parameter in ``unit``.
    unit : str
        Unit of the drive (default "V").
    velocity_segment : int or None
        The jetting velocity is read at the end of this segment (0-based); None: the first segment
        that ends at the largest |level| (for a trapezoid: the maximum stroke).
    """

    name = "segments"

    def __init__(self, declare=None, segments=None, unit: str = "V", velocity_segment: int | None = None):
        declare = {"V": "V", "t": "us"} if declare is None else declare
        segments = [["t", "V"], ["t", 0.0]] if segments is None else segments
        if not isinstance(declare, Mapping) or not declare:
            raise ValueError("segments template: 'declare' must be an object parameter name -> unit")
        if not isinstance(unit, str) or not unit:
            raise ValueError("segments template: 'unit' must be a non-empty string")
        params = []
        for n, u in declare.items():
            if not isinstance(n, str) or not n.isidentifier() or not isinstance(u, str):
                raise ValueError(f"segments template: declared parameter {n!r}: {u!r} must be a name -> a unit")
            if u not in ("us", unit):
                raise ValueError(f"segments template: parameter {n} has unit {u!r}: a duration is in us, a level in "
                                 f"the drive's unit {unit!r}")
            lo = 0.0 if u == "us" else -1e4
            params.append(WaveformParameter(n, u, "duration" if u == "us" else "level", lo, 1e6 if u == "us" else 1e4))
        if not isinstance(segments, (list, tuple)) or not segments:
            raise ValueError("segments template: 'segments' must be a list of [duration, level]")
        segs = []
        for i, seg in enumerate(segments):
            if not isinstance(seg, (list, tuple)) or len(seg) != 2:
                raise ValueError(f"segments template: segment {i} must be [duration, level], got {seg!r}")
            segs.append((self._term(seg[0], declare, "us", f"segment {i} duration"),
                         self._term(seg[1], declare, unit, f"segment {i} level")))
        if segs[-1][1] != 0.0:
            raise ValueError("segments template: the last segment must end at level 0 (the drive back at rest)")
        if velocity_segment is not None and (isinstance(velocity_segment, bool) or int(velocity_segment) != velocity_segment
                                             or not 0 <= int(velocity_segment) < len(segs)):
            raise ValueError(f"segments template: velocity_segment must be a segment index 0..{len(segs) - 1}")
        self.declare = dict(declare)
        self.segments = [list(seg) for seg in segments]
        self.unit = unit
        self.drive_unit = unit
        self.velocity_segment = None if velocity_segment is None else int(velocity_segment)
        self.parameters = tuple(params)
        self._segs = segs

    @staticmethod
    def _term(x, declare, unit, what):
        """A number, or (sign, name) of a declared parameter of ``unit``."""
        if isinstance(x, str):
            sign, name = (-1.0, x[1:]) if x.startswith("-") else (1.0, x)
            if name not in declare:
                raise ValueError(f"segments template: {what} names {name!r}, which is not declared")
            if declare[name] != unit:
                raise ValueError(f"segments template: {what} is in {unit}, but {name} is declared in {declare[name]}")
            if unit == "us" and sign < 0:
                raise ValueError(f"segments template: {what} cannot be a negative duration")
            return (sign, name)
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not np.isfinite(x):
            raise ValueError(f"segments template: {what} must be a number or a declared parameter, got {x!r}")
        if unit == "us" and x < 0:
            raise ValueError(f"segments template: {what} must be >= 0, got {x!r}")
        return float(x)

    def __eq__(self, other) -> bool:
        return isinstance(other, SegmentsTemplate) and self.constants() == other.constants()

    __hash__ = None

    def __repr__(self) -> str:
        return f"SegmentsTemplate({self.constants()!r})"

    def constants(self) -> dict:
        return {"declare": dict(self.declare), "segments": [list(s) for s in self.segments], "unit": self.unit,
                "velocity_segment": self.velocity_segment}

    @classmethod
    def from_constants(cls, consts: Mapping) -> "SegmentsTemplate":
        bad = sorted(set(consts) - {"declare", "segments", "unit", "velocity_segment"})
        if bad:
            raise ValueError(f"waveform template segments: unknown constant(s) {', '.join(bad)} "
                             "(known: declare, segments, unit, velocity_segment)")
        if "declare" not in consts or "segments" not in consts:
            raise ValueError("waveform template segments needs 'declare' (name -> unit) and 'segments'")
        return cls(consts["declare"], consts["segments"], consts.get("unit", "V"), consts.get("velocity_segment"))

    def breakpoints(self, values):
        v = self.check(values)

        def val(term):
            return term if isinstance(term, float) else term[0] * v[term[1]]

        t, level = [0.0], [0.0]
        for dur, lev in self._segs:
            d = val(dur)
            if d == 0 and val(lev) != level[-1]:
                raise ValueError(f"segments template: a segment of zero duration must keep the level "
                                 f"(a step needs a ramp), at t = {t[-1]:g} us")
            t.append(t[-1] + d)
            level.append(val(lev))
        return _merge_corners(np.array(t), np.array(level))

    def velocity_instant_us(self, values) -> float:
        v = self.check(values)
        ends = np.cumsum([dur if isinstance(dur, float) else v[dur[1]] for dur, _ in self._segs])
        if self.velocity_segment is not None:
            return float(ends[self.velocity_segment])
        levels = np.abs([lev if isinstance(lev, float) else lev[0] * v[lev[1]] for _, lev in self._segs])
        return float(ends[int(np.argmax(levels))])


#: Templates by name (``template`` of sequence.json's ``waveform``, of model files).
TEMPLATES = {"trapezoid": TrapezoidTemplate, "three_pulse": ThreePulseTemplate, "segments": SegmentsTemplate}


def template_from_dict(d) -> WaveformTemplate:
    """A template from ``{"template": name, **constants}`` (:meth:`WaveformTemplate.to_dict`)."""
    if not isinstance(d, Mapping) or d.get("template") not in TEMPLATES:
        name = d.get("template") if isinstance(d, Mapping) else d
        raise ValueError(f"unknown waveform template {name!r} (known: {', '.join(TEMPLATES)})")
    cls = TEMPLATES[d["template"]]
    consts = {k: v for k, v in d.items() if k != "template"}
    if hasattr(cls, "from_constants"):
        return cls.from_constants(consts)
    allowed = set(cls().constants())
    bad = sorted(set(consts) - allowed)
    if bad:
        raise ValueError(f"waveform template {d['template']}: unknown constant(s) {', '.join(bad)} "
                         f"(known: {', '.join(sorted(allowed)) or 'none'})")
    for k, v in consts.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"waveform template {d['template']}: {k} must be a number, got {v!r}")
    return cls(**{k: float(v) for k, v in consts.items()})


@dataclass(frozen=True)
class Drive:
    """A template with its parameter values and the dead time: one firing's drive.

    ``values`` are checked by the template at construction.
    """

    template: WaveformTemplate
    values: Mapping
    dead_time_us: float = DEAD_TIME_US

    def __post_init__(self) -> None:
        object.__setattr__(self, "values", self.template.check(self.values))
        if not (np.isfinite(self.dead_time_us) and self.dead_time_us >= 0):
            raise ValueError(f"dead_time_us must be >= 0, got {self.dead_time_us!r}")

    def at(self, t_us) -> np.ndarray:
        """The drive at ``t_us`` µs after the firing trigger."""
        return self.template.drive(self.values, np.asarray(t_us, dtype=float) - self.dead_time_us)

    def knots(self) -> tuple[np.ndarray, np.ndarray]:
        """Knots from the trigger and slope changes, for :func:`identify.ecm.pwl_response`."""
        return self.template.knots(self.values, self.dead_time_us)

    @property
    def velocity_instant_us(self) -> float:
        """Instant after the trigger at which the jetting velocity is read (µs)."""
        return self.dead_time_us + self.template.velocity_instant_us(self.values)

    @property
    def end_us(self) -> float:
        """Instant after the trigger at which the drive is back at rest (µs)."""
        return self.dead_time_us + self.template.end_us(self.values)

    def to_dict(self) -> dict:
        """sequence.json's ``waveform`` object (template form; :func:`drive_from_document`)."""
        return {**self.template.to_dict(), "parameters": dict(self.values), "dead_time_us": float(self.dead_time_us)}


def drive_from_document(doc, where: str = "waveform") -> Drive:
    """The drive of a sequence.json ``waveform`` object: the template form ``{"template": name,
    "parameters": {name: value}, <constants>, "dead_time_us"}`` or the paper's flat form
    (``u1_um_per_ms``, ``u2_um``, optional ``u3_um_per_ms``, ``hold_us``, ``dead_time_us``: the
    trapezoid template). ValueError naming ``where`` on anything else."""
    if not isinstance(doc, Mapping):
        raise ValueError(f"{where}: 'waveform' must be an object")
    dead = doc.get("dead_time_us", DEAD_TIME_US)
    if isinstance(dead, bool) or not isinstance(dead, (int, float)) or not np.isfinite(dead) or dead < 0:
        raise ValueError(f"{where}: waveform dead_time_us must be a number >= 0, got {dead!r}")
    if "template" not in doc:
        tpl = TrapezoidTemplate(float(doc.get("u3_um_per_ms", U3_PRESET_UM_PER_MS)),
                                float(doc.get("hold_us", HOLD_PRESET_US)))
        values = {k: doc.get(k) for k in tpl.parameter_names}
        try:
            return Drive(tpl, values, float(dead))
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
    rest = {k: v for k, v in doc.items() if k not in ("parameters", "dead_time_us")}
    if "parameters" not in doc:
        raise ValueError(f"{where}: waveform template {doc['template']!r} needs 'parameters' (name -> value)")
    try:
        return Drive(template_from_dict(rest), doc["parameters"], float(dead))
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
