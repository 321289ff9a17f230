"""
Every liquid body is a body of revolution about its own axis: a profile r(s) along the axis
(µm), the union (pointwise maximum of r) of a few analytic primitives. The truth volume is
π ∫ r(s)² ds, integrated by composite Gauss-Legendre quadrature with break points at every
primitive's support ends (r² is a polynomial on each primitive, so single-primitive volumes
are exact to rounding; unions have kinks where primitives cross, handled by ≤ 1 µm panels:
relative error < 1e-7). Renderer and truth use the very same profile.

Frames (all lengths in µm)
--------------------------
* Nozzle frame: z along the nozzle axis from the tip plane (positive in the jetting
  direction), x across the axis (positive to the right in the image).
* Body frame: s along the body's own axis from the body origin, y across. A body's origin
  (z, x) and axis angle (rad, from the nozzle axis towards +x) place it in the nozzle frame.

The drop formation models that place these bodies over time are in
:mod:`dropvision.synth.shapes`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import brentq

__all__ = [
    "UM3_PER_NL", "Spheroid", "SphericalSegment", "QuadraticNeck", "TabulatedProfile", "Profile", "LiquidBody",
    "cap_volume_um3", "cap_height_for_volume_um", "segment_sphere_radius_um", "bead_segment", "dumbbell_profile",
    "young_laplace_profile",
]

#: µm³ per nl.
UM3_PER_NL = 1e6

_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)


# ----------------------------------------------------------------------------------------
# Primitives: r²(s) on a support; -1 outside (so that no point is inside there)
# ----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Spheroid:
    """Spheroid centred at ``center_um`` with semi-axes ``a_um`` (along) and ``b_um`` (across).
    A sphere when a = b."""

    center_um: float
    a_um: float
    b_um: float

    @property
    def support(self) -> tuple[float, float]:
        return self.center_um - self.a_um, self.center_um + self.a_um

    def breakpoints(self) -> tuple[float, ...]:
        return (*self.support, self.center_um)

    @property
    def max_radius_um(self) -> float:
        return self.b_um

    def r2(self, s):
        u = (s - self.center_um) / self.a_um
        return np.where(np.abs(u) <= 1.0, self.b_um**2 * (1.0 - u * u), -1.0)

    def volume_um3(self) -> float:
        """Closed form 4/3 π a b²."""
        return 4.0 / 3.0 * np.pi * self.a_um * self.b_um**2


def segment_sphere_radius_um(base_radius_um: float, height_um: float) -> float:
    """Radius of the sphere of a segment with a flat base of ``base_radius_um`` and ``height_um``."""
    return (base_radius_um**2 + height_um**2) / (2.0 * height_um)


@dataclass(frozen=True)
class SphericalSegment:
    """Spherical segment whose flat base (radius ``base_radius_um``) lies in the plane
    s = ``top_um`` (the tip plane by default) and which reaches ``height_um`` below it: a cap
    below a hemisphere, a bulb above (the meniscus); with ``top_um`` > 0, the bead left on the
    orifice after pinch-off (`bead_segment`)."""

    base_radius_um: float
    height_um: float
    top_um: float = 0.0

    @property
    def sphere_radius_um(self) -> float:
        return segment_sphere_radius_um(self.base_radius_um, self.height_um)

    @property
    def center_um(self) -> float:
        return self.top_um + self.height_um - self.sphere_radius_um

    @property
    def support(self) -> tuple[float, float]:
        return self.top_um, self.top_um + self.height_um

    def breakpoints(self) -> tuple[float, ...]:
        c = self.center_um
        lo, hi = self.support
        return (lo, hi) + ((c,) if lo < c < hi else ())

    @property
    def max_radius_um(self) -> float:
        return self.sphere_radius_um if self.center_um > self.top_um else self.base_radius_um

    def r2(self, s):
        R, c = self.sphere_radius_um, self.center_um
        lo, hi = self.support
        return np.where((s >= lo) & (s <= hi), R * R - (s - c) ** 2, -1.0)

    def volume_um3(self) -> float:
        """Closed form π h (3 a² + h²) / 6."""
        return cap_volume_um3(self.base_radius_um, self.height_um)


@dataclass(frozen=True)
class QuadraticNeck:
    """r(s) = r0 + (r1 - r0) ((s - s0)/(s1 - s0))² between s0 and s1 (either order)."""

    s0_um: float
    s1_um: float
    r0_um: float
    r1_um: float

    @property
    def support(self) -> tuple[float, float]:
        return min(self.s0_um, self.s1_um), max(self.s0_um, self.s1_um)

    def breakpoints(self) -> tuple[float, ...]:
        return self.support

    @property
    def max_radius_um(self) -> float:
        return max(self.r0_um, self.r1_um)

    def r2(self, s):
        lo, hi = self.support
        span = self.s1_um - self.s0_um
        if span == 0:
            return np.full(np.shape(s), -1.0)
        u = (s - self.s0_um) / span
        r = self.r0_um + (self.r1_um - self.r0_um) * u * u
        return np.where((s >= lo) & (s <= hi), r * r, -1.0)


@dataclass(frozen=True, eq=False)
class TabulatedProfile:
    """r²(s) tabulated at increasing ``s_um`` (linear interpolation of r², µm²); used for the
    Young-Laplace pendant drop. ``breaks_um`` are extra quadrature break points."""

    s_um: np.ndarray
    r2_um2: np.ndarray

    @property
    def support(self) -> tuple[float, float]:
        return float(self.s_um[0]), float(self.s_um[-1])

    def breakpoints(self) -> tuple[float, ...]:
        return tuple(float(v) for v in self.s_um)

    @property
    def max_radius_um(self) -> float:
        return float(np.sqrt(np.max(self.r2_um2)))

    def r2(self, s):
        s = np.asarray(s, dtype=float)
        lo, hi = self.support
        v = np.interp(s, self.s_um, self.r2_um2)
        return np.where((s >= lo) & (s <= hi), v, -1.0)


def bead_segment(top_um: float, bead_um: float) -> SphericalSegment:
    """The bead left on the orifice: a sphere of diameter ``bead_um`` cut 15 % of its
    diameter below its top (segment height 0.85 d, base radius d sqrt(0.85 x 0.15)), its flat
    base in the plane s = ``top_um`` (the apex of the residual meniscus)."""
    h = 0.85 * bead_um
    a = bead_um * np.sqrt(0.85 * 0.15)
    return SphericalSegment(float(a), float(h), float(top_um))


def dumbbell_profile(volume_um3: float) -> Profile:
    """A dumbbell satellite of exactly ``volume_um3`` (to the quadrature, < 1e-7): a front
    sphere (radius r, centre s = 0), a rear sphere (0.7 r, centre s = -2.4 r) and two
    quadratic necks meeting in a waist of radius 0.3 r at s = -1.2 r. The shape scales as a
    whole, so the scale is (target / volume at r = 1)^(1/3), checked by quadrature."""

    def parts(r):
        return (Spheroid(0.0, r, r), Spheroid(-2.4 * r, 0.7 * r, 0.7 * r),
                QuadraticNeck(-1.2 * r, 0.0, 0.3 * r, 0.85 * r),
                QuadraticNeck(-1.2 * r, -2.4 * r, 0.3 * r, 0.6 * r))

    # the union's kinks (where a neck crosses a sphere) scale with r: found once at r = 1 and
    # made quadrature break points, so every panel integrates one polynomial (exact)
    unit = parts(1.0)
    kinks = _crossings(unit[0], unit[2]) + _crossings(unit[1], unit[3])

    def build(r):
        return Profile(parts(r), breaks_um=tuple(k * r for k in kinks))

    r = (volume_um3 / build(1.0).volume_um3()) ** (1.0 / 3.0)
    return build(r)


def _crossings(p, q, n: int = 4001) -> tuple[float, ...]:
    """Axial positions where two primitives' radii cross (both present), by bracketing + brentq."""
    lo = max(p.support[0], q.support[0])
    hi = min(p.support[1], q.support[1])
    if not hi > lo:
        return ()

    def f(x):
        return float(p.r2(np.float64(x)) - q.r2(np.float64(x)))

    xs = np.linspace(lo, hi, n)
    d = p.r2(xs) - q.r2(xs)
    out = []
    for i in np.nonzero(np.sign(d[:-1]) * np.sign(d[1:]) < 0)[0]:
        out.append(float(brentq(f, xs[i], xs[i + 1], xtol=1e-15, rtol=1e-15)))
    return tuple(out)


