"""Physics of the synthetic drop: waveform (Eq. 1) -> 3rd-order ECM (Eqs. 2-6) -> pinch-off
instant and adjusters (Eqs. 7-8).

Everything a synthetic sequence's ground truth depends on is computed here from a documented
set of physical parameters (:class:`SynthPhysics`) and the two control parameters (u1, u2):

* the ECM parameters follow from the nozzle geometry and the ink with Eq. (2), the compliance
  from a chosen meniscus resonance, and the piston parameters from fixed ratios (team notes);
* :func:`drop_history` simulates the grown volume and flow with :func:`identify.ecm.simulate`
  on a fine uniform grid (0.5 µs by default) and evaluates the pinch-off law and the two
  adjusters. Between grid points the grown volume is a cubic Hermite interpolant that uses the
  simulated flow as derivative (error far below 1e-6 nl for the default grid).

Times are µs after the firing trigger; the piston starts to move after the dead time.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.interpolate import CubicHermiteSpline

from identify.ecm import EcmParameters, flow_velocity_m_s, simulate
from identify.hydraulics import hydraulics_from_dimensions
from identify.waveform import DEAD_TIME_US, HOLD_PRESET_US, U3_PRESET_UM_PER_MS, Drive, Waveform

__all__ = ["SynthPhysics", "DropHistory", "drop_history", "LinearLaw", "TemplateLaws", "drive_history",
           "THREE_PULSE_LAWS", "THREE_PULSE_CENTRE", "trapezoid_laws", "DEFAULT_LAWS"]


@dataclass(frozen=True)
class SynthPhysics:
    """Physical parameters of the synthetic printhead, nozzle and ink (colour-ink-like).

    Ink and nozzle
    --------------
    density_kg_m3, viscosity_mpa_s, surface_tension_mn_m : float
        Ink properties (colour ink of Table 1).
    nozzle_inner_diameter_um, nozzle_outer_diameter_um : float
        Nozzle pipe diameters; the meniscus is pinned at the inner radius.
    nozzle_length_mm : float
        Length of the nozzle-side pipe (L_N, R_N of Eq. 2 with the inner radius).
    reservoir_channel_radius_um, reservoir_channel_length_mm : float
        Reservoir-side channel (L_R, R_R of Eq. 2).

    ECM lumped parameters
    ---------------------
    meniscus_resonance_hz : float
        C_N = 1 / ((2 π f)^2 (L_N + L_R)).
    piston_inertance_kg_m4 : float
        L_a.
    piston_loss_ratio_per_s : float
        R_a = ratio * L_a (the slow piston pole, rad/s).
    compliance_ratio_coefficient : float
        K_c = coefficient * L_a / (C_N L_R) (negative: a stroke pushes ink out).

    Waveform and data-driven laws (Eq. 7, linear in u1 [µm/ms] and u2 [µm])
    ------------------------------------------------------------------------
    u3_um_per_ms, hold_us, dead_time_us : float
        Factory presets of the waveform and the trigger-to-piston dead time.
    pinchoff_law_us : (c0, c_u1, c_u2)
        t_p = c0 + c_u1 (u1 - 70) + c_u2 (u2 - 25), µs after the trigger.
    volume_adjuster_nl : (p00, p10, p01)
        y_c^vol = p00 + p10 u1 + p01 u2 (nl), paper Eq. (16) form.
    velocity_adjuster_m_s : (p00, p10, p01)
        y_c^vel = p00 + p10 u1 + p01 u2 (m/s), paper Eq. (17) form.
    """

    ink_name: str = "synthetic colour ink"
    density_kg_m3: float = 993.0
    viscosity_mpa_s: float = 2.21
    surface_tension_mn_m: float = 28.72
    nozzle_inner_diameter_um: float = 200.0
    nozzle_outer_diameter_um: float = 360.0
    nozzle_length_mm: float = 5.0
    reservoir_channel_radius_um: float = 94.0
    reservoir_channel_length_mm: float = 20.0
    meniscus_resonance_hz: float = 800.0
    piston_inertance_kg_m4: float = 4e-13
    piston_loss_ratio_per_s: float = 3333.0
    compliance_ratio_coefficient: float = -6.8e-7
    u3_um_per_ms: float = U3_PRESET_UM_PER_MS
    hold_us: float = HOLD_PRESET_US
    dead_time_us: float = DEAD_TIME_US
    pinchoff_law_us: tuple[float, float, float] = (1050.0, -14.0, 10.2)
    volume_adjuster_nl: tuple[float, float, float] = (0.16, 0.014, 0.0037)
    velocity_adjuster_m_s: tuple[float, float, float] = (-0.155, 0.0025, 0.0008)

    def __post_init__(self) -> None:
        for name in ("density_kg_m3", "viscosity_mpa_s", "surface_tension_mn_m",
                     "nozzle_inner_diameter_um", "nozzle_outer_diameter_um", "nozzle_length_mm",
                     "reservoir_channel_radius_um", "reservoir_channel_length_mm",
                     "meniscus_resonance_hz", "piston_inertance_kg_m4", "piston_loss_ratio_per_s"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"SynthPhysics.{name} must be a positive number, got {value!r}")
        if self.nozzle_outer_diameter_um <= self.nozzle_inner_diameter_um:
            raise ValueError("SynthPhysics: nozzle_outer_diameter_um must exceed nozzle_inner_diameter_um")
        for name in ("pinchoff_law_us", "volume_adjuster_nl", "velocity_adjuster_m_s"):
            if len(getattr(self, name)) != 3:
                raise ValueError(f"SynthPhysics.{name} needs three coefficients")

    # -- derived quantities ---------------------------------------------------------------
    @property
    def nozzle_inner_radius_um(self) -> float:
        return 0.5 * self.nozzle_inner_diameter_um

    @property
    def nozzle_outer_radius_um(self) -> float:
        return 0.5 * self.nozzle_outer_diameter_um

    def ecm_parameters(self) -> EcmParameters:
        """ECM parameters (SI) from Eq. (2) and the resonance/piston ratios documented above.

        Returns
        -------
        EcmParameters
            La, LN, LR in kg/m^4; Ra, RN, RR in kg/(m^4 s); CN in m^4 s^2/kg; Kc in
            kg/(m^2 s^2). LN, RN, LR, RR from
            :func:`identify.hydraulics.hydraulics_from_dimensions`.
        """
        LN, RN, LR, RR = hydraulics_from_dimensions(
            self.density_kg_m3, self.viscosity_mpa_s, self.nozzle_inner_diameter_um,
            self.nozzle_length_mm, self.reservoir_channel_radius_um, self.reservoir_channel_length_mm,
        )
        CN = 1.0 / ((2 * np.pi * self.meniscus_resonance_hz) ** 2 * (LN + LR))
        La = self.piston_inertance_kg_m4
        return EcmParameters(La=La, Ra=self.piston_loss_ratio_per_s * La, CN=CN,
                             Kc=self.compliance_ratio_coefficient * La / (CN * LR),
                             LN=LN, RN=RN, LR=LR, RR=RR)

    def waveform(self, u1_um_per_ms: float, u2_um: float) -> Waveform:
        """The trapezoidal waveform of Eq. (1) with the preset u3 and hold time."""
        return Waveform(u1_um_per_ms, u2_um, self.u3_um_per_ms, self.hold_us)

    def pinchoff_instant_us(self, u1_um_per_ms: float, u2_um: float) -> float:
        """Continuous pinch-off instant (µs after the trigger) from the linear law."""
        c0, c1, c2 = self.pinchoff_law_us
        return float(c0 + c1 * (u1_um_per_ms - 70.0) + c2 * (u2_um - 25.0))

    def volume_adjuster_nl_at(self, u1_um_per_ms: float, u2_um: float) -> float:
        """Volume adjuster y_c^vol (nl)."""
        p00, p10, p01 = self.volume_adjuster_nl
        return float(p00 + p10 * u1_um_per_ms + p01 * u2_um)

    def velocity_adjuster_m_s_at(self, u1_um_per_ms: float, u2_um: float) -> float:
        """Velocity adjuster y_c^vel (m/s)."""
        p00, p10, p01 = self.velocity_adjuster_m_s
        return float(p00 + p10 * u1_um_per_ms + p01 * u2_um)

    def rayleigh_mode2(self, radius_um: float) -> tuple[float, float]:
        """Angular frequency (rad/µs) and amplitude decay time (µs) of the l=2 shape mode of a
        free drop of radius R (Rayleigh: ω² = 8σ/(ρR³); Lamb: τ = ρR²/(5µ))."""
        R = radius_um * 1e-6
        omega = np.sqrt(8 * self.surface_tension_mn_m * 1e-3 / (self.density_kg_m3 * R**3))
        tau = self.density_kg_m3 * R**2 / (5 * self.viscosity_mpa_s * 1e-3)
        return float(omega * 1e-6), float(tau * 1e6)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class DropHistory:
    """Volume/flow history of one firing and the drop it produces (truth quantities).

    Attributes
    ----------
    u1_um_per_ms, u2_um : float
    t_us, volume_nl, flow_nl_per_us : ndarray
        Fine simulation grid (µs after the trigger), ECM grown volume and flow.
    pinchoff_instant_us : float
    grown_volume_at_pinchoff_instant_nl : float
    volume_adjuster_nl, velocity_adjuster_m_s : float
    inflight_volume_nl : float
        Grown volume at the pinch-off instant + volume adjuster (Eq. 8).
    max_stroke_instant_us : float
        Dead time + u2/u1.
    flow_velocity_at_max_stroke_m_s : float
    jetting_velocity_m_s : float
        Flow velocity at maximum stroke + velocity adjuster (Eq. 8).
    nozzle_inner_diameter_um : float
    """

    u1_um_per_ms: float
    u2_um: float
    t_us: np.ndarray
    volume_nl: np.ndarray
    flow_nl_per_us: np.ndarray
    pinchoff_instant_us: float
    grown_volume_at_pinchoff_instant_nl: float
    volume_adjuster_nl: float
    velocity_adjuster_m_s: float
    inflight_volume_nl: float
    max_stroke_instant_us: float
    flow_velocity_at_max_stroke_m_s: float
    jetting_velocity_m_s: float
    nozzle_inner_diameter_um: float
    volume_spline: CubicHermiteSpline = field(repr=False, compare=False, default=None)
    #: the drive of a waveform template (:func:`drive_history`): its ``to_dict()``; None for (u1, u2)
    drive: dict | None = field(default=None, compare=False)

    def grown_volume_nl_at(self, t_us) -> np.ndarray:
        """ECM grown volume (nl) at arbitrary times (cubic Hermite between grid points)."""
        return self.volume_spline(np.asarray(t_us, dtype=float))

    def flow_nl_per_us_at(self, t_us) -> np.ndarray:
        """ECM flow (nl/µs) at arbitrary times (linear between grid points)."""
        return np.interp(np.asarray(t_us, dtype=float), self.t_us, self.flow_nl_per_us)

    def flow_velocity_m_s_at(self, t_us) -> np.ndarray:
        """Average flow velocity in the nozzle (m/s) at arbitrary times."""
        return flow_velocity_m_s(self.flow_nl_per_us_at(t_us), self.nozzle_inner_diameter_um)

    def summary(self) -> dict:
        """Scalar truth quantities as a dict."""
        return {k: float(getattr(self, k)) for k in (
            "u1_um_per_ms", "u2_um", "pinchoff_instant_us", "grown_volume_at_pinchoff_instant_nl",
            "volume_adjuster_nl", "velocity_adjuster_m_s", "inflight_volume_nl",
            "max_stroke_instant_us", "flow_velocity_at_max_stroke_m_s", "jetting_velocity_m_s")}


def drop_history(physics: SynthPhysics, u1_um_per_ms: float, u2_um: float, *,
                 t_end_us: float = 2500.0, dt_us: float = 0.5) -> DropHistory:
    """Simulate the ECM for one waveform and evaluate the pinch-off law and adjusters.

    Parameters
    ----------
    physics : SynthPhysics
    u1_um_per_ms, u2_um : float
        Control parameters of the waveform.
    t_end_us : float
        End of the simulation grid (µs after the trigger); must cover the pinch-off instant.
    dt_us : float
        Grid step (µs).

    Raises
    ------
    ValueError
        If the pinch-off instant falls outside (dead time, t_end_us] or the resulting
        in-flight volume or jetting velocity is not positive.
    """
    if not dt_us > 0:
        raise ValueError(f"dt_us must be > 0, got {dt_us!r}")
    wf = physics.waveform(u1_um_per_ms, u2_um)
    tp = physics.pinchoff_instant_us(u1_um_per_ms, u2_um)
    return _history(
        physics, lambda t: wf.displacement_um(t - physics.dead_time_us), physics.dead_time_us, tp,
        lambda: (physics.volume_adjuster_nl_at(u1_um_per_ms, u2_um), physics.velocity_adjuster_m_s_at(u1_um_per_ms, u2_um)),
        physics.dead_time_us + wf.max_stroke_us, f"(u1, u2) = ({u1_um_per_ms}, {u2_um})", "the piston moves",
        t_end_us, dt_us, u1_um_per_ms=float(u1_um_per_ms), u2_um=float(u2_um))


def _history(physics: SynthPhysics, drive_at, dead_time_us: float, tp: float, adjusters, t_max: float, what: str,
             starts: str, t_end_us: float, dt_us: float, **fields) -> DropHistory:
    """The one simulation of :func:`drop_history` and :func:`drive_history`: the ECM of ``physics``
    driven by ``drive_at(t)`` on a ``dt_us`` grid up to after the pinch-off instant ``tp``, the grown
    volume at ``tp``, the adjusters (``adjusters()`` -> (nl, m/s)) and the flow velocity at
    ``t_max``. ``what`` names the drive and ``starts`` its start in the errors; ``fields`` are the
    further fields of the :class:`DropHistory`."""
    t_end = max(float(t_end_us), tp + 50.0)
    t = np.arange(0.0, t_end + 0.5 * dt_us, dt_us)
    u = drive_at(t)
    coeffs = physics.ecm_parameters().coefficients()
    volume, flow = simulate(coeffs, t, u)
    if not dead_time_us < tp:
        raise ValueError(f"pinch-off law gives t_p = {tp:.1f} µs for {what}: before {starts}")
    spline = CubicHermiteSpline(t, volume, flow)
    v_tp = float(spline(tp))
    adj_v, adj_u = adjusters()
    fv_max = float(flow_velocity_m_s(np.interp(t_max, t, flow), physics.nozzle_inner_diameter_um))
    inflight = v_tp + adj_v
    v_jet = fv_max + adj_u
    if not inflight > 0 or not v_jet > 0:
        raise ValueError(f"{what} gives a non-physical drop: in-flight volume {inflight:.3g} nl, "
                         f"jetting velocity {v_jet:.3g} m/s")
    return DropHistory(
        t_us=t, volume_nl=volume, flow_nl_per_us=flow, pinchoff_instant_us=tp,
        grown_volume_at_pinchoff_instant_nl=v_tp, volume_adjuster_nl=adj_v, velocity_adjuster_m_s=adj_u,
        inflight_volume_nl=inflight, max_stroke_instant_us=t_max, flow_velocity_at_max_stroke_m_s=fv_max,
        jetting_velocity_m_s=v_jet, nozzle_inner_diameter_um=physics.nozzle_inner_diameter_um,
        volume_spline=spline, **fields,
    )


# --------------------------------------------------------------------------- waveform templates


@dataclass(frozen=True)
class LinearLaw:
    """A law linear in named waveform parameters: ``constant + sum_k slopes[k] (x_k - centre[k])``
    (a parameter absent from ``centre`` is centred at 0; absent from ``slopes``: no effect)."""

    constant: float
    slopes: dict = field(default_factory=dict)
    centre: dict = field(default_factory=dict)

    def at(self, values) -> float:
        out = float(self.constant)
        for k, c in self.slopes.items():  # in order, as SynthPhysics writes its (u1, u2) laws
            if k not in values:
                raise ValueError(f"a law has a slope for {k!r}, which is not a parameter of the drive "
                                 f"({', '.join(values)})")
            out = out + float(c) * (float(values[k]) - float(self.centre.get(k, 0.0)))
        return float(out)

    def to_dict(self) -> dict:
        return {"constant": float(self.constant), "slopes": dict(self.slopes), "centre": dict(self.centre)}

    @classmethod
    def from_dict(cls, d) -> "LinearLaw":
        if not isinstance(d, dict) or not isinstance(d.get("constant"), (int, float)) or isinstance(d["constant"], bool):
            raise ValueError(f"a linear law is {{'constant': number, 'slopes': {{name: number}}, 'centre': "
                             f"{{name: number}}}}, got {d!r}")
        return cls(float(d["constant"]), dict(d.get("slopes") or {}), dict(d.get("centre") or {}))


@dataclass(frozen=True)
class TemplateLaws:
    """The synthetic printhead's pinch-off instant (µs after the trigger) and adjusters (nl, m/s)
    as laws linear in a template's parameters (the data-driven part of Eq. 8, for any template)."""

    pinchoff_us: LinearLaw
    volume_adjuster_nl: LinearLaw
    velocity_adjuster_m_s: LinearLaw

    def to_dict(self) -> dict:
        return {k: getattr(self, k).to_dict() for k in ("pinchoff_us", "volume_adjuster_nl", "velocity_adjuster_m_s")}

    @classmethod
    def from_dict(cls, d) -> "TemplateLaws":
        keys = ("pinchoff_us", "volume_adjuster_nl", "velocity_adjuster_m_s")
        missing = [k for k in keys if not isinstance(d, dict) or k not in d]
        if missing:
            raise ValueError(f"laws: missing {', '.join(missing)} (each a linear law: constant, slopes, centre)")
        return cls(*(LinearLaw.from_dict(d[k]) for k in keys))


