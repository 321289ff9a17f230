"""Rendering of the analytic silhouettes into strobe images (orthographic telecentric view).

A body of revolution whose axis lies in the image plane projects to the region
|across| <= r(along) exactly, so a pixel's liquid coverage is the area fraction of the pixel
square inside that region. It is computed by supersampling (``supersample`` x ``supersample``
points per pixel) only where it matters: a half-pixel lattice first classifies pixels as fully
inside, fully outside or mixed (lattice points disagree, or a lattice point is within 1 px of
the silhouette edge across the axis, which also catches sub-pixel threads); the mixed pixels
and their neighbours are supersampled.

Image formation per frame (intensities as fractions of full scale):

    T = 1 - c_liquid (1 - T_liquid') - c_nozzle (1 - T_nozzle)   (T_liquid' brightened by the lens spot)
    I = backlight(r, c) * dust(r, c) * GaussianBlur(T, sigma)
    DN = quantise((Poisson(I * full_well) + N(0, read_noise)) / full_well * (2^bits - 1))

Pixel (row, col) centres are integers; the pixel square is [row ± 0.5] x [col ± 0.5].
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from dropvision.synth.shapes import Body, Profile, QuadraticNeck

__all__ = ["CameraGeometry", "body_coverage", "spot_mask", "coverage_image", "Optics", "Renderer"]


@dataclass(frozen=True)
class CameraGeometry:
    """Where the nozzle frame lies in the (canonical) image.

    Attributes
    ----------
    pixel_size_um : float
    shape : (rows, cols)
    tip_row, axis_col : float
        Pixel coordinates of the centre of the nozzle tip (pixel centres are integers).
    tilt_deg : float
        Angle of the nozzle axis from the image's downward direction, positive when the axis
        leans towards larger columns (to the right) going down.
    """

    pixel_size_um: float
    shape: tuple[int, int]
    tip_row: float
    axis_col: float
    tilt_deg: float = 0.0

    def direction(self, extra_angle_rad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Unit vectors (row, col) along an axis at tilt + extra angle, and across it (+x)."""
        a = np.deg2rad(self.tilt_deg) + extra_angle_rad
        return np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])

    def to_pixel(self, z_um, x_um) -> tuple[np.ndarray, np.ndarray]:
        """Nozzle-frame point (µm) -> (row, col)."""
        d, n = self.direction()
        z, x = np.asarray(z_um) / self.pixel_size_um, np.asarray(x_um) / self.pixel_size_um
        return self.tip_row + z * d[0] + x * n[0], self.axis_col + z * d[1] + x * n[1]


def _body_frame(body: Body, geom: CameraGeometry):
    o_r, o_c = geom.to_pixel(body.origin_z_um, body.origin_x_um)
    d, n = geom.direction(body.axis_angle_rad)
    return float(o_r), float(o_c), d, n


def _box(body: Body, geom: CameraGeometry, pad_px: float = 2.0):
    """Pixel index box (r0, r1, c0, c1), inclusive-exclusive, clipped; None if outside."""
    o_r, o_c, d, n = _body_frame(body, geom)
    lo, hi = body.profile.support
    rmax = body.profile.max_radius_um
    px = geom.pixel_size_um
    pts = []
    for s in (lo, hi):
        for y in (-rmax, rmax):
            pts.append((o_r + (s * d[0] + y * n[0]) / px, o_c + (s * d[1] + y * n[1]) / px))
    pts = np.array(pts)
    r0 = int(np.floor(pts[:, 0].min() - pad_px))
    r1 = int(np.ceil(pts[:, 0].max() + pad_px)) + 1
    c0 = int(np.floor(pts[:, 1].min() - pad_px))
    c1 = int(np.ceil(pts[:, 1].max() + pad_px)) + 1
    H, W = geom.shape
    r0, r1, c0, c1 = max(r0, 0), min(r1, H), max(c0, 0), min(c1, W)
    if r0 >= r1 or c0 >= c1:
        return None
    return r0, r1, c0, c1


def _inside(body: Body, geom: CameraGeometry, rows, cols, frame):
    o_r, o_c, d, n = frame
    px = geom.pixel_size_um
    dr, dc = rows - o_r, cols - o_c
    s = (dr * d[0] + dc * d[1]) * px
    y = (dr * n[0] + dc * n[1]) * px
    r2 = body.profile.r2(s)
    return y * y <= r2, r2, y