def young_laplace_profile(apex_radius_um: float, bond: float, needle_radius_um: float,
                          n_points: int = 4001) -> dict:
    """Axisymmetric pendant drop (Young-Laplace) hanging from a needle of radius
    ``needle_radius_um``.

    With arc length σ from the apex, φ the tangent angle, x the radius and z the height above
    the apex (dimensionless by the apex radius b), the profile obeys
    dx/dσ = cos φ, dz/dσ = sin φ, dφ/dσ = 2 - β z - sin φ / x (β = Δρ g b² / γ the Bond
    number; sin φ / x -> 1 at the apex) and dV/dσ = π x² sin φ. It is integrated (scipy
    solve_ivp, DOP853, rtol 1e-12) from the apex until x comes back to the needle radius past
    the equator (φ > π/2); the drop is the part below that plane. β = 0 gives a sphere.

    Returns
    -------
    dict
        ``s_um`` (increasing, 0 at the needle plane, apex at ``height_um``), ``r2_um2``,
        ``volume_um3`` (the ODE quadrature), ``height_um``, ``max_radius_um``,
        ``equator_s_um``.
    """
    from scipy.integrate import solve_ivp

    b = float(apex_radius_um)
    xn = float(needle_radius_um) / b
    if not (b > 0 and 0 < xn < 1 and bond >= 0):
        raise ValueError(f"pendant drop: need apex radius > needle radius > 0 and bond >= 0, got "
                         f"b = {apex_radius_um!r} µm, needle radius {needle_radius_um!r} µm, bond {bond!r}")

    def rhs(_, y):
        x, z, phi, _v = y
        curv = 2.0 - bond * z - (np.sin(phi) / x if x > 1e-9 else 1.0)
        return [np.cos(phi), np.sin(phi), curv, np.pi * x * x * np.sin(phi)]

    def reach(_, y):
        return y[0] - xn if y[2] > np.pi / 2 else 1.0
    reach.terminal, reach.direction = True, -1

    def overhang(_, y):
        return np.pi - y[2]
    overhang.terminal = True

    s0 = 1e-6  # start just off the apex (series: x = σ, z = σ²/2, φ = σ)
    sol = solve_ivp(rhs, (s0, 20.0), [s0, s0 * s0 / 2.0, s0, 0.0], method="DOP853", rtol=1e-12,
                    atol=1e-14, events=(reach, overhang), dense_output=True)
    if not sol.t_events[0].size:
        raise ValueError(f"pendant drop: the profile (apex radius {b:g} µm, Bond {bond:g}) never "
                         f"narrows back to the needle radius {needle_radius_um:g} µm")
    s_end = float(sol.t_events[0][0])
    sig = np.linspace(s0, s_end, int(n_points))
    x, z, phi, vol = sol.sol(sig)
    v_end = float(sol.sol(s_end)[3]) + np.pi * s0**3 / 3.0 * 0.0  # cap below s0 is O(s0^4)
    height = z[-1]
    s_um = (height - z[::-1]) * b
    r2 = (x[::-1] * b) ** 2
    s_um[0], r2[0] = 0.0, float(needle_radius_um) ** 2
    s_um = np.append(s_um[:-1], height * b)
    r2 = np.append(r2[:-1], 0.0)
    i_eq = int(np.argmax(r2))
    return {"s_um": s_um, "r2_um2": r2, "volume_um3": v_end * b**3, "height_um": float(height * b),
            "max_radius_um": float(np.sqrt(r2[i_eq])), "equator_s_um": float(s_um[i_eq]),
            "apex_radius_um": b, "bond": float(bond), "needle_radius_um": float(needle_radius_um)}


