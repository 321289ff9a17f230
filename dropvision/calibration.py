"""Calibration of a strobe sequence from its own frames.

- Background (illumination) `estimate_background`: from a few frames spread over the
  sequence, the pixels away from any dark body are averaged, and a smooth 2-D polynomial is
  fitted to them (robustly); it carries the backlight fall-off under the nozzle and the liquid.
  Where the frames show a static, partly transparent speck (dust on the optics), the measured
  attenuation is folded into the background (it is then invisible in the transmission);
  specks that stay dark in every frame and are not joined to the nozzle are *opaque dust*,
  removed from every dark mask.  One frame only: the polynomial alone, no dust detection.
- Nozzle `find_nozzle`: the dark body touching the top edge (canonical orientation); its
  straight part is a run of rows of constant width of the dark run holding the nozzle (followed
  up from the body's lowest row): the one of the expected outer width when the metadata gives
  it, else the narrowest (a holder block above it is wider; `_straight_walls`); the outer walls'
  sub-pixel 50 % edges over those rows give the midline (axis column, tilt) and the outer width
  (cross-check of the pixel size).  Walls shorter than 10 rows (a nozzle barely protruding from
  its holder) take the tilt from the holder's face instead, and with no straight walls at all
  the part of the body below the face is the nozzle (`_face_nozzle`: the axis is perpendicular
  to the face).
- Tip plane `find_tip`: in a frame with the meniscus at rest, the vertical transmission
  profiles of the wall annulus columns (between the inner and outer radius) cross 50 % at the
  tip; when liquid hangs below the walls (annulus dark below the straight part) the tip is the
  row where the silhouette leaves the straight walls.
- Liquid interior level `interior_level`: median transmission inside liquid bodies (their
  bright lens spot excluded); the edge threshold is half-way between it and 1.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import cv2
import numpy as np

from dropvision.segmentation import edge_threshold, fill_holes
from dropvision.special import erf
from dropvision.volume import runs, subpixel_edges


class CalibrationError(ValueError):
    """The frames do not allow a calibration (no nozzle found...)."""


class CalibrationWarning(UserWarning):
    """A calibration cross-check disagrees (e.g. pixel size vs nozzle width)."""


# ----------------------------------------------------------------------------- background
@dataclass
class BackgroundModel:
    """Illumination estimate for the whole frame.

    Attributes
    ----------
    background : ndarray of float32
        Expected grey level of an empty pixel (dust attenuation included).
    opaque : ndarray of bool or None
        Opaque static specks (never liquid).
    n_frames : int
        Frames used.
    dust_pixels : int
        Pixels with a static attenuation (corrected or opaque).
    falloff : float
        1 - min/max of the smooth illumination over the frame.
    residual : float
        Robust spread (1.4826 MAD) of the background pixels' relative departure from the model,
        averaged over 4 x 4 blocks (the model's misfit more than the pixel noise): how far the
        local background may be off (transmission units).
    """

    background: np.ndarray
    opaque: np.ndarray | None
    n_frames: int
    dust_pixels: int
    falloff: float
    residual: float = 0.0


def _poly_terms(x: np.ndarray, y: np.ndarray, degree: int) -> np.ndarray:
    return np.stack([x**i * y**j for i in range(degree + 1) for j in range(degree + 1 - i)], axis=-1)


def _fit_smooth(values: np.ndarray, valid: np.ndarray, degree: int, step: int) -> np.ndarray:
    h, w = values.shape
    ys, xs = np.mgrid[0:h:step, 0:w:step]
    v = values[ys, xs]
    ok = valid[ys, xs]
    sx, sy = 2.0 / max(w - 1, 1), 2.0 / max(h - 1, 1)
    x = xs[ok] * sx - 1.0
    y = ys[ok] * sy - 1.0
    v = v[ok].astype(np.float64)
    if v.size < 50:
        raise CalibrationError("too few background pixels to estimate the illumination")
    a = _poly_terms(x, y, degree)
    keep = np.ones(v.size, bool)
    coef = None
    for _ in range(4):
        coef, *_ = np.linalg.lstsq(a[keep], v[keep], rcond=None)
        r = v - a @ coef
        sigma = 1.4826 * np.median(np.abs(r[keep])) + 1e-3 * np.median(v)
        new = np.abs(r) < 4 * sigma
        if np.array_equal(new, keep):
            break
        keep = new
    # evaluate on a coarse grid and interpolate bilinearly (the surface is a smooth polynomial)
    g = 8
    cw, ch = (w + g - 1) // g + 1, (h + g - 1) // g + 1
    gx = np.arange(cw) * g * sx - 1.0
    gy = np.arange(ch) * g * sy - 1.0
    coarse = np.zeros((ch, cw), np.float64)
    k = 0
    for i in range(degree + 1):
        for j in range(degree + 1 - i):
            coarse += coef[k] * np.outer(gy**j, gx**i)
            k += 1
    # map pixel (x, y) to coarse coordinate x / g: warp with an affine scale
    m = np.array([[1.0 / g, 0, 0], [0, 1.0 / g, 0]])
    out = cv2.warpAffine(coarse.astype(np.float32), m, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                         borderMode=cv2.BORDER_REPLICATE)
    return out


def darkest_level(image: np.ndarray) -> float:
    """The darkest grey level of a frame's bodies, however few pixels they cover: the minimum
    of the frame smoothed over 2 px (against noise), sampled every 2nd pixel."""
    return float(cv2.GaussianBlur(np.asarray(image, np.float32)[::2, ::2], (0, 0), 1.0).min())


def dark_bodies_mask(image: np.ndarray, margin_px: int) -> np.ndarray:
    """Bool mask of dark bodies, holes filled, grown by ``margin_px``.

    Dark is below half the bright level (95th percentile).  In a low-contrast frame, whose
    darkest body (`darkest_level`) lies between 30 and 80 % of the bright level (liquid and
    nozzle half transparent), half the bright level would miss the bodies themselves: the frame
    is smoothed (Gaussian, 2 px, against its noise) and dark is below ``1 - (1 - darkest) / 4``
    of the bright level.
    """
    img = np.asarray(image, np.float32)
    level = float(np.percentile(img[::4, ::4], 95))
    darkest = darkest_level(img) / max(level, 1e-6)
    if 0.3 < darkest < 0.8:
        img = cv2.GaussianBlur(img, (0, 0), 2.0)
        mask = (img < (1.0 - 0.25 * (1.0 - darkest)) * level).astype(np.uint8) * 255
    else:
        mask = (img < 0.5 * level).astype(np.uint8) * 255
    mask = fill_holes(mask)
    if margin_px > 0:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1, 2 * margin_px + 1))
        mask = cv2.dilate(mask, k)
    return mask > 0


def estimate_background(
    images: list[np.ndarray], degree: int = 4, margin_px: int = 6, dust_min_attenuation: float = 0.03
) -> BackgroundModel:
    """Estimate the illumination from the frames themselves (see module docstring).

    Parameters
    ----------
    images : list of ndarray
        A few frames spread over the sequence (same shape).
    degree : int
        Total degree of the smooth polynomial illumination.
    margin_px : int
        Pixels around dark bodies not used as background samples.
    dust_min_attenuation : float
        A static attenuation larger than this is folded into the background.
    """
    if not images:
        raise CalibrationError("no readable frame to estimate the background from")
    h, w = images[0].shape
    acc = np.zeros((h, w), np.float64)
    cnt = np.zeros((h, w), np.int32)
    for img in images:
        bright = ~dark_bodies_mask(img, margin_px)
        acc[bright] += img[bright]
        cnt[bright] += 1
    valid = cnt > 0
    mean = np.where(valid, acc / np.maximum(cnt, 1), 0.0).astype(np.float32)
    step = max(2, int(np.sqrt(h * w / 20000)))
    smooth = _fit_smooth(mean, valid, degree, step)
    smooth = np.maximum(smooth, 1e-3 * float(np.max(smooth)))
    background = smooth.copy()
    opaque = None
    dust_pixels = 0
    if len(images) >= 3:
        ratio = np.where(valid, mean / smooth, 1.0).astype(np.float32)
        ratio = cv2.GaussianBlur(ratio, (0, 0), 0.7)
        dust = valid & (ratio < 1.0 - dust_min_attenuation)
        background = np.where(dust, smooth * ratio, smooth).astype(np.float32)
        dust_pixels = int(dust.sum())
        never = (~valid).astype(np.uint8)
        n, lab, stats, _ = cv2.connectedComponentsWithStats(never, connectivity=8)
        top_labels = np.unique(lab[0][never[0] > 0])
        op = (lab > 0) & ~np.isin(lab, top_labels)
        if op.any():
            opaque = op
            dust_pixels += int(op.sum())
    falloff = float(1.0 - smooth.min() / smooth.max())
    return BackgroundModel(background, opaque, len(images), dust_pixels, falloff,
                           background_residual(mean, valid, background))


def background_residual(mean: np.ndarray, valid: np.ndarray, background: np.ndarray, block: int = 4) -> float:
    """Robust spread of ``mean / background - 1`` over blocks of ``block`` x ``block`` background pixels.

    Blocks with any pixel that is not background are left out; 0 when fewer than 20 blocks remain.
    """
    h, w = mean.shape
    hb, wb = h // block, w // block
    if hb == 0 or wb == 0:
        return 0.0
    sl = (slice(0, hb * block), slice(0, wb * block))
    rel = np.where(valid[sl], mean[sl] / np.maximum(background[sl], 1e-6) - 1.0, 0.0)
    rel = rel.reshape(hb, block, wb, block).mean(axis=(1, 3))
    ok = valid[sl].reshape(hb, block, wb, block).all(axis=(1, 3))
    r = rel[ok]
    if r.size < 20:
        return 0.0
    return float(1.4826 * np.median(np.abs(r - np.median(r))))


def clipped_fraction(background: np.ndarray, max_value: int | None) -> float:
    """Fraction of the background model at the sensor maximum (within 1 %): a clipped backlight."""
    if not max_value:
        return 0.0
    return float(np.mean(background[::4, ::4] >= 0.99 * max_value))


def _level_se(fit) -> float:
    """Standard error of the first parameter (the level) of a `least_squares` fit, from its Jacobian."""
    try:
        cov = np.linalg.inv(fit.jac.T @ fit.jac) * float(np.mean(fit.fun**2))
        return float(np.sqrt(max(cov[0, 0], 0.0)))
    except np.linalg.LinAlgError:
        return float("inf")


def unclipped_level(image: np.ndarray, nozzle: "Nozzle", max_value: int, half_px: int = 12) -> tuple[float, float]:
    """Background grey level a clipped frame would have had, from the edges of the top body.

    Across an edge the grey level rises from the dark interior ``d`` to the background ``B`` as
    a blurred step, ``d + (B - d) Phi((u - u0) / sigma)`` (``u`` the distance along the edge
    normal); the sensor clips its upper part.

    1. The profiles across each straight wall, averaged over the wall rows (aligned on the
       nearest pixel of each row's edge), fitted with the step below the clip (unknowns ``B``,
       ``u0``, ``sigma``; ``d`` from the samples deep inside the wall); needs five unclipped
       samples in the rising part. Median over the walls.
    2. The outline of the body touching the top (nozzle walls and any liquid hanging below),
       wherever it is steeper than 45 degrees: the samples of each row are placed at their
       distance along the normal from the row's edge (found at the clipped threshold), ``d`` is
       each row's level 6 px and more inside; pooled, they sample the step at every sub-pixel
       phase where the outline is curved or tilted (used when at least four of five phase bins
       hold 5 % of the rows). The step is fitted by least squares to the samples below the
       clip (unknowns ``B``, ``u0``, ``sigma``); kept when ``B``'s standard error is under 1 %.
    3. Where these fail or are not an error-function step (real optics: a halo, a long dark tail;
       residual over 2 % of full scale), the steepest point of each averaged wall profile is taken
       as the middle ``(d + B) / 2``, provided the two samples above it are below the clip.

    Every estimate needs the middle of the step below the clip; otherwise (a sharp, straight
    edge against a strongly clipped background) there is none and the frames are flagged
    ``saturated``.

    Parameters
    ----------
    image : ndarray
        Raw frame (canonical orientation).
    nozzle : Nozzle
        The top body's walls and outline (`find_nozzle`).
    max_value : int
        Sensor maximum.
    half_px : int
        Half width of the profile taken across each edge.

    Returns
    -------
    level : float
        NaN without an estimate.
    level_se : float
        Its standard uncertainty: the fits' standard errors and the spread between the walls'
        estimates (their standard error), whichever is larger; for the steepest-point estimate the
        spread of the walls' values, at least half their difference from the level's own middle
        sample (NaN without an estimate).
    """
    from scipy.optimize import least_squares
    from scipy.special import ndtr

    img = np.asarray(image, np.float64)
    h, w = img.shape
    clip = 0.98 * max_value
    offs = np.arange(-half_px, half_px + 1, dtype=float)
    # 1. the straight walls' profiles, averaged over the rows, fitted one wall at a time
    walls, fitted, fitted_se = [], [], []
    for edges, sign in ((nozzle.left_px, -1), (nozzle.right_px, 1)):
        profs = []
        for r, e in zip(nozzle.rows, edges):
            c = int(round(e)) if np.isfinite(e) else -1
            if c - half_px < 0 or c + half_px + 1 > w:
                continue
            profs.append(img[int(r), c - half_px:c + half_px + 1][::sign])
        if len(profs) < 3:
            continue
        prof = np.mean(profs, axis=0)
        d = float(np.median(prof[:3]))
        walls.append((prof, d))
        use = prof < clip
        if (use & (prof > d + 0.05 * (clip - d))).sum() < 5:
            continue
        fit = least_squares(lambda x, uu=offs[use], vv=prof[use], d=d: d + (x[0] - d) * ndtr((uu - x[1]) / x[2]) - vv,
                            (1.2 * max_value, 0.0, 1.5),
                            bounds=([0.5 * max_value, -half_px / 2, 0.3], [20 * max_value, half_px / 2, half_px / 2]))
        b = float(fit.x[0])
        if fit.success and 0.5 * (b + d) < clip and np.sqrt(np.mean(fit.fun**2)) < 0.02 * max_value:
            fitted.append(b)
            fitted_se.append(_level_se(fit))
    if fitted:
        spread = float(np.std(fitted, ddof=1) / np.sqrt(len(fitted))) if len(fitted) >= 2 else 0.0
        return float(np.median(fitted)), max(float(np.sqrt(np.mean(np.square(fitted_se)))), spread)
    # 2. pooled outline
    if nozzle.outline_rows is not None and nozzle.outline_rows.size >= 5:
        us, vs, ds, phases = [], [], [], []
        rows = nozzle.outline_rows
        for edges, sign in ((nozzle.outline_left, -1.0), (nozzle.outline_right, 1.0)):
            slope = np.gradient(edges, rows) if rows.size > 1 else np.zeros(rows.size)
            for r, xe, sl in zip(rows, edges, slope):
                if not np.isfinite(xe) or abs(sl) > 1.0:
                    continue
                c = int(round(xe))
                if c - half_px < 0 or c + half_px + 1 > w:
                    continue
                v = img[int(r), c - half_px:c + half_px + 1]
                u = sign * (c + offs - xe) / np.hypot(1.0, sl)  # + towards the background
                inside = u < -6.0
                if inside.sum() < 2:
                    continue
                keep = v < clip
                us.append(u[keep])
                vs.append(v[keep])
                ds.append(np.full(int(keep.sum()), float(np.median(v[inside]))))
                phases.append(xe - c)
        # the step is only separable from its level when it is sampled at many sub-pixel phases
        bins = np.bincount(np.minimum(((np.asarray(phases) + 0.5) * 5).astype(int), 4), minlength=5)
        if us and (bins >= max(3, 0.05 * len(phases))).sum() >= 4:
            u, v, d = np.concatenate(us), np.concatenate(vs), np.concatenate(ds)
            rising = v > d + 0.05 * (clip - d)
            if rising.sum() >= 20:
                def resid(x):
                    return d + (x[0] - d) * ndtr((u - x[1]) / x[2]) - v

                fit = least_squares(resid, (1.2 * max_value, 0.0, 1.5),
                                    bounds=([0.5 * max_value, -half_px / 2, 0.2], [20 * max_value, half_px / 2,
                                                                                   half_px / 2]))
                b = float(fit.x[0])
                rms = float(np.sqrt(np.mean(fit.fun[rising] ** 2)))
                b_se = _level_se(fit)  # from the fit's Jacobian: the lower half alone may not fix it
                if (fit.success and 0.5 * (b + float(np.median(d))) < clip and rms < 0.02 * max_value
                        and b_se < 0.01 * b):
                    return b, b_se
    # 3. steepest point of the averaged wall profiles
    found = []
    for prof, d in walls:
        diff = np.diff(prof)
        k = int(np.argmax(diff))
        if 0 < k < diff.size - 2 and prof[k + 2] < clip and (prof > d + 0.05 * (clip - d)).sum() >= 3:
            den = diff[k - 1] - 2 * diff[k] + diff[k + 1]
            off = 0.5 * (diff[k - 1] - diff[k + 1]) / den if den < 0 else 0.0
            mid = float(np.interp(k + 0.5 + off, np.arange(prof.size), prof))
            found.append(2.0 * mid - d)
    if not found:
        return float("nan"), float("nan")
    level = float(np.median(found))
    # the steepest sample locates the middle to about half a sample's rise: that much of the
    # level (twice the middle), and the walls' spread
    spread = float(np.std(found, ddof=1) / np.sqrt(len(found))) if len(found) >= 2 else 0.0
    rise = max((float(np.max(np.diff(prof))) for prof, _ in walls), default=0.0)
    return level, max(spread, rise)


def clipped_edge_range_px(image: np.ndarray, nozzle: "Nozzle", max_value: int, half_px: int = 12) -> float:
    """How far outside the half-of-clip crossing an edge may really lie when the level is unknown.

    Against a background clipped at the sensor maximum with an unknown true level ``B >= max``,
    the edge's 50 % crossing ``(B + d) / 2`` lies between the crossing at ``(max + d) / 2`` and
    the first clipped sample outside it.  The median over the nozzle's straight wall rows of
    that distance (px); 1 px when no wall row has a clipped sample within ``half_px``.

    Parameters
    ----------
    image : ndarray
        Raw frame (canonical orientation).
    nozzle : Nozzle
        Walls found against the clipped background.
    max_value : int
        Sensor maximum.
    half_px : int
        Profile half width (px).

    Returns
    -------
    float
        Distance (px), at least 0.5 px (the pixel itself).
    """
    img = np.asarray(image, np.float64)
    w = img.shape[1]
    clip = 0.98 * max_value
    dists = []
    for edges, sign in ((nozzle.left_px, -1), (nozzle.right_px, 1)):
        for r, e in zip(nozzle.rows, edges):
            if not np.isfinite(e):
                continue
            c = int(round(e))
            cols = c + sign * np.arange(0, half_px + 1)
            cols = cols[(cols >= 0) & (cols < w)]
            sat = np.nonzero(img[int(r), cols] >= clip)[0]
            if sat.size:
                dists.append(abs(cols[sat[0]] - e))
    return float(max(0.5, np.median(dists))) if dists else 1.0


# ----------------------------------------------------------------------------- nozzle
@dataclass
class Nozzle:
    """Outer walls of the nozzle (full-frame coordinates).

    Attributes
    ----------
    rows : ndarray
        Rows of the straight part used for the fit.
    left_px, right_px : ndarray
        Sub-pixel outer wall edges on those rows.
    axis_a, axis_b : float
        Midline ``col = axis_a + axis_b * row``.
    outer_width_px : float
        Mean horizontal outer width (multiply by cos(tilt) for the diameter).
    straight_end_row : int
        Last row of the straight part.
    interior_level : float
        Median transmission inside the nozzle.
    """

    rows: np.ndarray
    left_px: np.ndarray
    right_px: np.ndarray
    axis_a: float
    axis_b: float
    outer_width_px: float
    straight_end_row: int
    interior_level: float
    #: Sub-pixel outer edges of every row of the top body (walls and the liquid hanging below).
    outline_rows: np.ndarray | None = None
    outline_left: np.ndarray | None = None
    outline_right: np.ndarray | None = None

    @property
    def tilt_rad(self) -> float:
        return float(np.arctan(self.axis_b))

    @property
    def outer_diameter_px(self) -> float:
        return self.outer_width_px * float(np.cos(self.tilt_rad))

    def axis_col(self, row: float) -> float:
        return self.axis_a + self.axis_b * row


def _straight_walls(width: np.ndarray, cand: np.ndarray, expected_px: float | None = None) -> tuple[int, int]:
    """(start, stop) of the nozzle's straight part: a run of rows of constant width.

    Runs of consecutive candidate rows whose widths (5-row running median) stay within 1.5 px of
    the run's median are the straight parts of the top body (a holder block above the nozzle, the nozzle, a needle).
    With the nozzle's expected outer width (px), the longest run within a factor 1.5 of it is the
    nozzle; none: (0, 0).  Without it, runs of at least 6 rows are preferred to shorter ones (at
    least 3) and the narrowest is the nozzle (a holder is wider; the liquid hanging below is not
    of constant width), the longest on a tie.
    """
    # a 5-row running median: edge noise (low contrast) must not break a straight wall
    width = np.asarray(width, float)
    if width.size >= 5:
        pad = np.pad(width, 2, mode="edge")
        width = np.median(np.lib.stride_tricks.sliding_window_view(pad, 5), axis=1)
    runs_ = []
    i, n = 0, width.size
    while i < n:
        if not cand[i]:
            i += 1
            continue
        j = i + 1
        while j < n and cand[j] and abs(width[j] - np.median(width[i:j])) <= 1.5:
            j += 1
        if width[i] >= 4 and j - i >= 3:
            runs_.append((i, j))
        i = j
    if not runs_:
        return (0, 0)
    med = {r: float(np.median(width[r[0]:r[1]])) for r in runs_}
    if expected_px:
        near = [r for r in runs_ if 1 / 1.5 < med[r] / expected_px < 1.5]
        return max(near, key=lambda r: r[1] - r[0]) if near else (0, 0)
    if any(r[1] - r[0] >= 6 for r in runs_):
        runs_ = [r for r in runs_ if r[1] - r[0] >= 6]
    return min(runs_, key=lambda r: (med[r], -(r[1] - r[0])))


def _face_nozzle(t: np.ndarray, body: np.ndarray, threshold: float) -> tuple[int, int, float] | None:
    """A nozzle barely protruding from a holder block or plate: (first row, stop row, axis slope).

    The lowest dark row of the top body in each column is its bottom profile; its longest
    straight stretch (RANSAC) is the holder's face, and the columns reaching more than 1.5 px below the face
    (the group nearest the middle of the face) are the nozzle (and its meniscus).  Returns the rows
    from the face down to the bottom of that group and the axis slope (col per row,
    perpendicular to the face), or None when nothing protrudes.
    """
    cols = np.nonzero(body.any(axis=0))[0]
    if cols.size < 20:
        return None
    bottom = np.array([np.nonzero(body[:, c])[0].max() for c in cols], float)
    # the face is the longest straight stretch of the bottom profile (a wedge or a rounded corner
    # beside it is not): RANSAC over pairs of columns, inliers within 1 px, refitted
    x = cols.astype(float)
    rng = np.random.default_rng(0)
    best = None
    for _ in range(300):
        i, j = rng.choice(cols.size, 2, replace=False)
        if x[i] == x[j]:
            continue
        slope = (bottom[j] - bottom[i]) / (x[j] - x[i])
        inl = np.abs(bottom - (bottom[i] + slope * (x - x[i]))) <= 1.0
        if best is None or inl.sum() > best.sum():
            best = inl
    if best is None or best.sum() < 10:
        return None
    q = np.polyfit(x[best], bottom[best], 1)
    res = bottom - np.polyval(q, x)
    below = res >= 1.5
    if not below.any():
        return None
    # groups of adjacent protruding columns; the nozzle is the one nearest the middle of the face
    # (a wedge or corner protrudes at its ends)
    edges_ = np.flatnonzero(np.diff(np.r_[0, below.astype(int), 0]))
    groups = list(zip(edges_[::2], edges_[1::2] - 1))
    face_mid = 0.5 * (x[best].min() + x[best].max())
    lo, hi = min(groups, key=lambda g: abs(0.5 * (x[g[0]] + x[g[1]]) - face_mid))
    face_row = float(max(np.polyval(q, cols[lo]), np.polyval(q, cols[hi])))  # the face's lower end over the nozzle
    r0 = int(np.ceil(face_row + 1.0))
    r1 = int(bottom[lo:hi + 1].max()) + 1
    if r1 - r0 < 4:  # fewer rows give no usable wall lines
        return None
    return r0, r1, float(-q[0])


def _axis_runs(rr: np.ndarray, s: np.ndarray, e: np.ndarray, y1: int) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the dark run holding the nozzle: followed from the lowest row upwards.

    In the lowest row with a run at least 3 px wide the widest run is taken; in each row above,
    the run overlapping (8-connected) the one below it most. Rows above the first row without
    such a run get -1.
    """
    start = np.full(y1, -1)
    stop = np.full(y1, -1)
    order = np.argsort(rr, kind="stable")
    rr, s, e = rr[order], s[order], e[order]
    bounds = np.searchsorted(rr, np.arange(y1 + 1))
    prev = None
    for r in range(y1 - 1, -1, -1):
        i0, i1 = bounds[r], bounds[r + 1]
        if i0 == i1:
            if prev is None:
                continue
            break
        if prev is None:
            k = i0 + int(np.argmax(e[i0:i1] - s[i0:i1]))
            if e[k] - s[k] < 3:  # a noise pixel hanging below the body
                continue
        else:  # 8-connected: a run touching the one below diagonally still continues it
            overlap = np.minimum(e[i0:i1], prev[1] + 1) - np.maximum(s[i0:i1], prev[0] - 1)
            if overlap.max() <= 0:
                break
            k = i0 + int(np.argmax(overlap))
        start[r], stop[r] = s[k], e[k]
        prev = (s[k], e[k])
    return start, stop


def find_nozzle(transmission: np.ndarray, threshold: float = 0.5, expected_width_px: float | None = None) -> Nozzle:
    """Locate the nozzle (dark body at the top edge) and fit its outer walls.

    Parameters
    ----------
    transmission : ndarray of float
        Background-normalised frame (canonical orientation).
    threshold : float
        Edge level (50 % between background and the nozzle's interior).
    expected_width_px : float, optional
        The nozzle's outer diameter in pixels when the metadata gives it: picks the nozzle among
        the straight parts of the top body (a holder block is wider).
    """
    t = np.asarray(transmission, np.float32)
    h, w = t.shape
    mask = (t < threshold).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    top = [k for k in range(1, n) if stats[k, cv2.CC_STAT_TOP] == 0]
    if not top:
        raise CalibrationError("no nozzle: no dark body touches the top edge of the frame")
    k = max(top, key=lambda k: stats[k, cv2.CC_STAT_AREA])
    body = fill_holes((lab == k).astype(np.uint8) * 255) > 0
    y1 = stats[k, cv2.CC_STAT_TOP] + stats[k, cv2.CC_STAT_HEIGHT]
    rr, s, e = runs(body[:y1])
    # outer silhouette per row: first start .. last stop
    first = np.full(y1, -1)
    last = np.full(y1, -1)
    np.maximum.at(last, rr, e)
    first_vals = np.full(y1, w + 1)
    np.minimum.at(first_vals, rr, s)
    first = np.where(first_vals <= w, first_vals, -1)
    # the run holding the nozzle in each row, followed up from the body's lowest row (a holder
    # block beside the nozzle is another run, or makes this one much wider)
    a_start, a_stop = _axis_runs(rr, s, e, y1)
    width = np.where(a_start >= 0, a_stop - a_start, 0)
    cand = (width > 2) & (width < 0.9 * w) & (a_start > 0) & (a_stop < w)
    if cand.sum() < 3:
        raise CalibrationError(f"no nozzle: the dark body at the top edge (rows 0-{y1 - 1}, up to "
                               f"{int(np.max(last - np.maximum(first, 0)))} px wide) has no straight walls")
    a, b = _straight_walls(width, cand, expected_width_px)
    face_slope = None
    if b - a < 3:  # no walls of the expected width: a nozzle barely protruding from a holder or plate
        face = _face_nozzle(t, body[:y1], threshold)
        if face is None:
            raise CalibrationError(
                f"no nozzle: the dark body at the top edge (rows 0-{y1 - 1}, up to {int(width.max())} px wide) "
                "has fewer than 3 rows of constant width"
                + (f" near the expected {expected_width_px:.0f} px" if expected_width_px else "")
                + " and nothing protrudes below its lower face; give nozzle_tip_row and axis_col in sequence.json")
        a, b, face_slope = face
    # sub-pixel edges of the outer walls, away from the tip (blur) and from a holder's face
    if b - a >= 12:
        rows = np.arange(a + 2 if a > 0 else a, b - 4)  # 2 rows off a holder's face above the walls
    else:
        rows = np.arange(a, max(a + 1, b - 1) if face_slope is not None else max(a + 3, b - 2))
    ones = np.ones_like(t)
    edges = subpixel_edges(t, ones, rows, a_start[rows], a_stop[rows], threshold)
    left, right = edges.left_px, edges.right_px
    mid = 0.5 * (left + right)
    coef = np.polyfit(rows.astype(float), mid, 1) if rows.size >= 2 else np.array([0.0, mid[0]])
    if face_slope is None and rows.size < 10:  # walls too short for their midline's slope
        face_slope = _face_nozzle(t, body[:y1], threshold)
        face_slope = None if face_slope is None else face_slope[2]
    if face_slope is not None and rows.size < 10:  # the axis is perpendicular to the holder's face
        coef = np.array([face_slope, float(np.mean(mid) - face_slope * np.mean(rows))])
    inner = cv2.erode(body[: b].astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    vals_in = t[: b][inner & (t[: b] < threshold)]
    level = float(np.median(vals_in)) if vals_in.size else 0.0
    orows = np.nonzero((first > 0) & (last < w) & (last > first))[0]
    outline = subpixel_edges(t, ones, orows, first[orows], last[orows], threshold)
    return Nozzle(rows, left, right, float(coef[1]), float(coef[0]), float(np.mean(right - left)), int(b - 1), level,
                  orows, outline.left_px, outline.right_px)


def _crossing_down(profile: np.ndarray, start: int, stop: int, threshold: float) -> float:
    """First downward crossing of ``threshold`` (dark -> bright) in ``profile[start:stop]``."""
    seg = profile[start:stop]
    above = np.nonzero(seg >= threshold)[0]
    above = above[above > 0]
    for i in above:
        if seg[i - 1] < threshold:
            f = (threshold - seg[i - 1]) / (seg[i] - seg[i - 1])
            return start + i - 1 + float(f)
    return np.nan


def find_tip(
    transmission: np.ndarray,
    nozzle: Nozzle,
    threshold: float,
    inner_radius_px: float | None = None,
) -> tuple[float, str]:
    """Sub-pixel row of the nozzle tip plane at the axis, and how it was found.

    Parameters
    ----------
    transmission : ndarray
        A frame with the meniscus at rest (normalised).
    nozzle : Nozzle
    threshold : float
        50 % level between background and the nozzle's interior.
    inner_radius_px : float, optional
        Nozzle inner radius (pixels), to place the annulus columns on the wall.

    Returns
    -------
    tip_row : float
    source : str
        ``"wall annulus 50 % crossing"`` or ``"silhouette leaves the straight walls"``.
    """
    t = np.asarray(transmission, np.float32)
    h, w = t.shape
    r_out = 0.5 * nozzle.outer_diameter_px
    tan = nozzle.axis_b
    end = nozzle.straight_end_row
    lo = r_out * 0.6 if inner_radius_px is None else inner_radius_px + 1.5
    hi = r_out - 2.5
    tips = {}
    if hi > lo:
        offsets = np.linspace(lo, hi, max(2, int(hi - lo) + 1))
        for side in (-1, 1):
            vals = []
            for d in offsets:
                col = nozzle.axis_col(end) + side * d
                c = int(round(col))
                if not 0 <= c < w:
                    continue
                y = _crossing_down(t[:, c], max(0, end - 12), min(h, end + 12), threshold)
                if np.isfinite(y):
                    vals.append(y + (c - nozzle.axis_col(y)) * tan)
            if len(vals) >= 2:
                tips[side] = float(np.median(vals))
    if len(tips) == 2 and abs(tips[-1] - tips[1]) < 1.0 and abs(0.5 * (tips[-1] + tips[1]) - end) < 4:
        return 0.5 * (tips[-1] + tips[1]), "wall annulus 50 % crossing"
    # silhouette departure from the straight wall lines: the deviation of the outer edges from
    # the fitted wall lines, extrapolated linearly back to zero from its first rows above 0.3 px
    rows = np.arange(end + 1, min(h, end + 60))
    mask = (t < threshold)
    fl = np.polyfit(nozzle.rows.astype(float), nozzle.left_px, 1)
    fr = np.polyfit(nozzle.rows.astype(float), nozzle.right_px, 1)
    ys, devs = [], []
    for y in rows:
        cl = np.polyval(fl, y)
        cr = np.polyval(fr, y)
        row = mask[y]
        c0 = int(max(0, np.floor(cl - r_out)))
        c1 = int(min(w, np.ceil(cr + r_out)))
        if not np.any(row[c0:c1]):
            return float(y - 0.5), "silhouette leaves the straight walls (ends)"
        rr, s, e = runs(row[None, c0:c1])
        ed = subpixel_edges(t[y:y + 1, c0:c1], np.ones((1, c1 - c0), np.float32), np.zeros_like(s), s, e, threshold)
        dev = max(abs(ed.left_px.min() + c0 - cl), abs(ed.right_px.max() + c0 - cr))
        ys.append(y)
        devs.append(dev)
        if dev > 3.0:
            break
    ys = np.array(ys, float)
    devs = np.array(devs, float)
    sel = devs > 0.3
    if sel.sum() >= 2:
        k = np.nonzero(sel)[0]
        k = k[: max(2, min(len(k), 4))]
        slope, icpt = np.polyfit(ys[k], devs[k], 1)
        if slope > 0:
            y0 = -icpt / slope
            return float(np.clip(y0, end - 1.0, ys[k[0]])), "silhouette leaves the straight walls"
    if sel.any():
        return float(ys[np.argmax(sel)] - 0.5), "silhouette leaves the straight walls"
    return float(end + 0.5), "end of the straight walls"


def interior_level(transmission: np.ndarray, region: np.ndarray, erode_px: int = 4, threshold: float = 0.5) -> float:
    """Median transmission inside dark bodies of ``region`` (bool), eroded, lens spot excluded
    (the mode instead when it is above 0.3: low contrast)."""
    t = np.asarray(transmission, np.float32)
    mask = (region & (t < threshold)).astype(np.uint8) * 255
    filled = fill_holes(mask)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * erode_px + 1, 2 * erode_px + 1))
    inner = cv2.erode(filled, k) > 0
    vals = t[inner & (t < threshold)]
    if vals.size < 20:
        return float("nan")
    level = float(np.median(vals))
    if level > 0.3 and vals.size >= 200:
        # low contrast: the edge moves by (level error) / slope, and the slope is small, so the
        # halo of the lens spot must not pull the level up: the mode of the values instead
        hist, edges = np.histogram(vals, bins=60, range=(float(np.percentile(vals, 1)), float(np.percentile(vals, 99))))
        hist = np.convolve(hist, np.ones(5) / 5, mode="same")
        k = int(np.argmax(hist))
        half = 2.5 * (edges[1] - edges[0])
        centre = 0.5 * (edges[k] + edges[k + 1])
        near = vals[np.abs(vals - centre) <= half]
        level = float(np.mean(near)) if near.size else level
    return level