def body_coverage(body: Body, geom: CameraGeometry, supersample: int = 8, *, full: bool = False):
    """Exact-by-supersampling pixel coverage of one body.

    Parameters
    ----------
    body : Body
    geom : CameraGeometry
    supersample : int
        Samples per pixel side for mixed pixels.
    full : bool
        Supersample every pixel of the box (slow reference; for tests).

    Returns
    -------
    (r0, c0, patch) or None
        ``patch`` (float64, values in [0, 1]) covers rows r0.. and cols c0.. of the image.
    """
    box = _box(body, geom)
    if box is None:
        return None
    r0, r1, c0, c1 = box
    nr, nc = r1 - r0, c1 - c0
    frame = _body_frame(body, geom)
    K = int(supersample)
    offs = (np.arange(K) + 0.5) / K - 0.5
    if full:
        rows = (np.arange(r0, r1)[:, None] + offs[None, :]).ravel()
        cols = (np.arange(c0, c1)[:, None] + offs[None, :]).ravel()
        inside, _, _ = _inside(body, geom, rows[:, None], cols[None, :], frame)
        return r0, c0, inside.reshape(nr, K, nc, K).mean(axis=(1, 3))
    # half-pixel lattice: points r0-0.5 .. r1-0.5 step 0.5
    lr = r0 - 0.5 + 0.5 * np.arange(2 * nr + 1)
    lc = c0 - 0.5 + 0.5 * np.arange(2 * nc + 1)
    inside, r2, y = _inside(body, geom, lr[:, None], lc[None, :], frame)
    edge_px = 1.0 * geom.pixel_size_um
    near = (r2 > 0) & (np.abs(np.sqrt(np.maximum(r2, 0.0)) - np.abs(y)) < edge_px)
    any_in = np.zeros((nr, nc), bool)
    all_in = np.ones((nr, nc), bool)
    any_near = np.zeros((nr, nc), bool)
    for i in range(3):
        for j in range(3):
            blk = inside[i:i + 2 * nr:2, j:j + 2 * nc:2]
            any_in |= blk
            all_in &= blk
            any_near |= near[i:i + 2 * nr:2, j:j + 2 * nc:2]
    mixed = (any_in & ~all_in) | any_near
    mixed = cv2.dilate(mixed.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    cov = (all_in & ~mixed).astype(float)
    ii, jj = np.nonzero(mixed)
    if ii.size:
        sub_r = (ii + r0)[:, None, None] + offs[None, :, None]
        sub_c = (jj + c0)[:, None, None] + offs[None, None, :]
        ins, _, _ = _inside(body, geom, sub_r, sub_c, frame)
        cov[ii, jj] = ins.reshape(ii.size, -1).mean(axis=1)
    return r0, c0, cov


def spot_mask(body: Body, geom: CameraGeometry, min_spot_px: float = 1.2):
    """Soft-edged bright-spot ellipses of a body (appearance only): (r0, c0, patch) or None.

    Spots whose across semi-axis is below ``min_spot_px`` pixels are not drawn.
    """
    if not body.spots:
        return None
    box = _box(body, geom, pad_px=1.0)
    if box is None:
        return None
    r0, r1, c0, c1 = box
    o_r, o_c, d, n = _body_frame(body, geom)
    px = geom.pixel_size_um
    rows = np.arange(r0, r1)[:, None] - o_r
    cols = np.arange(c0, c1)[None, :] - o_c
    s = (rows * d[0] + cols * d[1]) * px
    y = (rows * n[0] + cols * n[1]) * px
    out = np.zeros((r1 - r0, c1 - c0))
    found = False
    for s0, ha, hb in body.spots:
        if hb / px < min_spot_px:
            continue
        rho = np.sqrt(((s - s0) / ha) ** 2 + (y / hb) ** 2)
        width = max(1.0 * px / hb, 1e-6)  # ~1 px soft edge
        out = np.maximum(out, np.clip((1.0 - rho) / width + 0.5, 0.0, 1.0))
        found = True
    return (r0, c0, out) if found else None


def _paste(target, patch_info, mode="add"):
    if patch_info is None:
        return
    r0, c0, patch = patch_info
    view = target[r0:r0 + patch.shape[0], c0:c0 + patch.shape[1]]
    if mode == "add":
        view += patch
    else:
        np.maximum(view, patch, out=view)


def coverage_image(bodies, geom: CameraGeometry, supersample: int = 8, *, full: bool = False) -> np.ndarray:
    """Liquid coverage of disjoint bodies (sum, clipped to 1), float64 (rows, cols)."""
    cov = np.zeros(geom.shape)
    for b in bodies:
        _paste(cov, body_coverage(b, geom, supersample, full=full))
    return np.minimum(cov, 1.0)


@dataclass(frozen=True)
class Optics:
    """Illumination, optics and sensor of the synthetic strobe camera.

    Attributes
    ----------
    blur_sigma_px : float
        Gaussian optical blur (0: none).
    falloff : float
        Backlight vignetting: corner brightness = (1 - falloff) x centre (smooth, quadratic).
    backlight_level : float
        Centre brightness as a fraction of full scale.
    liquid_transmission, nozzle_transmission : float
        Fraction of the backlight seen through the liquid / nozzle.
    spot_transmission : float
        Brightness of the lens spot at the centre of large liquid bodies.
    full_well_e, read_noise_e : float
        Shot noise (Poisson) scale and Gaussian read noise in electrons; noise = False
        disables both.
    bit_depth : int
        8, 12 (in 16-bit containers) or 16.
    supersample : int
    """

    blur_sigma_px: float = 0.8
    falloff: float = 0.1
    backlight_level: float = 0.88
    liquid_transmission: float = 0.10
    nozzle_transmission: float = 0.07
    spot_transmission: float = 0.80
    full_well_e: float = 10000.0
    read_noise_e: float = 8.0
    noise: bool = True
    bit_depth: int = 8
    supersample: int = 8


class Renderer:
    """Renders states of one sequence; static parts (nozzle, backlight, dust) are computed once.

    Parameters
    ----------
    geom : CameraGeometry
    optics : Optics
    nozzle_outer_radius_um : float
    dust : list of (row, col, sigma_px, depth)
        Static dark specks (multiplicative Gaussian blobs).
    """

    def __init__(self, geom: CameraGeometry, optics: Optics, nozzle_outer_radius_um: float, dust=()):
        if optics.bit_depth not in (8, 12, 16):
            raise ValueError(f"bit_depth must be 8, 12 or 16, got {optics.bit_depth!r}")
        self.geom, self.optics = geom, optics
        H, W = geom.shape
        reach = (H + W) * geom.pixel_size_um * 2
        nozzle = Body("nozzle", Profile((QuadraticNeck(-reach, 0.0, nozzle_outer_radius_um,
                                                       nozzle_outer_radius_um),)), 0.0, 0.0)
        self.nozzle_cov = coverage_image([nozzle], geom, optics.supersample)
        rr = (np.arange(H) - (H - 1) / 2.0) / ((H - 1) / 2.0)
        cc = (np.arange(W) - (W - 1) / 2.0) / ((W - 1) / 2.0)
        rho2 = (rr[:, None] ** 2 + cc[None, :] ** 2) / 2.0  # 1 at the corners
        self.backlight = optics.backlight_level * (1.0 - optics.falloff * rho2)
        dust_map = np.ones((H, W))
        yy, xx = np.mgrid[0:H, 0:W]
        for r, c, sig, depth in dust:
            r0, r1 = max(int(r - 5 * sig), 0), min(int(r + 5 * sig) + 2, H)
            c0, c1 = max(int(c - 5 * sig), 0), min(int(c + 5 * sig) + 2, W)
            if r0 >= r1 or c0 >= c1:
                continue
            g = np.exp(-((yy[r0:r1, c0:c1] - r) ** 2 + (xx[r0:r1, c0:c1] - c) ** 2) / (2 * sig * sig))
            dust_map[r0:r1, c0:c1] *= 1.0 - depth * g
        self.dust_map = dust_map
        self.static = self.backlight * dust_map
        self.max_dn = float(2 ** optics.bit_depth - 1)
        self.dtype = np.uint8 if optics.bit_depth == 8 else np.uint16

    def intensity(self, bodies) -> np.ndarray:
        """Noise-free intensity (fraction of full scale) of a frame with these liquid bodies."""
        o, g = self.optics, self.geom
        cov = np.zeros(g.shape)
        spot = np.zeros(g.shape)
        for b in bodies:
            _paste(cov, body_coverage(b, g, o.supersample))
            _paste(spot, spot_mask(b, g), mode="max")
        cov = np.minimum(cov, 1.0)
        t_liq = o.liquid_transmission + (o.spot_transmission - o.liquid_transmission) * spot
        trans = 1.0 - cov * (1.0 - t_liq) - self.nozzle_cov * (1.0 - o.nozzle_transmission)
        trans = np.clip(trans, 0.0, 1.0).astype(np.float32)
        if o.blur_sigma_px > 0:
            trans = cv2.GaussianBlur(trans, (0, 0), o.blur_sigma_px, borderType=cv2.BORDER_REPLICATE)
        return trans * self.static

    def render(self, bodies, rng: np.random.Generator) -> np.ndarray:
        """One quantised frame (uint8 or uint16)."""
        o = self.optics
        img = self.intensity(bodies)
        if o.noise:
            e = rng.poisson(np.maximum(img, 0.0) * o.full_well_e).astype(np.float32)
            if o.read_noise_e > 0:
                e += rng.normal(0.0, o.read_noise_e, size=e.shape).astype(np.float32)
            img = e / o.full_well_e
        dn = np.rint(np.clip(img * self.max_dn, 0.0, self.max_dn))
        return dn.astype(self.dtype)
