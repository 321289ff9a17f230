"""Illumination (background) model of a strobe sequence, and a backlight clipped at the sensor maximum.

- `estimate_background`: from a few frames spread over the sequence, the pixels away from any
  dark body are averaged, and a smooth 2-D polynomial is fitted to them (robustly); it carries
  the backlight fall-off under the nozzle and the liquid.  Where the frames show a static,
  partly transparent speck (dust on the optics), the measured attenuation is folded into the
  background (it is then invisible in the transmission); specks that stay dark in every frame
  and are not joined to the nozzle are *opaque dust*, removed from every dark mask.  One frame
  only: the polynomial alone, no dust detection.
- Clipped backlight: `clipped_fraction` of the background at the sensor maximum;
  `unclipped_level` estimates the level it would have had from the nozzle walls' edge
  profiles, and `clipped_edge_range_px` bounds the edge position when it cannot.

`CalibrationError` and `CalibrationWarning` (raised by every calibration stage) are declared
here, the first of them; `dropvision.calibrate.calibration` exports them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from dvcore.robust import MAD_TO_SIGMA, robust_sigma
from dropvision.frame.segmentation import fill_holes

if TYPE_CHECKING:
    from dropvision.calibrate.nozzle import Nozzle


class CalibrationError(ValueError):
    """The frames do not allow a calibration (no nozzle found...)."""


class NoNozzleError(CalibrationError):
    """No nozzle in the frame: no dark body at the top edge, or none with a nozzle's walls or face.
    Callers that can measure without a nozzle catch this class (never the message's words)."""


class CalibrationWarning(UserWarning):
    """A calibration cross-check disagrees (e.g. pixel size vs nozzle width)."""


@dataclass(frozen=True)
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


def _poly_terms(col: np.ndarray, row: np.ndarray, grid_x: np.ndarray, grid_y: np.ndarray, degree: int) -> np.ndarray:
    """Terms ``x**i * y**j`` (total degree <= ``degree``) of the samples at grid indices ``col``, ``row``.

    The samples lie on a grid, so each power is taken once per grid column (row) and gathered:
    the same ``x**i`` of the same coordinates, to the bit, at a fraction of the cost.
    """
    px = [(grid_x**i)[col] for i in range(degree + 1)]
    py = [(grid_y**j)[row] for j in range(degree + 1)]
    return np.stack([px[i] * py[j] for i in range(degree + 1) for j in range(degree + 1 - i)], axis=-1)


def _fit_smooth(values: np.ndarray, valid: np.ndarray, degree: int, step: int) -> np.ndarray:
    h, w = values.shape
    ys, xs = np.mgrid[0:h:step, 0:w:step]
    v = values[ys, xs]
    ok = valid[ys, xs]
    sx, sy = 2.0 / max(w - 1, 1), 2.0 / max(h - 1, 1)
    grid_x = np.arange(0, w, step) * sx - 1.0  # sample coordinates scaled to -1..1
    grid_y = np.arange(0, h, step) * sy - 1.0
    v = v[ok].astype(np.float64)
    if v.size < 50:
        raise CalibrationError("too few background pixels to estimate the illumination")
    row, col = np.nonzero(ok)
    a = _poly_terms(col, row, grid_x, grid_y, degree)
    keep = np.ones(v.size, bool)
    coef = None
    for _ in range(4):
        coef, *_ = np.linalg.lstsq(a[keep], v[keep], rcond=None)
        r = v - a @ coef
        sigma = MAD_TO_SIGMA * np.median(np.abs(r[keep])) + 1e-3 * np.median(v)
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


def median_by_selection(values: np.ndarray):
    """``np.median`` of a large 1-d array, the same value, by selection within a bracket.

    The two middle order statistics are bracketed by those of a strided sample (some 20 000
    values, widened by 4 of its standard errors), the values below and within the bracket are
    counted, and only those within are partitioned: a few passes over the data instead of a
    partition of all of it (some 5 times faster on 2 million values). Where the bracket does not
    hold them (or a value is NaN, or fewer than 100 000) ``np.median`` itself (its dtype too).
    ``values`` is not changed."""
    x = np.asarray(values).ravel()
    n = x.size
    if n < 100_000:
        return np.median(x)
    sample = np.sort(x[:: max(1, n // 20_000)])
    m = sample.size
    k_lo, k_hi = (n - 1) // 2, n // 2  # the middle order statistics (one for odd n)
    half = int(math.ceil(4.0 * math.sqrt(m) * 0.5)) + 2  # 4 standard errors of the sample's median rank
    lo = sample[max(0, m // 2 - half)]
    hi = sample[min(m - 1, m // 2 + half)]
    below = int(np.count_nonzero(x < lo))
    inside = x[(x >= lo) & (x <= hi)]
    above = int(np.count_nonzero(x > hi))
    if below + inside.size + above != n or not below <= k_lo <= k_hi < below + inside.size:
        return np.median(x)  # NaN among them (counted nowhere), or the bracket missed the middle
    part = np.partition(inside, [k_lo - below, k_hi - below])
    # np.median's own mean of its middle values (their dtype, their order)
    return np.median(np.array([part[k_lo - below], part[k_hi - below]], dtype=x.dtype) if k_lo != k_hi
                     else part[k_lo - below:k_lo - below + 1])


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
    images: list[np.ndarray], degree: int = 4, margin_px: int = 6, dust_min_attenuation: float = 0.03,
    static_dust: bool = True,
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
    static_dust : bool
        Look for static dust (three or more frames). False where what stays in one place in every
        frame may be the liquid itself: shots of one rig at one strobe delay, whose drops sit at
        nearly one place (`dropvision.analysis.shot_rig`); the polynomial alone, as for one frame.
    """
    if not images:
        raise CalibrationError("no readable frame to estimate the background from")
    h, w = images[0].shape
    if len(images) == 1:  # the frame itself where valid (its values elsewhere are never read), no sums
        valid = ~dark_bodies_mask(images[0], margin_px)
        mean = np.asarray(images[0], np.float32)
    else:
        acc = np.zeros((h, w), np.float64)
        cnt = np.zeros((h, w), np.int32)
        for img in images:
            bright = ~dark_bodies_mask(img, margin_px)
            np.add(acc, img, out=acc, where=bright)  # in place, no gathered copies
            cnt += bright
        valid = cnt > 0
        mean = np.where(valid, acc / np.maximum(cnt, 1), 0.0).astype(np.float32)
    step = max(2, int(np.sqrt(h * w / 20000)))
    smooth = _fit_smooth(mean, valid, degree, step)
    smooth = np.maximum(smooth, 1e-3 * float(np.max(smooth)))
    background = smooth.copy()
    opaque = None
    dust_pixels = 0
    if static_dust and len(images) >= 3:
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


def _block_means(image: np.ndarray, hb: int, wb: int, block: int) -> np.ndarray:
    """``image.reshape(hb, block, wb, block).mean(axis=(1, 3))`` of a float32 image, the same values (numpy's
    order of the sums: each block row's ``block`` values one after the other, then the rows one after the
    other; checked to the bit in tests/calibrate/test_calibration_fast.py), by ``block**2`` whole-array sums instead of
    numpy's strided reduction (some 3 times faster on a 2048 x 1536 frame). Other types or blocks: numpy."""
    v = image.reshape(hb, block, wb, block)
    if image.dtype != np.float32 or not 2 <= block <= 7 or min(hb, wb) < 16:  # (numpy orders small ones otherwise)
        return v.mean(axis=(1, 3))
    total = None
    for i in range(block):
        row = v[:, i, :, 0] + v[:, i, :, 1]
        for j in range(2, block):
            row += v[:, i, :, j]
        total = row if total is None else total + row
    return np.true_divide(total, block * block, out=total, casting="unsafe")


def background_residual(mean: np.ndarray, valid: np.ndarray, background: np.ndarray, block: int = 4) -> float:
    """The background model's misfit: the robust spread of ``mean / background - 1`` over blocks of
    ``block`` x ``block`` background pixels, less (in quadrature) the part the frames' noise gives it.

    What moves every edge of a body alike is the model's error where the body lies, which changes
    slowly over the frame (an illumination the smooth model does not follow); a block's own noise
    (the sensor's, averaged over its pixels and the frames) changes from block to block and moves
    the edges independently, which their random part holds.  The noise's share is read off the
    differences between neighbouring blocks (robust spread over sqrt(2)), in which a slow misfit
    cancels.  Blocks with any pixel that is not background are left out; 0 when fewer than 20
    blocks (or 20 differences) remain.  On the synthetic sweep (a polynomial backlight the model
    follows) the block spread was the noise's, 0.0017 of the background at noise 2, and gave each
    body a common edge error of 0.0085 px; a vignetting the model misses keeps its spread.
    """
    h, w = mean.shape
    hb, wb = h // block, w // block
    if hb == 0 or wb == 0:
        return 0.0
    sl = (slice(0, hb * block), slice(0, wb * block))
    rel = np.where(valid[sl], mean[sl] / np.maximum(background[sl], 1e-6) - 1.0, 0.0)
    rel = _block_means(rel, hb, wb, block)
    ok = valid[sl].reshape(hb, block, wb * block).all(axis=1).reshape(hb, wb, block).all(axis=2)
    r = rel[ok]
    if r.size < 20:
        return 0.0
    spread = robust_sigma(r)
    d = np.concatenate([(rel[:, 1:] - rel[:, :-1])[ok[:, 1:] & ok[:, :-1]],
                        (rel[1:, :] - rel[:-1, :])[ok[1:, :] & ok[:-1, :]]])
    if d.size < 20:
        return spread
    noise = robust_sigma(d) / math.sqrt(2.0)
    return float(math.sqrt(max(spread * spread - noise * noise, 0.0)))


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


def unclipped_level(image: np.ndarray, nozzle: Nozzle, max_value: int, half_px: int = 12) -> tuple[float, float]:
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
    img = np.asarray(image, np.float64)
    clip = 0.98 * max_value
    walls = _wall_profiles(img, nozzle, half_px)
    found = _walls_step_level(walls, clip, max_value, half_px)  # 1. the straight walls, one at a time
    if found is None:
        found = _outline_step_level(img, nozzle, clip, max_value, half_px)  # 2. the pooled outline
    if found is None:
        found = _steepest_point_level(walls, clip)  # 3. the steepest point of the walls' profiles
    return found


def _wall_profiles(img: np.ndarray, nozzle: Nozzle, half_px: int) -> list[tuple[np.ndarray, float]]:
    """(profile, d) of each straight wall with three rows or more (`unclipped_level`, step 1): the
    grey levels across its edge (``2 half_px + 1`` samples from the dark side out, aligned on the
    nearest pixel of each row's edge) averaged over its rows, and its dark level ``d`` (the median
    of the three innermost samples)."""
    w = img.shape[1]
    walls = []
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
        walls.append((prof, float(np.median(prof[:3]))))
    return walls


def _walls_step_level(walls: list, clip: float, max_value: int, half_px: int) -> tuple[float, float] | None:
    """Step 1 of `unclipped_level`: each wall's averaged profile fitted by the blurred step below the
    clip; (median level, its standard uncertainty) over the walls whose fit holds, or None."""
    from scipy.optimize import least_squares
    from scipy.special import ndtr

    offs = np.arange(-half_px, half_px + 1, dtype=float)
    fitted, fitted_se = [], []
    for prof, d in walls:
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
    if not fitted:
        return None
    spread = float(np.std(fitted, ddof=1) / np.sqrt(len(fitted))) if len(fitted) >= 2 else 0.0
    return float(np.median(fitted)), max(float(np.sqrt(np.mean(np.square(fitted_se)))), spread)


def _outline_samples(img: np.ndarray, nozzle: Nozzle, clip: float, half_px: int) -> tuple[list, list, list, list]:
    """The samples of step 2 of `unclipped_level`: in each outline row steeper than 45 degrees, the
    samples below the clip at their distance ``u`` along the normal from the row's edge (+ towards
    the background), their grey levels ``v``, the row's dark level ``d`` (6 px and more inside) and
    the edge's sub-pixel phase; per row: (us, vs, ds, phases)."""
    w = img.shape[1]
    offs = np.arange(-half_px, half_px + 1, dtype=float)
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
    return us, vs, ds, phases


def _outline_step_level(img: np.ndarray, nozzle: Nozzle, clip: float, max_value: int,
                        half_px: int) -> tuple[float, float] | None:
    """Step 2 of `unclipped_level`: the pooled outline samples (`_outline_samples`) fitted by the
    blurred step; (level, its standard error) when the samples cover the sub-pixel phases and the
    fit holds, else None."""
    from scipy.optimize import least_squares
    from scipy.special import ndtr

    if nozzle.outline_rows is None or nozzle.outline_rows.size < 5:
        return None
    us, vs, ds, phases = _outline_samples(img, nozzle, clip, half_px)
    # the step is only separable from its level when it is sampled at many sub-pixel phases
    bins = np.bincount(np.minimum(((np.asarray(phases) + 0.5) * 5).astype(int), 4), minlength=5)
    if not (us and (bins >= max(3, 0.05 * len(phases))).sum() >= 4):
        return None
    u, v, d = np.concatenate(us), np.concatenate(vs), np.concatenate(ds)
    rising = v > d + 0.05 * (clip - d)
    if rising.sum() < 20:
        return None

    def resid(x):
        return d + (x[0] - d) * ndtr((u - x[1]) / x[2]) - v

    fit = least_squares(resid, (1.2 * max_value, 0.0, 1.5),
                        bounds=([0.5 * max_value, -half_px / 2, 0.2], [20 * max_value, half_px / 2, half_px / 2]))
    b = float(fit.x[0])
    rms = float(np.sqrt(np.mean(fit.fun[rising] ** 2)))
    b_se = _level_se(fit)  # from the fit's Jacobian: the lower half alone may not fix it
    if fit.success and 0.5 * (b + float(np.median(d))) < clip and rms < 0.02 * max_value and b_se < 0.01 * b:
        return b, b_se
    return None


def _steepest_point_level(walls: list, clip: float) -> tuple[float, float]:
    """Step 3 of `unclipped_level`: the steepest point of each wall's averaged profile taken as the
    middle ``(d + B) / 2``; (median level, its uncertainty), or (NaN, NaN) without one."""
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


def clipped_edge_range_px(image: np.ndarray, nozzle: Nozzle, max_value: int, half_px: int = 12) -> float:
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
