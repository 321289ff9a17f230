"""Small exact-coverage drawings for the measure tests (independent of dropvision.synth).

Bodies of revolution about a (possibly tilted) axis, seen in orthographic backlight: a sample
point is dark when its distance ``s`` from the axis is below the body's radius ``r(z)`` at its
axial position ``z``.  Coverage by 8x8 supersampling, then a lens spot, Gaussian blur,
illumination fall-off, noise and quantisation.  Volumes are analytic.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage


def sphere(zc_px, r_px, sc_px=0.0):
    """Sphere on the axis (centre at axial distance zc from the tip plane)."""
    return {"kind": "spheroid", "zc": zc_px, "a": r_px, "c": r_px, "sc": sc_px}


def spheroid(zc_px, a_px, c_px, sc_px=0.0):
    """Spheroid, equatorial radius a, polar semi-axis c (along the axis)."""
    return {"kind": "spheroid", "zc": zc_px, "a": a_px, "c": c_px, "sc": sc_px}


def cap(base_r_px, h_px):
    """Spherical cap hanging below the tip plane (base radius, height)."""
    return {"kind": "cap", "a": base_r_px, "h": h_px}


def cylinder(z0_px, z1_px, r_px):
    """Liquid cylinder from z0 to z1 along the axis."""
    return {"kind": "cyl", "z0": z0_px, "z1": z1_px, "r": r_px}


def volume_px3(body) -> float:
    """Analytic volume of a body (pixel^3)."""
    if body["kind"] == "spheroid":
        return 4.0 / 3.0 * np.pi * body["a"] ** 2 * body["c"]
    if body["kind"] == "cap":
        a, h = body["a"], body["h"]
        return np.pi * h * (3 * a * a + h * h) / 6.0
    return np.pi * body["r"] ** 2 * (body["z1"] - body["z0"])


def _inside(body, z, s):
    if body["kind"] == "spheroid":
        return ((z - body["zc"]) / body["c"]) ** 2 + ((s - body["sc"]) / body["a"]) ** 2 < 1.0
    if body["kind"] == "cap":
        a, h = body["a"], body["h"]
        rc = (a * a + h * h) / (2 * h)
        r2 = rc * rc - (z - (h - rc)) ** 2
        return (z >= 0) & (z <= h) & (s * s < r2)
    return (z >= body["z0"]) & (z <= body["z1"]) & (np.abs(s) < body["r"])


def render(
    shape=(200, 160),
    bodies=(),
    tip_row=40.3,
    axis_col=80.2,
    tilt_deg=0.0,
    nozzle_r_out=20.0,
    nozzle_r_in=None,
    nozzle_level=0.05,
    liquid_level=0.12,
    spot=0.6,
    blur_px=1.0,
    falloff=0.0,
    noise=0.0,
    bits=8,
    level=0.8,
    dust=(),
    seed=0,
    ss=8,
):
    """Render a frame (uint8/uint16) of the nozzle and liquid bodies.

    Returns the image; the tip plane passes through (tip_row, axis_col) perpendicular to the axis.
    """
    h, w = shape
    rng = np.random.default_rng(seed)
    th = np.radians(tilt_deg)
    off = (np.arange(ss) + 0.5) / ss - 0.5
    ys = (np.arange(h)[:, None] + off[None, :]).ravel()
    xs = (np.arange(w)[:, None] + off[None, :]).ravel()
    Y, X = np.meshgrid(ys, xs, indexing="ij")
    dx, dy = X - axis_col, Y - tip_row
    z = dx * np.sin(th) + dy * np.cos(th)
    s = dx * np.cos(th) - dy * np.sin(th)
    noz = (z < 0) & (np.abs(s) < nozzle_r_out)
    liq = np.zeros_like(noz)
    spot_img = np.zeros(Y.shape, float)
    for b in bodies:
        inside = _inside(b, z, s)
        liq |= inside
        if spot > 0 and b["kind"] == "spheroid":
            rr = ((z - b["zc"]) ** 2 + (s - b["sc"]) ** 2) / (0.3 * b["a"]) ** 2
            spot_img = np.maximum(spot_img, np.where(inside, spot * np.exp(-rr), 0.0))
    liq &= ~noz
    t = np.ones(Y.shape)
    t = np.where(liq, liquid_level + spot_img, t)
    t = np.where(noz, nozzle_level, t)
    t = t.reshape(h, ss, w, ss).mean(axis=(1, 3))
    if blur_px > 0:
        t = ndimage.gaussian_filter(t, blur_px, mode="nearest")
    for (r0, c0, rad, att) in dust:
        yy, xx = np.mgrid[0:h, 0:w]
        t = t * np.where((yy - r0) ** 2 + (xx - c0) ** 2 < rad * rad, att, 1.0)
    yy, xx = np.mgrid[0:h, 0:w]
    rr = ((yy - h / 2) ** 2 + (xx - w / 2) ** 2) / ((h / 2) ** 2 + (w / 2) ** 2)
    illum = level * (1.0 - falloff * rr)
    maxv = 2**bits - 1
    img = t * illum * maxv + noise * maxv * rng.standard_normal((h, w))
    img = np.clip(np.round(img), 0, maxv)
    return img.astype(np.uint8 if bits <= 8 else np.uint16)