def cap_volume_um3(base_radius_um: float, height_um: float) -> float:
    """Volume of a spherical segment of base radius a and height h: π h (3a² + h²)/6."""
    return float(np.pi * height_um * (3.0 * base_radius_um**2 + height_um**2) / 6.0)


def cap_height_for_volume_um(base_radius_um: float, volume_um3: float) -> float:
    """Height of the pinned spherical segment holding ``volume_um3`` (real root of the cubic)."""
    if not volume_um3 > 0:
        raise ValueError(f"a pinned meniscus needs a positive volume, got {volume_um3:.6g} µm³")
    # h^3 + 3 a^2 h - 6 V / π = 0 has exactly one real root (monotone); Cardano.
    p, q = 3.0 * base_radius_um**2, -6.0 * volume_um3 / np.pi
    d = np.sqrt(q * q / 4.0 + p**3 / 27.0)
    return float(np.cbrt(-q / 2.0 + d) + np.cbrt(-q / 2.0 - d))


# ----------------------------------------------------------------------------------------
# Profiles and bodies
# ----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Profile:
    """Union of coaxial primitives, optionally clipped to ``s >= clip_min_um``."""

    parts: tuple
    clip_min_um: float | None = None
    breaks_um: tuple = ()  # extra quadrature break points (kinks where primitives cross)

    @property
    def support(self) -> tuple[float, float]:
        lo = min(p.support[0] for p in self.parts)
        hi = max(p.support[1] for p in self.parts)
        if self.clip_min_um is not None:
            lo = max(lo, self.clip_min_um)
        return lo, hi

    @property
    def max_radius_um(self) -> float:
        return max(p.max_radius_um for p in self.parts)

    def r2(self, s):
        """Squared radius (µm²) at axial positions ``s`` (µm); negative outside the body."""
        s = np.asarray(s)
        out = self.parts[0].r2(s)
        for p in self.parts[1:]:
            out = np.maximum(out, p.r2(s))
        if self.clip_min_um is not None:
            out = np.where(s >= self.clip_min_um, out, -1.0)
        return out

    def _nodes(self, max_panel_um: float):
        lo, hi = self.support
        bps = {lo, hi}
        for p in self.parts:
            bps.update(b for b in p.breakpoints() if lo < b < hi)
        bps.update(b for b in self.breaks_um if lo < b < hi)
        bps = np.array(sorted(bps))
        xs, ws = [], []
        for a, b in zip(bps[:-1], bps[1:]):
            if b - a <= 0:
                continue
            n = max(1, int(np.ceil((b - a) / max_panel_um)))
            edges = np.linspace(a, b, n + 1)
            half = 0.5 * np.diff(edges)
            mid = 0.5 * (edges[:-1] + edges[1:])
            xs.append((mid[:, None] + half[:, None] * _GL_X[None, :]).ravel())
            ws.append((half[:, None] * _GL_W[None, :]).ravel())
        if not xs:
            return np.zeros(0), np.zeros(0)
        return np.concatenate(xs), np.concatenate(ws)

    def volume_um3(self, max_panel_um: float = 1.0) -> float:
        """π ∫ r² ds (µm³), composite 8-point Gauss-Legendre."""
        x, w = self._nodes(max_panel_um)
        return float(np.pi * np.sum(w * np.maximum(self.r2(x), 0.0)))

    def centroid_um(self, max_panel_um: float = 1.0) -> float:
        """Axial centroid ∫ s r² ds / ∫ r² ds (µm, body frame)."""
        x, w = self._nodes(max_panel_um)
        r2 = np.maximum(self.r2(x), 0.0)
        return float(np.sum(w * x * r2) / np.sum(w * r2))

    def volume_nl(self) -> float:
        return self.volume_um3() / UM3_PER_NL


