"""Drop formation models of the synthetic drop: the liquid bodies (:mod:`dropvision.synth.profiles`)
of a jetting nozzle or a pendant drop at any time, with exact volumes.

Drop formation model (:class:`DropShapeModel`), t = time after the trigger, t_p = pinch-off:

1. Meniscus/growth (t < t_p - neck duration): a spherical segment pinned at the inner nozzle
   radius R_i whose volume is V_men0 + V_grown(t): a cap for small volumes, a bulb beyond a
   hemisphere. The initial meniscus is the segment of height ``meniscus_height_um``.
2. Neck thinning (last ``neck_duration_us`` before t_p): union of an upper neck pinned at R_i
   narrowing to a waist of radius r_w = r_w0 (τ/T)^(2/3) (τ = t_p - t), a lower neck flaring
   from the waist into the bulb, and a bulb (prolate spheroid, elongation growing to
   ``pinchoff_elongation``) whose centre moves down at the jetting velocity. The bulb's
   equivalent radius is solved (brentq) so that the union's volume is V_men0 + V_grown(t).
3. Pinch-off (t ≥ t_p): the waist breaks. The residual meniscus (the upper neck as a stub,
   retracting with time constant ``stub_retract_us``, united with a cap recovering to the
   initial meniscus with time constant ``meniscus_recover_us``) stays attached. The main drop
   (spheroid a = R(1+ε cos ωt), b = R/sqrt(1+ε cos ωt), ε decaying; ω and the decay from the
   l = 2 Rayleigh/Lamb mode) flies from the bulb centre at t_p at the jetting velocity along
   the trajectory; its centre moves exactly linearly.
4. Tail: a thread (radius ≥ ``tail_thread_radius_fraction`` R) with a rounded tip joins the
   main drop. With ``satellites = 0`` it shortens and merges into the drop within
   ``tail_merge_us``; with satellites it stretches (tip at ``tail_tip_speed_fraction`` of the
   jetting velocity) and breaks after ``tail_break_us`` into 1 or 2 spheres that fly slower.

Realism tier (docs/SYNTH_REALISM.md):

* ``bead_um``: after pinch-off a bead (:func:`bead_segment`, a sphere of that diameter cut
  15 % below its top) hangs from the apex of the residual meniscus; the supports are disjoint,
  so the attached volume grows by exactly its cap volume.
* ``satellite_mode``: "separate" (above), "touching" (the first satellite rides on the drop
  ``touching_gap_um`` behind it: its silhouette merges with the drop's), "dumbbell" (the first
  satellite is :func:`dumbbell_profile`, two spheres joined by a neck, of the same volume),
  "mixed" (a touching one, then a dumbbell; needs 2 satellites to show both).
* ``tail_bulb``: the tail's tip is a bulb of ``tail_bulb_radius_fraction`` x the drop radius
  (part of the main body; the drop's radius is solved with it, so the volume stays exact).
* :class:`PendantShapeModel`: a static Young-Laplace pendant drop on a needle.

Volume bookkeeping (documented choice): the attached volume before pinch-off is
V_men0 + V_grown(t) exactly. The detached liquid is V_inflight + V_sat from the pinch-off on,
where V_inflight = V_grown(t_p) + volume adjuster and V_sat = ``satellite_volume_fraction`` ×
V_inflight (0 without satellites). The main body (drop + joined tail) holds all of it until
the tail has merged (main drop = V_inflight) or broken up (main drop = V_inflight, each
satellite V_sat / n). The extra liquid of the adjuster comes from inside the nozzle (not
visible); the residual meniscus is whatever its profile holds.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

import numpy as np
from scipy.optimize import brentq

from dropvision.synth.profiles import (UM3_PER_NL, LiquidBody, Profile, QuadraticNeck, SphericalSegment, Spheroid,
                                       TabulatedProfile, bead_segment, cap_height_for_volume_um, cap_volume_um3,
                                       dumbbell_profile, young_laplace_profile)
from identify.physics import DropHistory, SynthPhysics

__all__ = [
    "UM3_PER_NL", "Spheroid", "SphericalSegment", "QuadraticNeck", "Profile", "LiquidBody",
    "ShapeParams", "ShapeState", "DropShapeModel", "cap_volume_um3", "cap_height_for_volume_um",
    "TabulatedProfile", "SATELLITE_MODES", "bead_segment", "dumbbell_profile",
    "young_laplace_profile", "PendantShapeModel", "SATELLITE_KINDS",
]

#: Satellite layouts after break-up (ShapeParams.satellite_mode).
SATELLITE_MODES = ("separate", "touching", "dumbbell", "mixed")
#: Kind of each satellite (first, second) per mode: a sphere flying on its own, a sphere riding
#: on the drop a ``touching_gap_um`` behind it, or a dumbbell (two spheres joined by a neck).
SATELLITE_KINDS = {"separate": ("sphere", "sphere"), "touching": ("touching", "sphere"),
                   "dumbbell": ("dumbbell", "sphere"), "mixed": ("touching", "dumbbell")}


# ----------------------------------------------------------------------------------------
# Drop formation model
# ----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ShapeParams:
    """Shape knobs of the drop formation model (see the module docstring).

    All defaults are chosen to look like the paper's Fig. 5; none changes a truth volume
    except ``meniscus_height_um`` (initial meniscus) and ``satellite_volume_fraction``.
    """

    meniscus_height_um: float = 15.0
    neck_duration_us: float = 150.0
    neck_waist_start_fraction: float = 0.6
    waist_depth_fraction: float = 0.15
    neck_base_fraction: float = 0.45
    pinchoff_elongation: float = 0.2
    separation_gap_um: float = 12.0
    tail_merge_us: float = 40.0
    tail_break_us: float = 120.0
    tail_thread_radius_fraction: float = 0.07
    tail_tip_speed_fraction: float = 0.5
    satellite_volume_fraction: float = 0.02
    satellite_speed_fractions: tuple[float, float] = (0.85, 0.75)
    stub_retract_us: float = 25.0
    meniscus_recover_us: float = 60.0
    spot_radius_fraction: float = 0.3
    satellite_mode: str = "separate"
    touching_gap_um: float = 1.0
    tail_bulb: bool = False
    tail_bulb_radius_fraction: float = 0.3
    bead_um: float = 0.0

    def __post_init__(self) -> None:
        if self.satellite_mode not in SATELLITE_MODES:
            raise ValueError(f"ShapeParams.satellite_mode must be one of {', '.join(SATELLITE_MODES)}, "
                             f"got {self.satellite_mode!r}")
        for name, value in asdict(self).items():
            if isinstance(value, str):
                continue
            vals = value if isinstance(value, tuple) else (value,)
            if not all(np.isfinite(v) and v >= 0 for v in vals):
                raise ValueError(f"ShapeParams.{name} must be >= 0, got {value!r}")
        if not 0 < self.waist_depth_fraction < 1:
            raise ValueError("ShapeParams.waist_depth_fraction must be in (0, 1)")
        if not self.tail_tip_speed_fraction < 1:
            raise ValueError("ShapeParams.tail_tip_speed_fraction must be < 1")

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class ShapeState:
    """Bodies and truth values at one instant (one frame before any position jitter)."""

    t_us: float
    attached: bool
    attached_body: LiquidBody | None
    main_body: LiquidBody | None
    satellites: tuple = ()
    attached_volume_nl: float = 0.0
    grown_volume_nl: float = 0.0
    drop_volume_nl: float = float("nan")
    detached_volume_nl: float = 0.0
    drop_z_um: float = float("nan")
    drop_x_um: float = float("nan")
    flow_velocity_m_s: float = float("nan")
    tail_attached: bool = False
    inflight: bool = False
    extra: dict = field(default_factory=dict)

    @property
    def n_satellites(self) -> int:
        return len(self.satellites)

    @property
    def bodies(self) -> tuple[LiquidBody, ...]:
        out = tuple(b for b in (self.attached_body, self.main_body) if b is not None)
        return out + tuple(self.satellites)

    def shifted(self, dz_um: float, dx_um: float) -> "ShapeState":
        """The same state with every detached body moved by (dz, dx) in the nozzle frame."""
        if self.main_body is None:
            return self
        return replace(
            self, main_body=self.main_body.shifted(dz_um, dx_um),
            satellites=tuple(b.shifted(dz_um, dx_um) for b in self.satellites),
            drop_z_um=self.drop_z_um + dz_um, drop_x_um=self.drop_x_um + dx_um)


def _solve_scale(volume_of, target_um3: float, lo: float, hi: float, what: str) -> float:
    f_lo = volume_of(lo) - target_um3
    if f_lo > 0:
        raise ValueError(f"{what}: target volume {target_um3 / UM3_PER_NL:.4g} nl is smaller than "
                         f"the fixed parts of the shape ({(f_lo + target_um3) / UM3_PER_NL:.4g} nl)")
    while volume_of(hi) < target_um3:
        hi *= 2.0
    return brentq(lambda r: volume_of(r) - target_um3, lo, hi, xtol=1e-12, rtol=1e-13, maxiter=200)


class DropShapeModel:
    """Shapes and truth of one firing as a function of time (see the module docstring).

    Parameters
    ----------
    history : DropHistory
        ECM volume history, pinch-off instant, in-flight volume and jetting velocity.
    physics : SynthPhysics
        Nozzle radii and ink (for the drop oscillation).
    shape : ShapeParams
    drift_mrad : float
        Trajectory angle from the nozzle axis (towards +x).
    satellites : int
        0 (tail merges), 1 or 2.
    """

    def __init__(self, history: DropHistory, physics: SynthPhysics, shape: ShapeParams = ShapeParams(),
                 *, drift_mrad: float = 0.0, satellites: int = 0):
        if satellites not in (0, 1, 2):
            raise ValueError(f"satellites must be 0, 1 or 2, got {satellites!r}")
        self.history, self.physics, self.shape = history, physics, shape
        self.satellites = int(satellites)
        self.theta = float(drift_mrad) * 1e-3
        self.ri = physics.nozzle_inner_radius_um
        self.v_um_per_us = history.jetting_velocity_m_s  # 1 m/s = 1 µm/µs
        self.tp = history.pinchoff_instant_us
        sp = shape
        self.meniscus = SphericalSegment(self.ri, sp.meniscus_height_um) if sp.meniscus_height_um > 0 else None
        self.v_men0_um3 = self.meniscus.volume_um3() if self.meniscus else 0.0
        self.v_inflight_um3 = history.inflight_volume_nl * UM3_PER_NL
        self.v_sat_um3 = sp.satellite_volume_fraction * self.v_inflight_um3 if satellites else 0.0
        self.r_inflight = (3.0 * self.v_inflight_um3 / (4.0 * np.pi)) ** (1.0 / 3.0)
        self.omega, self.tau_osc = physics.rayleigh_mode2(self.r_inflight)
        # neck phase start and bulb centre there (continuity with the pinned segment)
        self.t_neck = max(self.tp - sp.neck_duration_us, physics.dead_time_us)
        self.neck_us = self.tp - self.t_neck
        v0 = self._attached_target_um3(self.t_neck)
        h0 = cap_height_for_volume_um(self.ri, v0)
        self.c0 = max(SphericalSegment(self.ri, h0).center_um, 0.3 * self.ri)
        self.c_p = self.c0 + self.v_um_per_us * self.neck_us
        self.s_wp = sp.waist_depth_fraction * self.c_p
        self.tail_l0 = self.c_p - self.s_wp - sp.separation_gap_um
        self.r_thread = sp.tail_thread_radius_fraction * self.r_inflight
        self.t_final = sp.tail_break_us if satellites else sp.tail_merge_us
        self._kinds = SATELLITE_KINDS[sp.satellite_mode][:self.satellites]
        self._dumbbell = dumbbell_profile(self.v_sat_um3 / satellites) if "dumbbell" in self._kinds else None
        self._sat_layout = self._satellite_layout() if satellites else ()

    # -- helpers --------------------------------------------------------------------------
    def _attached_target_um3(self, t_us: float) -> float:
        return self.v_men0_um3 + float(self.history.grown_volume_nl_at(t_us)) * UM3_PER_NL

    def elongation(self, delta_us: float) -> float:
        """ε of the free drop δ µs after pinch-off (damped l = 2 oscillation)."""
        return (self.shape.pinchoff_elongation * np.exp(-delta_us / self.tau_osc)
                * np.cos(self.omega * delta_us))

    def _drop(self, R: float, eps: float, center: float = 0.0) -> Spheroid:
        return Spheroid(center, R * (1.0 + eps), R / np.sqrt(1.0 + eps))

    def drop_center_zx_um(self, delta_us: float) -> tuple[float, float]:
        """Main drop centre in the nozzle frame δ µs after pinch-off (exactly linear)."""
        d = self.v_um_per_us * delta_us
        return self.c_p + d * np.cos(self.theta), d * np.sin(self.theta)

    def _tail_length(self, delta_us: float) -> float:
        if self.satellites:
            return self.tail_l0 + (1.0 - self.shape.tail_tip_speed_fraction) * self.v_um_per_us * delta_us
        return self.tail_l0 * max(0.0, 1.0 - delta_us / self.shape.tail_merge_us)

    def _tail_parts(self, R: float, L: float) -> tuple:
        rt = self.r_thread
        if self.shape.tail_bulb:
            rb = max(rt, self.shape.tail_bulb_radius_fraction * R)
            if L <= rb:
                return ()
            return (QuadraticNeck(-L, 0.0, rt, max(rt, self.shape.neck_base_fraction * R)),
                    Spheroid(-L + rb, rb, rb))
        if L <= rt:
            return ()
        return (QuadraticNeck(-L, 0.0, rt, max(rt, self.shape.neck_base_fraction * R)),
                Spheroid(-L + rt, rt, rt))

    def _satellite_layout(self) -> tuple:
        """(offset from drop centre at break-up along the trajectory, radius, speed) per satellite."""
        sp, n = self.shape, self.satellites
        tb = sp.tail_break_us
        a_b = self._drop(self.r_inflight, self.elongation(tb)).a_um
        L_b = self._tail_length(tb)
        r_s = (3.0 * self.v_sat_um3 / n / (4.0 * np.pi)) ** (1.0 / 3.0)
        gap = max(0.5 * r_s, 8.0)
        out, prev = [], None
        if sp.satellite_mode == "separate":
            for k in range(n):
                s = -a_b - (k + 0.5) / n * max(L_b - a_b, 0.0)
                limit = -a_b - gap - r_s if prev is None else prev - 2 * r_s - gap
                s = min(s, limit)
                out.append((s, r_s, sp.satellite_speed_fractions[k] * self.v_um_per_us))
                prev = s
            return tuple(out)
        # touching / dumbbell / mixed: satellites by kind, each behind the previous one
        kinds = SATELLITE_KINDS[sp.satellite_mode]
        tail_end = -a_b
        for k in range(n):
            kind = kinds[k]
            if kind == "touching":
                s = -a_b - sp.touching_gap_um - r_s
                out.append((s, r_s, self.v_um_per_us))
                tail_end = s - r_s
            elif kind == "dumbbell":
                front = self._dumbbell.parts[0].a_um
                s = min(-a_b - (k + 0.5) / n * max(L_b - a_b, 0.0), tail_end - gap - front)
                out.append((s, front, sp.satellite_speed_fractions[k] * self.v_um_per_us))
                tail_end = s + self._dumbbell.support[0]
            else:
                s = min(-a_b - (k + 0.5) / n * max(L_b - a_b, 0.0), tail_end - gap - r_s)
                out.append((s, r_s, sp.satellite_speed_fractions[k] * self.v_um_per_us))
                tail_end = s - r_s
        return tuple(out)

    def _spot(self, center: float, a: float, b: float) -> tuple:
        f = self.shape.spot_radius_fraction
        return ((center - 0.15 * a, f * a, f * b),) if f > 0 else ()

    # -- the state at one instant ---------------------------------------------------------
    def state(self, t_us: float) -> ShapeState:
        """Bodies and truth at ``t_us`` (µs after the trigger)."""
        t = float(t_us)
        if t < self.tp:
            return self._attached_state(t)
        return self._detached_state(t)

    def _attached_state(self, t: float) -> ShapeState:
        sp = self.shape
        target = self._attached_target_um3(t)
        grown = float(self.history.grown_volume_nl_at(t))
        if t < self.t_neck:
            seg = SphericalSegment(self.ri, cap_height_for_volume_um(self.ri, target))
            profile = Profile((seg,))
            spots = self._spot(seg.center_um, seg.sphere_radius_um, seg.sphere_radius_um) \
                if seg.center_um > 0.25 * seg.sphere_radius_um else ()
        else:
            q = (t - self.t_neck) / self.neck_us
            tau = self.tp - t
            r_w = sp.neck_waist_start_fraction * self.ri * (tau / self.neck_us) ** (2.0 / 3.0)
            c = self.c0 + self.v_um_per_us * (t - self.t_neck)
            s_w = sp.waist_depth_fraction * c
            eps = sp.pinchoff_elongation * q
            upper = QuadraticNeck(s_w, 0.0, r_w, self.ri)

            def build(R):
                return Profile((upper, QuadraticNeck(s_w, c, r_w, max(r_w, sp.neck_base_fraction * R)),
                                self._drop(R, eps, c)), clip_min_um=0.0)

            R = _solve_scale(lambda R: build(R).volume_um3(), target, 1e-6,
                             2.0 * (target / np.pi) ** (1 / 3) + 10.0, f"neck phase at t = {t:g} µs")
            profile = build(R)
            d = self._drop(R, eps, c)
            spots = self._spot(c, d.a_um, d.b_um)
        body = LiquidBody("attached", profile, 0.0, 0.0, 0.0, spots)
        vol = body.volume_nl()
        return ShapeState(
            t_us=t, attached=True, attached_body=body, main_body=None, attached_volume_nl=vol,
            grown_volume_nl=grown,
            flow_velocity_m_s=float(self.history.flow_velocity_m_s_at(t)),
            extra={"attached_target_nl": target / UM3_PER_NL})

    def _residual_body(self, delta: float) -> LiquidBody:
        sp = self.shape
        parts = []
        ell = self.s_wp * (np.exp(-delta / sp.stub_retract_us) if sp.stub_retract_us > 0 else 0.0)
        if ell > 1e-6:
            parts.append(QuadraticNeck(ell, 0.0, 0.0, self.ri))
        h = sp.meniscus_height_um * (1.0 - np.exp(-delta / sp.meniscus_recover_us)) \
            if sp.meniscus_recover_us > 0 else sp.meniscus_height_um
        if h > 1e-6:
            parts.append(SphericalSegment(self.ri, h))
        if not parts:  # fully retracted: an (invisible) empty body
            parts.append(QuadraticNeck(0.0, 0.0, 0.0, 0.0))
        if sp.bead_um > 0:  # bead hanging from the apex of the residual meniscus (disjoint support)
            top = max(p.support[1] for p in parts)
            parts.append(bead_segment(top, sp.bead_um))
        return LiquidBody("attached", Profile(tuple(parts), clip_min_um=0.0), 0.0, 0.0, 0.0)

    def _detached_state(self, t: float) -> ShapeState:
        delta = t - self.tp
        residual = self._residual_body(delta)
        v_res = residual.volume_nl() if residual.profile.support[1] > residual.profile.support[0] else 0.0
        eps = self.elongation(delta)
        zc, xc = self.drop_center_zx_um(delta)
        inflight = delta >= self.t_final
        sats: list[LiquidBody] = []
        if not inflight:
            L = self._tail_length(delta)
            target = self.v_inflight_um3 + self.v_sat_um3

            def build(R):
                return Profile((self._drop(R, eps),) + self._tail_parts(R, L))

            R = _solve_scale(lambda R: build(R).volume_um3(), target, 1e-6, 2.0 * self.r_inflight,
                             f"tail phase at t = {t:g} µs")
            profile = build(R)
        else:
            R = self.r_inflight
            profile = Profile((self._drop(R, eps),))
            for kind, (s_b, r_s, v_s) in zip(self._kinds, self._sat_layout):
                s = s_b - (self.v_um_per_us - v_s) * (delta - self.shape.tail_break_us)
                if kind == "touching":  # rides on the drop, a gap of touching_gap_um behind it
                    s = -self._drop(R, eps).a_um - self.shape.touching_gap_um - r_s
                sz, sx = zc + s * np.cos(self.theta), xc + s * np.sin(self.theta)
                spots = self._spot(0.0, r_s, r_s)
                prof = self._dumbbell if kind == "dumbbell" else Profile((Spheroid(0.0, r_s, r_s),))
                sats.append(LiquidBody("satellite", prof, sz, sx, self.theta, spots))
        d = self._drop(R, eps)
        main = LiquidBody("drop", profile, zc, xc, self.theta, self._spot(0.0, d.a_um, d.b_um))
        v_main = main.volume_nl()
        cz, cx = main.centroid_zx_um()
        return ShapeState(
            t_us=t, attached=False, attached_body=residual, main_body=main, satellites=tuple(sats),
            attached_volume_nl=v_res, grown_volume_nl=v_res - self.v_men0_um3 / UM3_PER_NL,
            drop_volume_nl=v_main, detached_volume_nl=v_main + sum(b.volume_nl() for b in sats),
            drop_z_um=cz, drop_x_um=cx, tail_attached=not inflight, inflight=inflight)

    def initial_meniscus_volume_nl(self) -> float:
        return self.v_men0_um3 / UM3_PER_NL

    def describe(self) -> dict:
        """Derived constants of the shape model (for truth.json parameters)."""
        return {
            "initial_meniscus_volume_nl": self.initial_meniscus_volume_nl(),
            "neck_start_us": self.t_neck, "bulb_center_at_neck_start_um": self.c0,
            "bulb_center_at_pinchoff_um": self.c_p, "waist_depth_at_pinchoff_um": self.s_wp,
            "tail_length_at_pinchoff_um": self.tail_l0, "inflight_radius_um": self.r_inflight,
            "oscillation_omega_rad_per_us": self.omega, "oscillation_decay_us": self.tau_osc,
            "satellite_volume_total_nl": self.v_sat_um3 / UM3_PER_NL,
            "tail_final_us_after_pinchoff": self.t_final,
        }


class PendantShapeModel:
    """A static pendant drop hanging from a needle (never detaching): the Young-Laplace
    profile of :func:`young_laplace_profile`, pinned on the needle's outer radius at the tip
    plane, with a lens spot at its equator. Every frame shows the same drop.

    Truth: ``attached_volume_nl`` is the ODE quadrature of π x² dz (relative accuracy ~1e-12);
    the rendered profile (r² linear between 4001 profile points) holds the same volume to
    < 1e-6 relative. Grown volume, flow velocity and every detached quantity are NaN / 0.
    """

    def __init__(self, apex_radius_um: float, bond: float, needle_radius_um: float,
                 shape: ShapeParams = ShapeParams()):
        self.shape = shape
        self.profile_data = young_laplace_profile(apex_radius_um, bond, needle_radius_um)
        d = self.profile_data
        self.volume_um3 = d["volume_um3"]
        prof = Profile((TabulatedProfile(d["s_um"], d["r2_um2"]),))
        f = shape.spot_radius_fraction
        rmax = d["max_radius_um"]
        spots = ((d["equator_s_um"], f * rmax, f * rmax),) if f > 0 else ()
        self.body = LiquidBody("attached", prof, 0.0, 0.0, 0.0, spots)
        # names used by the dust layout and the truth (a pendant drop neither detaches nor flies)
        self.theta = 0.0
        self.tp = float("inf")
        self.r_inflight = rmax
        self.c_p = d["equator_s_um"]
        self.v_sat_um3 = 0.0
        self.satellites = 0

    def drop_center_zx_um(self, delta_us: float) -> tuple[float, float]:
        return self.c_p, 0.0

    def state(self, t_us: float) -> ShapeState:
        return ShapeState(t_us=float(t_us), attached=True, attached_body=self.body, main_body=None,
                          attached_volume_nl=self.volume_um3 / UM3_PER_NL, grown_volume_nl=float("nan"),
                          flow_velocity_m_s=float("nan"))

    def initial_meniscus_volume_nl(self) -> float:
        return float("nan")

    def describe(self) -> dict:
        d = self.profile_data
        return {"scene": "pendant", "volume_nl": self.volume_um3 / UM3_PER_NL,
                "apex_radius_um": d["apex_radius_um"], "bond": d["bond"],
                "needle_radius_um": d["needle_radius_um"], "height_um": d["height_um"],
                "max_radius_um": d["max_radius_um"], "equator_below_tip_um": d["equator_s_um"],
                "rendered_profile_volume_nl": self.body.volume_nl()}