# ----------------------------------------------------------------------------- calibration
@dataclass
class Calibration:
    """Everything the per-frame measurement needs (full-frame canonical coordinates)."""

    shape: tuple[int, int]
    pixel_size_um: float
    pixel_size_source: str
    tip_row: float
    tip_source: str
    axis_col: float
    axis_source: str
    tilt_rad: float
    tilt_source: str
    liquid_level: float
    nozzle_level: float
    threshold: float
    nozzle_outer_diameter_px: float
    nozzle_outer_diameter_um_measured: float
    pixel_size_disagreement_percent: float
    background: BackgroundModel
    notes: list[str] = field(default_factory=list)
    #: Pixel size implied by ``nozzle_outer_diameter_um`` over the given one (NaN without it).
    pixel_size_ratio: float = float("nan")
    #: Standard uncertainty of that ratio from the measured outer diameter (see `outer_diameter_uncertainty_px`).
    pixel_size_ratio_uncertainty: float = float("nan")
    #: A clipped background: ``fraction`` at the sensor maximum, unclipped ``level`` (NaN: unknown), ``method``.
    clipped: dict | None = None
    #: Parts of the edge-position uncertainty common to a body (px; `dropvision.context.edge_position_terms_px`).
    edge_position_terms_px: dict = field(default_factory=dict)
    #: The nozzle walls are out of focus (the sharpest detached body is the in-focus reference).
    nozzle_out_of_focus: bool = False

    @property
    def edge_position_uncertainty_px(self) -> float:
        """Standard uncertainty (px) of an edge position common to a body: its parts in quadrature."""
        return float(np.sqrt(sum(v * v for v in self.edge_position_terms_px.values())))

    @property
    def volume_uncertainty_source(self) -> str:
        """The largest part of the edge-position uncertainty ("edge floor" when none is known)."""
        terms = self.edge_position_terms_px
        return max(terms, key=terms.get) if terms else "edge floor"

    @property
    def clipped_level(self) -> float:
        """Unclipped background level used where the background is clipped; NaN when not clipped or unknown."""
        if not self.clipped or not self.clipped.get("used", False):
            return float("nan")  # not clipped
        return float(self.clipped["level"])

    @property
    def tilt_deg(self) -> float:
        return float(np.degrees(self.tilt_rad))

    def to_dict(self) -> dict:
        return {
            "pixel_size_um": self.pixel_size_um,
            "pixel_size_source": self.pixel_size_source,
            "tip_row": self.tip_row,
            "tip_row_source": self.tip_source,
            "axis_col": self.axis_col,
            "axis_col_source": self.axis_source,
            "tilt_deg": self.tilt_deg,
            "tilt_source": self.tilt_source,
            "coordinates": "canonical frame (nozzle at the top, drops travel down), pixel centres integers",
            "liquid_interior_transmission": self.liquid_level,
            "nozzle_interior_transmission": self.nozzle_level,
            "edge_threshold_transmission": self.threshold,
            "nozzle_outer_diameter_px": self.nozzle_outer_diameter_px,
            "nozzle_outer_diameter_um_measured": self.nozzle_outer_diameter_um_measured,
            "pixel_size_disagreement_percent": self.pixel_size_disagreement_percent,
            "pixel_size_ratio": self.pixel_size_ratio,
            "pixel_size_ratio_uncertainty": self.pixel_size_ratio_uncertainty,
            "background": {
                "method": "robust degree-4 polynomial fit to pixels away from dark bodies"
                + (", static dust attenuation folded in" if self.background.n_frames >= 3 else ""),
                "frames_used": self.background.n_frames,
                "dust_pixels": self.background.dust_pixels,
                "illumination_falloff": self.background.falloff,
                "residual": self.background.residual,
            },
            "clipped_background": None if self.clipped is None else dict(self.clipped),
            "edge_position_uncertainty_px": self.edge_position_uncertainty_px,
            "edge_position_terms_px": dict(self.edge_position_terms_px),
            "volume_uncertainty_source": self.volume_uncertainty_source,
            "nozzle_out_of_focus": self.nozzle_out_of_focus,
            "notes": list(self.notes),
        }


