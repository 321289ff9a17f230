"""Known hydraulic elements of the ECM, Eq. (2): pipe inertances and resistances.

The nozzle pipe (inertance L_N, resistance R_N, radius = half the nozzle inner diameter)
and the equivalent reservoir-side channel (L_R, R_R) follow from the ink and the geometry
by Eq. (2) for a laminar pipe flow. :func:`hydraulics_from_dimensions` is the one place that
turns ink properties and dimensions into :class:`Hydraulics`; the synthetic physics
(:mod:`identify.physics`), the training dataset (:mod:`identify.dataset`) and the ECM
identification (:mod:`identify.ecm_fit`, :func:`hydraulics_from_geometry`) all use it.

Units: SI for the elements (kg/m^4, kg/(m^4 s)); the dimensions enter as the printhead's
data sheets give them (µm, mm, mPa s).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from identify.ecm import UM

__all__ = [
    "DEFAULT_INK",
    "Hydraulics",
    "NozzleGeometry",
    "pipe_inertance",
    "pipe_resistance",
    "hydraulics_from_dimensions",
    "hydraulics_from_geometry",
]

#: Default ink of the synthetic physics (colour ink of Table 1).
DEFAULT_INK = {"name": "colour ink", "density_kg_m3": 993.0, "viscosity_mPa_s": 2.21, "surface_tension_mN_m": 28.72}


def pipe_resistance(viscosity_pa_s: float, length_m: float, radius_m: float) -> float:
    """Hydraulic resistance of a laminar pipe flow, Eq. (2): R = 8 µ l / (π r^4).

    Parameters
    ----------
    viscosity_pa_s : float
        Dynamic viscosity µ (Pa s).
    length_m, radius_m : float
        Pipe length l and radius r (m).

    Returns
    -------
    float
        Resistance (kg/(m^4 s)).
    """
    return 8.0 * viscosity_pa_s * length_m / (np.pi * radius_m**4)


def pipe_inertance(density_kg_m3: float, length_m: float, radius_m: float) -> float:
    """Hydraulic inertance of a pipe, Eq. (2): L = ρ l / (π r^2).

    Parameters
    ----------
    density_kg_m3 : float
        Density ρ (kg/m^3).
    length_m, radius_m : float
        Pipe length l and radius r (m).

    Returns
    -------
    float
        Inertance (kg/m^4).
    """
    return density_kg_m3 * length_m / (np.pi * radius_m**2)


class Hydraulics(NamedTuple):
    """Known hydraulic elements of Eq. (2) (SI): unpacks as ``LN, RN, LR, RR``.

    LN, LR in kg/m^4 (nozzle pipe, reservoir side); RN, RR in kg/(m^4 s).
    """

    LN: float
    RN: float
    LR: float
    RR: float


def hydraulics_from_dimensions(
    density_kg_m3: float,
    viscosity_mpa_s: float,
    nozzle_inner_diameter_um: float,
    nozzle_length_mm: float,
    reservoir_radius_um: float,
    reservoir_length_mm: float,
) -> Hydraulics:
    """LN, RN, LR, RR of Eq. (2) from the ink and the nozzle/reservoir-channel dimensions.

    Parameters
    ----------
    density_kg_m3 : float
        Ink density (kg/m^3).
    viscosity_mpa_s : float
        Ink dynamic viscosity (mPa s).
    nozzle_inner_diameter_um : float
        Nozzle inner diameter (µm); the pipe radius of LN, RN is half of it.
    nozzle_length_mm : float
        Nozzle pipe length (mm).
    reservoir_radius_um, reservoir_length_mm : float
        Radius (µm) and length (mm) of the equivalent reservoir-side channel (LR, RR).

    Returns
    -------
    Hydraulics
        ``(LN, RN, LR, RR)`` in kg/m^4 and kg/(m^4 s).
    """
    rho = density_kg_m3
    mu = viscosity_mpa_s * 1e-3
    r_n = nozzle_inner_diameter_um * UM / 2.0
    l_n = nozzle_length_mm * 1e-3
    r_r = reservoir_radius_um * UM
    l_r = reservoir_length_mm * 1e-3
    return Hydraulics(
        LN=pipe_inertance(rho, l_n, r_n),
        RN=pipe_resistance(mu, l_n, r_n),
        LR=pipe_inertance(rho, l_r, r_r),
        RR=pipe_resistance(mu, l_r, r_r),
    )


@dataclass(frozen=True)
class NozzleGeometry:
    """Nozzle pipe and reservoir-side channel (defaults: the team's synthetic physics).

    Parameters
    ----------
    inner_diameter_um : float
        Nozzle inner diameter (µm); the pipe radius of LN, RN is half of it.
    length_mm : float
        Nozzle pipe length (mm).
    reservoir_radius_um, reservoir_length_mm : float
        Radius (µm) and length (mm) of the equivalent reservoir-side channel (LR, RR).
    """

    inner_diameter_um: float = 200.0
    length_mm: float = 5.0
    reservoir_radius_um: float = 94.0
    reservoir_length_mm: float = 20.0

    def __post_init__(self) -> None:
        for name in ("inner_diameter_um", "length_mm", "reservoir_radius_um", "reservoir_length_mm"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"nozzle geometry {name} must be a positive number, got {value!r}")


def _ink_value(ink: Any, key: str) -> float:
    value = ink.get(key) if isinstance(ink, Mapping) else getattr(ink, key, None)
    if value is None:
        raise ValueError(f"ink: missing {key!r} (need density_kg_m3 and viscosity_mPa_s)")
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"ink: {key} must be a positive number, got {value!r}")
    return value


def hydraulics_from_geometry(ink: Any = None, geometry: NozzleGeometry | None = None) -> Hydraulics:
    """LN, RN, LR, RR from Eq. (2) for an ink and a nozzle geometry.

    Parameters
    ----------
    ink : mapping or object, optional
        With ``density_kg_m3`` (kg/m^3) and ``viscosity_mPa_s`` (mPa s), e.g. the ``ink``
        block of sequence.json. Default :data:`DEFAULT_INK`.
    geometry : NozzleGeometry, optional
        Default ``NozzleGeometry()`` (200 µm x 5 mm nozzle, 94 µm x 20 mm reservoir side).

    Returns
    -------
    Hydraulics
        ``(LN, RN, LR, RR)`` in kg/m^4 and kg/(m^4 s).
    """
    ink = DEFAULT_INK if ink is None else ink
    geometry = NozzleGeometry() if geometry is None else geometry
    return hydraulics_from_dimensions(
        _ink_value(ink, "density_kg_m3"),
        _ink_value(ink, "viscosity_mPa_s"),
        geometry.inner_diameter_um,
        geometry.length_mm,
        geometry.reservoir_radius_um,
        geometry.reservoir_length_mm,
    )