def trapezoid_laws(physics: SynthPhysics) -> TemplateLaws:
    """The (u1, u2) laws of ``physics`` written as :class:`TemplateLaws` of the trapezoid template
    (the same numbers: :func:`drive_history` of the trapezoid equals :func:`drop_history`)."""
    c0, c1, c2 = physics.pinchoff_law_us
    p = physics.volume_adjuster_nl
    q = physics.velocity_adjuster_m_s
    names = ("u1_um_per_ms", "u2_um")
    return TemplateLaws(LinearLaw(c0, dict(zip(names, (c1, c2))), dict(zip(names, (70.0, 25.0)))),
                        LinearLaw(p[0], dict(zip(names, p[1:]))), LinearLaw(q[0], dict(zip(names, q[1:]))))


#: Laws of the synthetic three-pulse dispenser (`dropvision.synth` with a ``waveform`` of the
#: three_pulse template), centred on :data:`THREE_PULSE_CENTRE`: there the drive ends 626 us after
#: the trigger (dead time 220 us) and the drop pinches off at 660 us, later for a stronger or longer
#: main pulse, a stronger second pulse or a longer first delay.
THREE_PULSE_CENTRE = {"V1": 30.0, "V2": 10.0, "V3": 10.0, "w1": 200.0, "w2": 80.0, "w3": 80.0, "d1": 20.0, "d2": 20.0}
THREE_PULSE_LAWS = TemplateLaws(
    LinearLaw(660.0, {"V1": 1.5, "w1": 0.3, "V2": 1.0, "d1": 0.3}, THREE_PULSE_CENTRE),
    LinearLaw(0.3, {"V1": 0.02, "w1": 0.002, "V2": -0.01}, THREE_PULSE_CENTRE),
    LinearLaw(0.4, {"V1": 0.01, "w1": -0.0005, "V3": 0.005}, THREE_PULSE_CENTRE),
)