def calibrate(
    first: np.ndarray,
    spread: list[np.ndarray],
    pixel_size_um: float,
    *,
    nozzle_outer_diameter_um: float | None = None,
    nozzle_inner_diameter_um: float | None = None,
    tip_row: float | None = None,
    axis_col: float | None = None,
    pixel_size_tolerance: float = 0.02,
    edge_position_floor_px: float = 0.05,
    max_value: int | None = None,
    clipped_limit: float = 0.01,
) -> Calibration:
    """Calibrate a sequence from its first (meniscus at rest) frame and frames spread over it.

    Parameters
    ----------
    first : ndarray
        The first frame in delay order.
    spread : list of ndarray
        Frames spread over the sequence (``first`` included), for the background.
    pixel_size_um : float
        From the metadata.
    nozzle_outer_diameter_um, nozzle_inner_diameter_um : float, optional
        Nozzle dimensions (cross-check of the pixel size; annulus columns).
    tip_row, axis_col : float, optional
        User-given values override the detection.
    pixel_size_tolerance : float
        Relative disagreement of the pixel size with the outer diameter beyond which a
        calibration note (and a `CalibrationWarning`) is given.
    edge_position_floor_px : float
        Systematic uncertainty of one wall edge (px), see `outer_diameter_uncertainty_px`.
    max_value : int, optional
        Sensor maximum; with it, a background clipped there over more than ``clipped_limit`` of
        the frame gets its unclipped level from the nozzle walls (`unclipped_level`).
    clipped_limit : float
        Fraction of the background at the sensor maximum from which it is treated as clipped.
    """
    bg = estimate_background(spread)
    notes: list[str] = []
    clipped = None
    expected = nozzle_outer_diameter_um / pixel_size_um if nozzle_outer_diameter_um else None
    frac = clipped_fraction(bg.background, max_value)
    if frac > clipped_limit:
        level, level_se = unclipped_level(first, find_nozzle(np.asarray(first, np.float32) / bg.background, 0.5,
                                                             expected), max_value)
        clipped = {"fraction": frac, "level": level, "level_uncertainty": level_se, "max_value": int(max_value),
                   "method": "background grey level from the unclipped part of the top body's edge profile "
                             "(calibration.unclipped_level), used wherever the background model is at the "
                             "sensor maximum"}
        clipped["level_known"] = bool(np.isfinite(level) and level > max_value)
        clipped["used"] = True
        if clipped["level_known"]:
            bg.background = np.where(bg.background >= 0.99 * max_value, np.float32(level),
                                     bg.background).astype(np.float32)
            notes.append(f"background clipped at the sensor maximum over {100 * frac:.0f} % of the frame: its "
                         f"level {level:.0f} (max {max_value}) estimated from the nozzle walls; edges are taken "
                         "below the clip")
        else:
            # the true level is at or above the clip: the sensor maximum is its lower bound, and the
            # true edge lies between our crossing and the first clipped pixel outside it
            clipped["level"], clipped["level_uncertainty"] = float(max_value), float("nan")
            bg.background = np.where(bg.background >= 0.99 * max_value, np.float32(max_value),
                                     bg.background).astype(np.float32)
            nz = find_nozzle(np.asarray(first, np.float32) / bg.background, 0.5, expected)
            clipped["edge_range_px"] = clipped_edge_range_px(first, nz, max_value)
            notes.append(f"background clipped over {100 * frac:.0f} % of the frame and its level could not be "
                         f"estimated (the middle of the nozzle walls' edge is clipped too): the sensor maximum "
                         f"{max_value} is taken as its level (a lower bound); the true edge lies within "
                         f"{clipped['edge_range_px']:.2f} px outside the measured one (in the uncertainty)")
    t_first = np.asarray(first, np.float32) / bg.background
    # first pass with a 50 % threshold, refined with the measured nozzle level
    # first pass at 50 % (half-way to the darkest body in a low-contrast frame, where the nozzle
    # itself may sit near 50 %), refined with the measured nozzle level
    darkest = darkest_level(t_first)
    nozzle = find_nozzle(t_first, edge_threshold(darkest) if 0.3 < darkest < 0.8 else 0.5, expected)
    thr_n = edge_threshold(nozzle.interior_level)
    nozzle = find_nozzle(t_first, thr_n, expected)
    r_in = None if nozzle_inner_diameter_um is None else 0.5 * nozzle_inner_diameter_um / pixel_size_um
    tip, tip_src = find_tip(t_first, nozzle, thr_n, r_in)
    tilt = nozzle.tilt_rad
    axis = nozzle.axis_col(tip)
    axis_src = "nozzle outer walls midline fit"
    tilt_src = "nozzle outer walls midline fit"
    if tip_row is not None:
        tip, tip_src = float(tip_row), "user (sequence.json nozzle_tip_row)"
        axis = nozzle.axis_col(tip)
    if axis_col is not None:
        axis, axis_src = float(axis_col), "user (sequence.json axis_col)"
    d_px = nozzle.outer_diameter_px
    d_um = d_px * pixel_size_um
    disagree = ratio = ratio_u = float("nan")
    if nozzle_outer_diameter_um:
        disagree = 100.0 * (d_um / nozzle_outer_diameter_um - 1.0)
        # implied pixel size (outer diameter / measured px) over the given one
        ratio = float(nozzle_outer_diameter_um / d_um)
        ratio_u = float(ratio * outer_diameter_uncertainty_px(nozzle, edge_position_floor_px) / d_px)
        if abs(disagree) > 100 * pixel_size_tolerance:
            msg = (
                f"pixel size {pixel_size_um} um disagrees by {disagree:+.1f} % with the nozzle's outer "
                f"width ({d_px:.1f} px for {nozzle_outer_diameter_um} um)"
            )
            notes.append(msg)
            warnings.warn(msg, CalibrationWarning, stacklevel=2)
    # liquid interior level from liquid below the tip in the spread frames
    h, w = t_first.shape
    region = np.zeros((h, w), bool)
    region[int(np.ceil(tip)) + 3:, :] = True
    if bg.opaque is not None:
        region &= ~bg.opaque
    levels = []
    for img in spread:
        lv = interior_level(np.asarray(img, np.float32) / bg.background, region, threshold=thr_n)
        if np.isfinite(lv):
            levels.append(lv)
    if levels:
        liquid = float(np.median(levels))
    else:
        liquid = nozzle.interior_level
        notes.append("no liquid body large enough to measure its interior level: nozzle level used")
    return Calibration(
        shape=(h, w),
        pixel_size_um=float(pixel_size_um),
        pixel_size_source="sequence.json pixel_size_um",
        tip_row=float(tip),
        tip_source=tip_src,
        axis_col=float(axis),
        axis_source=axis_src,
        tilt_rad=float(tilt),
        tilt_source=tilt_src,
        liquid_level=liquid,
        nozzle_level=nozzle.interior_level,
        threshold=edge_threshold(liquid),
        nozzle_outer_diameter_px=float(d_px),
        nozzle_outer_diameter_um_measured=float(d_um),
        pixel_size_disagreement_percent=disagree,
        background=bg,
        notes=notes,
        pixel_size_ratio=ratio,
        pixel_size_ratio_uncertainty=ratio_u,
        clipped=clipped,
    )


