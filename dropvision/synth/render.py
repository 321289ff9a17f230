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
    T = (T (1 - c_block) + c_block T_block') x shadows          (realism tier: holder block with its
                                                               reflections T_block', wedge, cuvette wall)
    I = backlight(r, c) * vignetting(r, c) * dust(r, c) * PSF(GaussianBlur(T, sigma)) * mist(r, c) * exposure
        (PSF: none, or a non-Gaussian point-spread function, `psf_kernel`: an Airy pattern's
        diffraction rings or a defocus disc)
    DN = quantise((Poisson(I * full_well) + N(0, read_noise)) / full_well * (2^bits - 1))
    colour: DN_c = quantise(... x gain_c) per channel (gains with BT.601 luma 1)

Every realism step is skipped when its option is off, so default renders are unchanged bit for bit.

Pixel (row, col) centres are integers; the pixel square is [row ± 0.5] x [col ± 0.5].
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from dropvision.synth.profiles import LiquidBody, Profile, QuadraticNeck

__all__ = ["CameraGeometry", "body_coverage", "spot_mask", "coverage_image", "Optics", "Renderer",
           "Structure", "polygon_coverage", "mist_map", "psf_kernel", "PSFS"]

#: Point-spread functions of the optics: Gaussian only (``blur_sigma_px``), or a non-Gaussian one
#: applied on top of it (`psf_kernel`).
PSFS = ("gaussian", "airy", "disc")


def psf_kernel(psf: str, radius_px: float, subsample: int = 5, rings: int = 6) -> np.ndarray | None:
    """Normalised, pixel-integrated kernel of a non-Gaussian point-spread function (float32).

    - ``"airy"``: the incoherent image of a point through a circular aperture,
      ``(2 J1(v) / v)^2`` with ``v = 3.8317 rho / radius_px`` (``radius_px``: the first dark
      ring's radius, ``0.61 lambda / NA``), cut at its ``rings``-th dark ring: diffraction rings on
      both sides of every edge, a core about ``0.34 radius_px`` wide (Gaussian sigma) and tails
      that fall as ``rho^-3`` (no finite second moment: no Gaussian blur model holds far out);
    - ``"disc"``: a uniform disc of radius ``radius_px`` (geometric defocus), its edge sampled
      ``subsample`` x ``subsample`` per pixel.

    Returns None for ``"gaussian"`` (no kernel: the Gaussian blur alone).
    """
    if psf == "gaussian":
        return None
    if psf not in PSFS:
        raise ValueError(f"psf must be one of {', '.join(PSFS)}, got {psf!r}")
    if not (np.isfinite(radius_px) and radius_px > 0):
        raise ValueError(f"psf {psf!r} needs a radius > 0 px, got {radius_px!r}")
    from scipy.special import j1, jn_zeros

    cut = float(jn_zeros(1, rings)[-1] / jn_zeros(1, 1)[0]) * radius_px if psf == "airy" else radius_px
    half = int(np.ceil(cut)) + 1
    offs = (np.arange(subsample) + 0.5) / subsample - 0.5
    ax = (np.arange(-half, half + 1)[:, None] + offs[None, :]).ravel()
    rho = np.hypot(ax[:, None], ax[None, :])
    if psf == "airy":
        v = 3.8317059702075125 * rho / radius_px
        with np.errstate(invalid="ignore", divide="ignore"):
            k = np.where(v > 1e-9, (2.0 * j1(v) / np.where(v > 1e-9, v, 1.0)) ** 2, 1.0)
        k = np.where(rho <= cut, k, 0.0)
    else:
        k = (rho <= radius_px).astype(float)
    n = 2 * half + 1
    k = k.reshape(n, subsample, n, subsample).mean(axis=(1, 3))
    return (k / k.sum()).astype(np.float32)


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


def _body_frame(body: LiquidBody, geom: CameraGeometry):
    o_r, o_c = geom.to_pixel(body.origin_z_um, body.origin_x_um)
    d, n = geom.direction(body.axis_angle_rad)
    return float(o_r), float(o_c), d, n


def _box(body: LiquidBody, geom: CameraGeometry, pad_px: float = 2.0):
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


def _inside(body: LiquidBody, geom: CameraGeometry, rows, cols, frame):
    o_r, o_c, d, n = frame
    px = geom.pixel_size_um
    dr, dc = rows - o_r, cols - o_c
    s = (dr * d[0] + dc * d[1]) * px
    y = (dr * n[0] + dc * n[1]) * px
    r2 = body.profile.r2(s)
    return y * y <= r2, r2, y


def body_coverage(body: LiquidBody, geom: CameraGeometry, supersample: int = 8, *, full: bool = False):
    """Exact-by-supersampling pixel coverage of one body.

    Parameters
    ----------
    body : LiquidBody
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


def spot_mask(body: LiquidBody, geom: CameraGeometry, min_spot_px: float = 1.2):
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
    vignetting : float
        Radial multiplicative fall-off of the light, separate from ``falloff``:
        1 - vignetting ρ³ (ρ = distance from the image centre / centre-to-corner distance),
        so the corners get (1 - vignetting) x the light.
    exposure : float
        Gain on the light before the sensor (> 1: the bright background clips at full scale).
    colour_gains : (gR, gG, gB) or None
        None: grey frames. Otherwise RGB frames, channel = gain x grey scene (each channel
        quantised and clipped on its own).
    demosaic_blur_px : float
        Extra Gaussian blur of the R and B channels (Bayer-like demosaicing; colour only).
    static_blur_px : float
        Extra Gaussian blur of the nozzle and the rig structures (holder block, reflections,
        wedge, cuvette wall): they lie out of the jet's focal plane (0: in focus, the plain image
        formation).
    psf : str
        Point-spread function (`PSFS`): ``"gaussian"`` (``blur_sigma_px`` alone), ``"airy"`` or
        ``"disc"`` of ``psf_radius_px`` (`psf_kernel`), convolved after the Gaussian blur, with the
        same transmission everywhere (the liquid, the nozzle and the rig structures alike).
    psf_radius_px : float
        The Airy pattern's first dark ring, or the defocus disc's radius (px).
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
    vignetting: float = 0.0
    exposure: float = 1.0
    colour_gains: tuple | None = None
    demosaic_blur_px: float = 0.0
    static_blur_px: float = 0.0
    psf: str = "gaussian"
    psf_radius_px: float = 0.0


class Renderer:
    """Renders states of one sequence; static parts (nozzle, backlight, dust) are computed once.

    Parameters
    ----------
    geom : CameraGeometry
    optics : Optics
    nozzle_outer_radius_um : float
    dust : list of (row, col, sigma_px, depth)
        Static dark specks (multiplicative Gaussian blobs).
    structures : list of Structure
        Static rig structures in focus (holder block, its reflections, wedge shadow, cuvette
        wall), composited into the transmission before the blur.
    """

    def __init__(self, geom: CameraGeometry, optics: Optics, nozzle_outer_radius_um: float, dust=(),
                 structures=()):
        if optics.bit_depth not in (8, 12, 16):
            raise ValueError(f"bit_depth must be 8, 12 or 16, got {optics.bit_depth!r}")
        self.geom, self.optics = geom, optics
        H, W = geom.shape
        reach = (H + W) * geom.pixel_size_um * 2
        nozzle = LiquidBody("nozzle", Profile((QuadraticNeck(-reach, 0.0, nozzle_outer_radius_um,
                                                       nozzle_outer_radius_um),)), 0.0, 0.0)
        self.nozzle_cov = coverage_image([nozzle], geom, optics.supersample)
        rr = (np.arange(H) - (H - 1) / 2.0) / ((H - 1) / 2.0)
        cc = (np.arange(W) - (W - 1) / 2.0) / ((W - 1) / 2.0)
        rho2 = (rr[:, None] ** 2 + cc[None, :] ** 2) / 2.0  # 1 at the corners
        self.backlight = optics.backlight_level * (1.0 - optics.falloff * rho2)
        if optics.vignetting > 0:
            self.backlight = self.backlight * (1.0 - optics.vignetting * (rho2 ** 1.5))
        self.struct_keep = self.struct_add = None
        self._nozzle_blurred = None  # the out-of-focus nozzle's transmission (static_blur_px), made once
        self.structure_info = []
        if structures:
            self._init_structures(structures, optics.supersample)
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
        self.psf = psf_kernel(optics.psf, optics.psf_radius_px)
        self.max_dn = float(2 ** optics.bit_depth - 1)
        self.dtype = np.uint8 if optics.bit_depth == 8 else np.uint16

    def _init_structures(self, structures, supersample: int) -> None:
        H, W = self.geom.shape
        K = max(1, min(int(supersample), 8 if H * W <= 400_000 else 4))
        hcov = np.zeros((H, W))
        hmap = np.zeros((H, W))
        shadow = np.ones((H, W))
        covs = []
        for st in structures:
            cov = polygon_coverage((H, W), [st.polygon], K)
            covs.append(cov)
            if cov.sum() > 0:
                rr, cc = np.mgrid[0:H, 0:W]
                w = cov.sum()
                self.structure_info.append((st, float((rr * cov).sum() / w), float((cc * cov).sum() / w)))
            else:
                self.structure_info.append((st, float("nan"), float("nan")))
        for st, cov in zip(structures, covs):
            if st.kind == "block":
                hmap = hmap * (1.0 - cov) + st.transmission * cov
                hcov = np.maximum(hcov, cov)
        for st, cov in zip(structures, covs):
            if st.kind == "reflection":
                cov = cov * hcov
                hmap = hmap * (1.0 - cov) + st.transmission * cov
            elif st.kind == "shadow":
                shadow = shadow * (1.0 - cov * (1.0 - st.transmission))
        self.struct_keep = (1.0 - hcov) * shadow
        self.struct_add = hcov * hmap * shadow
        if self.optics.static_blur_px > 0:  # out of focus: blurred once, composited after the liquid's blur
            s = float(np.hypot(self.optics.blur_sigma_px, self.optics.static_blur_px))
            self.struct_keep = cv2.GaussianBlur(self.struct_keep.astype(np.float32), (0, 0), s,
                                                borderType=cv2.BORDER_REPLICATE)
            self.struct_add = cv2.GaussianBlur(self.struct_add.astype(np.float32), (0, 0), s,
                                               borderType=cv2.BORDER_REPLICATE)

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
        if o.static_blur_px > 0:
            return self._intensity_static_blurred(cov, t_liq)
        trans = 1.0 - cov * (1.0 - t_liq) - self.nozzle_cov * (1.0 - o.nozzle_transmission)
        trans = np.clip(trans, 0.0, 1.0)
        if self.struct_keep is not None:
            trans = trans * self.struct_keep + self.struct_add
        trans = trans.astype(np.float32)
        if o.blur_sigma_px > 0:
            trans = cv2.GaussianBlur(trans, (0, 0), o.blur_sigma_px, borderType=cv2.BORDER_REPLICATE)
        return self._psf(trans) * self.static

    def _psf(self, trans: np.ndarray) -> np.ndarray:
        """The non-Gaussian point-spread function applied (unchanged without one)."""
        if self.psf is None:
            return trans
        return cv2.filter2D(np.asarray(trans, np.float32), -1, self.psf, borderType=cv2.BORDER_REPLICATE)

    def _intensity_static_blurred(self, cov: np.ndarray, t_liq: np.ndarray) -> np.ndarray:
        """`intensity` with the nozzle and structures out of focus: the liquid's transmission
        blurred by ``blur_sigma_px``, times the nozzle's and the structures' blurred further by
        ``static_blur_px`` (layers in different planes multiply)."""
        o = self.optics
        if self._nozzle_blurred is None:
            s = float(np.hypot(o.blur_sigma_px, o.static_blur_px))
            t_noz = (1.0 - self.nozzle_cov * (1.0 - o.nozzle_transmission)).astype(np.float32)
            self._nozzle_blurred = cv2.GaussianBlur(t_noz, (0, 0), s, borderType=cv2.BORDER_REPLICATE)
        trans = np.clip(1.0 - cov * (1.0 - t_liq), 0.0, 1.0).astype(np.float32)
        if o.blur_sigma_px > 0:
            trans = cv2.GaussianBlur(trans, (0, 0), o.blur_sigma_px, borderType=cv2.BORDER_REPLICATE)
        trans = trans * self._nozzle_blurred
        if self.struct_keep is not None:
            trans = trans * self.struct_keep + self.struct_add
        return self._psf(trans) * self.static

    def render(self, bodies, rng: np.random.Generator, mist=()) -> np.ndarray:
        """One quantised frame (uint8 or uint16; (H, W, 3) RGB with ``colour_gains``).

        ``mist``: out-of-focus droplets of this frame, (row, col, diameter_px, sigma_px,
        attenuation) each (see :func:`mist_map`)."""
        o = self.optics
        img = self.intensity(bodies)
        if len(mist):
            img = img * mist_map(self.geom.shape, mist)
        if o.exposure != 1.0:
            img = img * o.exposure
        if o.noise:
            e = rng.poisson(np.maximum(img, 0.0) * o.full_well_e).astype(np.float32)
            if o.read_noise_e > 0:
                e += rng.normal(0.0, o.read_noise_e, size=e.shape).astype(np.float32)
            img = e / o.full_well_e
        if o.colour_gains is not None:
            chans = []
            for k, g in enumerate(o.colour_gains):
                c = np.asarray(img, np.float32) * np.float32(g)
                if o.demosaic_blur_px > 0 and k != 1:
                    c = cv2.GaussianBlur(c, (0, 0), o.demosaic_blur_px, borderType=cv2.BORDER_REPLICATE)
                chans.append(np.rint(np.clip(c * self.max_dn, 0.0, self.max_dn)).astype(self.dtype))
            return np.stack(chans, axis=-1)
        dn = np.rint(np.clip(img * self.max_dn, 0.0, self.max_dn))
        return dn.astype(self.dtype)


@dataclass(frozen=True)
class Structure:
    """A static rig structure in focus, as a polygon in canonical pixel coordinates.

    kind: ``"block"`` (opaque-ish occluder: replaces the scene's transmission by its own),
    ``"reflection"`` (bright streak/patch inside a block: replaces the block's transmission
    where both overlap), ``"shadow"`` (multiplies the transmission: wedge, cuvette wall).
    ``name`` and ``body_class`` go to truth_bodies.csv."""

    name: str
    kind: str
    polygon: tuple  # ((row, col), ...)
    transmission: float
    body_class: str = "holder"


def polygon_coverage(shape, polygons, K: int = 8) -> np.ndarray:
    """Area coverage (float64 in [0, 1]) of the union of polygons given as ((row, col), ...)
    in pixel coordinates (pixel centres integers), by filling a K x K supersampled raster with
    sub-pixel vertex precision (cv2.fillPoly, 8 fractional bits) and averaging."""
    H, W = int(shape[0]), int(shape[1])
    canvas = np.zeros((H * K, W * K), np.uint8)
    shift = 8
    lim = 4.0 * (H + W) * K
    pts = []
    for poly in polygons:
        a = np.asarray(poly, float)
        u = np.clip((a + 0.5) * K - 0.5, -lim, lim)  # supersampled coordinates, (row, col)
        pts.append(np.round(u[:, ::-1] * (1 << shift)).astype(np.int32))
    cv2.fillPoly(canvas, pts, 1, lineType=cv2.LINE_8, shift=shift)
    return canvas.reshape(H, K, W, K).sum(axis=(1, 3), dtype=np.uint16) / float(K * K)


def mist_map(shape, mist) -> np.ndarray:
    """Multiplicative transmission (float64) of out-of-focus mist droplets: each a disc of
    ``diameter_px`` blurred by a Gaussian of ``sigma_px``, scaled so that its darkest point
    removes ``attenuation`` of the light: 1 - attenuation x blob / max(blob)."""
    H, W = int(shape[0]), int(shape[1])
    out = np.ones((H, W))
    for r, c, dia, sig, att in mist:
        rad = 0.5 * dia
        half = int(np.ceil(rad + 4.0 * sig)) + 1
        r0, r1 = int(np.floor(r)) - half, int(np.floor(r)) + half + 1
        c0, c1 = int(np.floor(c)) - half, int(np.floor(c)) + half + 1
        yy, xx = np.mgrid[r0:r1, c0:c1]
        disc = np.clip(rad + 0.5 - np.hypot(yy - r, xx - c), 0.0, 1.0).astype(np.float32)
        blob = cv2.GaussianBlur(disc, (0, 0), float(sig), borderType=cv2.BORDER_CONSTANT).astype(float)
        m = blob.max()
        if m <= 0:
            continue
        fac = 1.0 - att * blob / m
        R0, R1, C0, C1 = max(r0, 0), min(r1, H), max(c0, 0), min(c1, W)
        if R0 >= R1 or C0 >= C1:
            continue
        out[R0:R1, C0:C1] *= fac[R0 - r0:R1 - r0, C0 - c0:C1 - c0]
    return out