def drive_history(physics: SynthPhysics, drive: Drive, laws: TemplateLaws, *, t_end_us: float = 2500.0,
                  dt_us: float = 0.5) -> DropHistory:
    """:func:`drop_history` for the drive of a waveform template: the ECM of ``physics`` simulated
    (first-order hold on a ``dt_us`` grid, exact where the drive's corners fall on it) with
    ``drive.at(t)`` as its input u(t), the pinch-off instant and the adjusters from ``laws``, the
    jetting velocity read at ``drive.velocity_instant_us`` (the trapezoid: the maximum stroke).
    ``physics.dead_time_us`` is not used: the drive carries its own."""
    if not dt_us > 0:
        raise ValueError(f"dt_us must be > 0, got {dt_us!r}")
    values = drive.values
    nan = float("nan")
    return _history(
        physics, drive.at, drive.dead_time_us, laws.pinchoff_us.at(values),
        lambda: (laws.volume_adjuster_nl.at(values), laws.velocity_adjuster_m_s.at(values)),
        drive.velocity_instant_us, "(" + ", ".join(f"{k} {v:g}" for k, v in values.items()) + ")",
        "the drive starts", t_end_us, dt_us, u1_um_per_ms=float(values.get("u1_um_per_ms", nan)),
        u2_um=float(values.get("u2_um", nan)), drive=drive.to_dict())


#: Default laws of a template without its own (`dropvision.synth`'s ``waveform`` without ``laws``).
DEFAULT_LAWS = {"three_pulse": THREE_PULSE_LAWS}


def laws_for(template_name: str, physics: SynthPhysics, laws=None) -> TemplateLaws:
    """The laws of a synthetic printhead driven by ``template_name``: ``laws`` (a
    :class:`TemplateLaws` or its dict) when given, else the trapezoid's from ``physics`` or the
    template's default (:data:`DEFAULT_LAWS`)."""
    if laws is not None:
        return laws if isinstance(laws, TemplateLaws) else TemplateLaws.from_dict(laws)
    if template_name == "trapezoid":
        return trapezoid_laws(physics)
    if template_name not in DEFAULT_LAWS:
        raise ValueError(f"no default synthetic laws for waveform template {template_name!r}: give 'laws'")
    return DEFAULT_LAWS[template_name]