def outer_diameter_uncertainty_px(nozzle: Nozzle, edge_position_floor_px: float) -> float:
    """Standard uncertainty (px) of the nozzle's measured outer diameter.

    Two parts in quadrature: the statistical error of the mean width (standard deviation of
    the per-row widths over the straight rows / sqrt(rows)), and a systematic floor of
    ``edge_position_floor_px`` on each of the two walls (threshold and blur model bias, which
    does not average out over rows).

    Parameters
    ----------
    nozzle : Nozzle
        Fitted outer walls.
    edge_position_floor_px : float
        Systematic uncertainty of one edge (px).

    Returns
    -------
    float
        Uncertainty of ``nozzle.outer_diameter_px`` (px).
    """
    w = np.asarray(nozzle.right_px, float) - np.asarray(nozzle.left_px, float)
    w = w[np.isfinite(w)]
    stat = float(np.std(w, ddof=1) / np.sqrt(w.size)) if w.size >= 2 else float("nan")
    return float(np.hypot(stat, np.sqrt(2.0) * edge_position_floor_px) * np.cos(nozzle.tilt_rad))


def edge_sigma_px(transmission: np.ndarray, nozzle: Nozzle, half_window_px: int = 8,
                  clip_transmission: float = float("inf")) -> float:
    """Effective blur of straight edges (px): Gaussian sigma including the pixel box.

    The transmission samples across the nozzle's outer walls, placed at their distance from
    each row's sub-pixel 50 % edge, are pooled into one finely sampled edge-spread function and
    fitted by least squares with an error function ``(1 + erf(u / (sqrt(2) sigma))) / 2``
    (plus a shift).  This sigma (optics and pixel box together) is the smoothing that displaces
    a curved 50 % edge by ``sigma^2 * curvature / 2``.  Samples at or above
    ``clip_transmission`` (a clipped background) are left out of the fit.
    """

    return esf_sigma_px(transmission, nozzle.rows, nozzle.left_px, nozzle.right_px, nozzle.interior_level,
                        half_window_px, clip_transmission)