@dataclass(frozen=True)
class LiquidBody:
    """A liquid body of revolution placed in the nozzle frame.

    Attributes
    ----------
    kind : str
        "attached", "drop" or "satellite".
    profile : Profile
        r(s) in the body frame (µm).
    origin_z_um, origin_x_um : float
        Body origin in the nozzle frame (µm).
    axis_angle_rad : float
        Body axis direction from the nozzle axis, towards +x.
    spots : tuple of (s_um, half_along_um, half_across_um)
        Bright lens-spot ellipses (appearance only; no effect on the truth).
    """

    kind: str
    profile: Profile
    origin_z_um: float
    origin_x_um: float
    axis_angle_rad: float = 0.0
    spots: tuple = ()

    def volume_nl(self) -> float:
        return self.profile.volume_nl()

    def centroid_zx_um(self) -> tuple[float, float]:
        """Centroid in the nozzle frame (µm)."""
        s = self.profile.centroid_um()
        return (self.origin_z_um + s * np.cos(self.axis_angle_rad),
                self.origin_x_um + s * np.sin(self.axis_angle_rad))

    def shifted(self, dz_um: float, dx_um: float) -> "LiquidBody":
        return replace(self, origin_z_um=self.origin_z_um + dz_um, origin_x_um=self.origin_x_um + dx_um)