def esf_sigma_px(transmission: np.ndarray, rows, left_px, right_px, interior_level: float,
                 half_window_px: int = 8, clip_transmission: float = float("inf")) -> float:
    """Gaussian sigma (px) of an edge-spread function pooled from the rows of a body's outline.

    Each row's samples within ``half_window_px`` of its sub-pixel left and right edges are
    placed at their distance from the edge along its normal (the horizontal distance times the
    cosine of the outline's slope there; rows where the outline is flatter than 45 degrees are
    left out), scaled from ``interior_level`` (0) to the background (1), and fitted with
    ``(1 + erf(u / (sqrt(2) sigma))) / 2`` plus a shift (Gauss-Newton).  Straight walls
    (`edge_sigma_px`) have slope 0.

    Parameters
    ----------
    transmission : ndarray
        Frame over the background model.
    rows, left_px, right_px : array_like
        Row and sub-pixel edges of the outline (one entry per row).
    interior_level : float
        Transmission inside the body.
    half_window_px : int
        Samples taken either side of each edge (px).
    clip_transmission : float
        Samples at or above it (a clipped background) are left out.

    Returns
    -------
    float
        NaN without usable rows.
    """
    t = np.asarray(transmission, np.float64)
    h, w = t.shape
    lo = interior_level
    rows = np.asarray(rows, int)
    us, vs = [], []
    for edges, sign in ((np.asarray(left_px, float), -1.0), (np.asarray(right_px, float), 1.0)):
        slope = np.gradient(edges, rows) if rows.size >= 2 else np.zeros(rows.size)
        for y, xe, s in zip(rows, edges, slope):
            if not np.isfinite(xe) or abs(s) > 1.0:
                continue
            c = int(round(xe))
            c0, c1 = c - half_window_px, c + half_window_px + 1
            if c0 < 0 or c1 > w or not 0 <= y < h:
                continue
            x = np.arange(c0, c1)
            keep = t[y, c0:c1] < clip_transmission
            us.append(sign * (x[keep] - xe) / np.hypot(1.0, s))
            vs.append((t[y, c0:c1][keep] - lo) / (1.0 - lo))
    if not us:
        return float("nan")
    u = np.concatenate(us)
    v = np.concatenate(vs)

    sig, shift = 1.0, 0.0
    for _ in range(30):  # Gauss-Newton on (sigma, shift)
        z = (u - shift) / (np.sqrt(2.0) * sig)
        r = 0.5 * (1.0 + erf(z)) - v
        g = np.exp(-z * z) / np.sqrt(np.pi)  # d/dz of the model
        j = np.column_stack([g * (-z / sig), g * (-1.0 / (np.sqrt(2.0) * sig))])
        step, *_ = np.linalg.lstsq(j, -r, rcond=None)
        sig = float(np.clip(sig + step[0], 0.05, 20.0))
        shift = float(shift + step[1])
        if abs(step[0]) < 1e-6:
            break
    return sig
