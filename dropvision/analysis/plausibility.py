"""Plausibility checks of a measured sequence: is what the metadata and the frames say consistent?

Each check takes the sequence's arrays and returns what it found, a list of
`dropvision.analysis.findings.Finding` (quality code, frames concerned, note, outputs withheld); it changes
nothing.  `dropvision.analysis.sequence_summary.apply_findings` applies them.  The lies they catch (issue "hostile
and lying input"): a wrong pixel size (`check_pixel_size`), delays shifted, compressed or
stretched (`pinchoff_before_dead_time`, `pinchoff_before_stroke_end`,
`growth_short_at_max_stroke`), frames of another sequence (`attached_volume_outliers`,
`check_track`), a wrong nozzle inner diameter (`check_nozzle`) and an implausible jetting
velocity (`implausible_velocity`).
"""

from __future__ import annotations

import numpy as np

import dropvision.quality as q
from dropvision.calibrate.calibration import Calibration
from dropvision.config import MeasureConfig
from dropvision.analysis.findings import Finding, Withheld, frames_of
from dropvision.analysis.tracking import neighbour_outliers
from dropvision.frame.volume import NL_PER_UM3

#: What a delay lie withholds: the pinch-off, the flow and the jetting velocity.
DELAYS_WRONG = frozenset({Withheld.PINCHOFF, Withheld.FLOW, Withheld.VELOCITY})


def delays_text(delays) -> str:
    """Distinct delays, comma separated (at most 8)."""
    d = np.unique(np.asarray(delays, float))
    text = ", ".join(f"{v:g}" for v in d[:8])
    return text + (", ..." if d.size > 8 else "")


def mean_at_last_attached_delay(values, delay, attached, before_us: float, skip_unmeasured: bool = True) -> float:
    """Mean of the finite ``values`` at the last attached delay before ``before_us`` (the grown
    volume at the pinch-off, nl, and its uncertainty).

    ``skip_unmeasured``: the last attached delay that has a finite value (a delay whose frames
    are all NaN is passed over); False: the last attached delay, NaN when its frames are all NaN.
    NaN without an attached delay before ``before_us`` (or when it is NaN).
    """
    values = np.asarray(values, float)
    use = attached & (delay < before_us)
    if skip_unmeasured:
        use = use & np.isfinite(values)
    if not use.any():
        return float("nan")
    at = values[attached & (delay == delay[use].max()) & np.isfinite(values)]
    return float(np.mean(at)) if at.size else float("nan")


#: How far the resting meniscus's width at the tip plane may differ from the given inner diameter before
#: the pixel size is called wrong: it is the orifice's only as far as the meniscus is pinned at the
#: inner edge, and it is read off curved edges 1-3 px below the plane (honest synthetic sequences:
#: within 0.5 %); a pixel size off by a factor is far beyond.
INNER_DIAMETER_TOLERANCE = 0.10


def check_pixel_size(cal: Calibration, meta, config: MeasureConfig, n_frames: int,
                     dead_time_us: float | None = None) -> list[Finding]:
    """Compare the given pixel size with the one implied by the nozzle's outer diameter, and with
    the one implied by its inner diameter (`inner_diameter_ratio`).

    Outer diameter: beyond ``config.pixel_size_tolerance_fraction`` every one of the ``n_frames``
    frames is flagged and the length-dependent summary values are withheld.  Inside it a note is
    written when the ratio differs from 1 by more than ``config.pixel_size_note_sigmas`` standard
    uncertainties of the measured outer diameter: the edge fit locates the outer diameter to
    about 0.1 % on a 76 px nozzle, so a 1.5 % lie (+4.6 % volume) is far outside what the
    measurement itself can explain, while honest sequences stay within ~1 uncertainty.  With the
    walls out of focus the flag waits beyond what their blur allows (`blurred_width_fraction`), and
    a ratio inside that but beyond the tolerance is a note.

    Inner diameter: the resting meniscus's width at the tip plane times the pixel size is the
    inner diameter; beyond `INNER_DIAMETER_TOLERANCE` the same.
    This catches what the outer check cannot: no outer diameter given, an outer diameter scaled
    with the pixel size, a pixel size read from a TIFF description.  ``dead_time_us``: the frame
    it is read in must be at rest (its delay at most the dead time; None: no waveform, not checked).
    """
    ratio, u = cal.pixel_size_ratio, cal.pixel_size_ratio_uncertainty
    inner = inner_diameter_ratio(cal, meta, dead_time_us)
    blurred = blurred_width_fraction(cal)
    every = tuple(range(n_frames))
    wrong = frozenset({Withheld.LENGTH_SCALED})
    found = []
    if not getattr(meta, "nozzle_outer_diameter_um", None):
        if not np.isfinite(inner):
            found.append(Finding(note="pixel size unchecked (no nozzle_outer_diameter_um)"))
        elif abs(inner - 1.0) <= INNER_DIAMETER_TOLERANCE:
            found.append(Finding(note=f"pixel size checked against the inner diameter only (no "
                                      f"nozzle_outer_diameter_um): the resting meniscus's width implies {inner:.3f} x "
                                      "the given one"))
    elif np.isfinite(ratio) and config.pixel_size_tolerance_fraction < abs(ratio - 1.0) <= blurred:
        found.append(Finding(note=f"pixel size implied by the nozzle's outer diameter is {ratio:.4f} x the given one: "
                                  f"within what its out-of-focus walls allow (blur sigma {cal.nozzle_sigma_px:.1f} px "
                                  f"a side: +-{100 * blurred:.0f} %), not judged beyond that"))
    elif np.isfinite(ratio) and abs(ratio - 1.0) > config.pixel_size_tolerance_fraction:
        found.append(Finding(q.PIXEL_SIZE_MISMATCH, every,
                             f"pixel size implied by the nozzle's outer diameter is {ratio:.4f} x the given one "
                             f"(beyond {100 * config.pixel_size_tolerance_fraction:g} %): volumes and velocities not "
                             "given",
                             wrong))
    elif np.isfinite(ratio) and np.isfinite(u) and abs(ratio - 1.0) > config.pixel_size_note_sigmas * u:
        found.append(Finding(note=f"pixel size implied by the nozzle's outer diameter is {ratio:.4f} x the given one "
                                  f"(+-{u:.4f}): within the tolerance but beyond the edge fit's uncertainty; volumes "
                                  "scale with its cube"))
    if np.isfinite(inner) and abs(inner - 1.0) > INNER_DIAMETER_TOLERANCE:
        found.append(Finding(q.PIXEL_SIZE_MISMATCH, every,
                             f"pixel size implied by the nozzle's inner diameter ({meta.nozzle_inner_diameter_um:g} "
                             f"um over the resting meniscus's width, {cal.rest_meniscus_width_px:.1f} px) is "
                             f"{inner:.3f} x the given one (beyond {100 * INNER_DIAMETER_TOLERANCE:g} %): the pixel "
                             "size or the inner diameter is wrong; volumes and velocities not given", wrong))
    return found


def blurred_width_fraction(cal: Calibration) -> float:
    """How far (a fraction) an out-of-focus nozzle's outer width can be from its true one: each wall's
    50 % line is placed to about its own blur, ``sigma``, where other dark bodies lie within a few
    sigma of it (a holder's face and block), so the width to ``2 sigma`` of it.  On the synthetic
    drop watcher with its holder 8 px out of focus the width read 74.9-82.6 px for a 76 px capillary
    over tip phases (a correct pixel size flagged wrong at 4 of 6); a pixel size off by a factor is far
    beyond.  0 with the walls in focus or no width."""
    sigma, width = float(cal.nozzle_sigma_px), float(cal.nozzle_outer_diameter_px)
    if not (cal.nozzle_out_of_focus and sigma > 0 and np.isfinite(width) and width > 0):
        return 0.0
    return 2.0 * sigma / width


def inner_diameter_ratio(cal: Calibration, meta, dead_time_us: float | None = None) -> float:
    """Pixel size implied by the nozzle's inner diameter over the given one: the inner diameter (µm)
    over the resting meniscus's width at the tip plane (`Calibration.rest_meniscus_width_px`) times
    the given pixel size.  NaN without an inner diameter, without that width, when the frame
    it was read in is not known to be at rest (no ``dead_time_us``, or its delay beyond it), or when
    the liquid is as wide there as the walls (``Calibration.rest_meniscus_at_outer_edge``: pinned
    at their outer edge, like the synthetic pendant drop on a 720 um needle, 71.7 px for 72 px,
    which read as a pixel size 0.60 x the given one)."""
    d_in = getattr(meta, "nozzle_inner_diameter_um", None)
    width = cal.rest_meniscus_width_px
    if not d_in or not (np.isfinite(width) and width > 0):
        return float("nan")
    if dead_time_us is None or not cal.rest_meniscus_delay_us <= dead_time_us:
        # no waveform, or after the dead time: the meniscus may be anywhere (a pendant drop wets the face)
        return float("nan")
    if cal.rest_meniscus_at_outer_edge:  # pinned at the walls' outer edge: no inner diameter to read
        return float("nan")
    return float(d_in / (width * cal.pixel_size_um))


def check_track(delay, drop, config: MeasureConfig) -> list[Finding]:
    """In-flight frames whose main drop (`dropvision.analysis.tracking.DropTrack`) disagrees with the
    neighbouring delays.

    A position far off the track with the track's volume is the same drop at a wrong delay
    (``delay_inconsistent``); a volume far off (or both) is another body or another sequence
    (``inconsistent_with_neighbours``).  Either is left out of the in-flight values.
    """
    inf = drop.inflight.copy()
    if inf.sum() < 4:
        return []
    x = np.where(inf, delay, np.nan)
    vols = drop.drop_volume_nl
    med = float(np.nanmedian(vols[inf]))
    vol_out = neighbour_outliers(x, vols, config.track_outlier_sigmas, config.volume_outlier_floor_fraction * med)
    z_out = neighbour_outliers(x, drop.z_um, config.track_outlier_sigmas, config.track_outlier_floor_um)
    wrong_delay = z_out & ~vol_out
    other = vol_out
    out = frozenset({Withheld.INFLIGHT})
    found = []
    if wrong_delay.any():
        found.append(Finding(q.DELAY_INCONSISTENT, frames_of(wrong_delay),
                             f"the drop's position at {delays_text(delay[wrong_delay])} us does not follow its motion "
                             "at the neighbouring delays (drop going back up: delays mislabelled): left out", out))
    if other.any():
        found.append(Finding(q.NEIGHBOURS, frames_of(other),
                             f"the main drop at {delays_text(delay[other])} us differs in volume from its neighbours "
                             "far beyond the sequence's scatter (another body or sequence): left out", out))
    return found


def check_nozzle(meta, drop, attached, config: MeasureConfig) -> list[Finding]:
    """Drop volume against the nozzle, and inner >= outer diameter: is the inner diameter a lie?

    The nozzle volume is pi r_in^2 x d_in: the bore one inner diameter long, the length scale of
    the meniscus and of the liquid pushed out per stroke.  A drop larger than
    ``config.max_drop_to_nozzle_volumes`` of these cannot come from this nozzle.  A lie withholds
    the flow velocities and flags the ``attached`` frames (whose flow it is) ``implausible_physics``,
    and the frames of too large a drop.
    """
    d_in = meta.nozzle_inner_diameter_um
    d_out = getattr(meta, "nozzle_outer_diameter_um", None)
    flow = frozenset({Withheld.FLOW})
    found = []
    if d_in and d_out and d_in >= d_out:
        found.append(Finding(q.IMPLAUSIBLE, frames_of(attached),
                             f"nozzle inner diameter {d_in:g} um >= outer {d_out:g} um: impossible, flow velocities "
                             "not given", flow))
    if d_in:
        nozzle_nl = np.pi * (0.5 * d_in) ** 2 * d_in * NL_PER_UM3
        big = np.isfinite(drop.drop_volume_nl) & (drop.drop_volume_nl > config.max_drop_to_nozzle_volumes * nozzle_nl)
        if big.any():
            found.append(Finding(q.IMPLAUSIBLE, frames_of(big | attached),
                                 f"drop volume up to {np.nanmax(drop.drop_volume_nl[big]):.3g} nl is more than "
                                 f"{config.max_drop_to_nozzle_volumes:g} nozzle volumes ({nozzle_nl:.3g} nl for "
                                 f"{d_in:g} um): nozzle_inner_diameter_um wrong? flow velocities not given", flow))
    return found


def pinchoff_before_dead_time(pinch_us: float, dead_time_us: float, n_frames: int) -> list[Finding]:
    """A pinch-off before the waveform's dead time: the delays are shifted or in another unit.

    The piston has not moved before the dead time, so no drop can have separated.  Every one of
    the ``n_frames`` frames is flagged ``delay_inconsistent`` (every delay is wrong); pinch-off and
    velocities are withheld (`DELAYS_WRONG`).
    """
    if not (np.isfinite(pinch_us) and pinch_us < dead_time_us):
        return []
    return [Finding(q.DELAY_INCONSISTENT, tuple(range(n_frames)),
                    f"pinch-off at {pinch_us:g} us is before the waveform's dead time {dead_time_us:g} us: delays "
                    "shifted or in another unit; pinch-off and velocities not given", DELAYS_WRONG)]


def attached_volume_outliers(delay, attached_nl, attached, config: MeasureConfig) -> list[Finding]:
    """Attached frames whose volume disagrees with the neighbouring delays' (frames of another sequence).

    Judged by `dropvision.analysis.tracking.neighbour_outliers` over the attached frames with a volume
    (four at least), with a floor of ``config.volume_outlier_floor_fraction`` of the largest.
    The outliers are flagged ``inconsistent_with_neighbours`` and left out of the growth
    (`Withheld.ATTACHED_IN_GROWTH`).
    """
    ok = attached & np.isfinite(attached_nl)
    if ok.sum() < 4:
        return []
    scale = float(np.nanmax(np.abs(attached_nl[ok])))
    out = neighbour_outliers(np.where(ok, delay, np.nan), attached_nl, config.track_outlier_sigmas,
                             config.volume_outlier_floor_fraction * scale)
    if not out.any():
        return []
    return [Finding(q.NEIGHBOURS, frames_of(out),
                    f"{int(out.sum())} attached frame(s) ({delays_text(delay[out])} us) disagree with the "
                    "neighbouring delays' volume far beyond the sequence's scatter: left out",
                    frozenset({Withheld.ATTACHED_IN_GROWTH}))]


def pinchoff_before_stroke_end(pinch_us: float, max_stroke_us: float, n_frames: int) -> list[Finding]:
    """A pinch-off before the end of the stroke: the delays are compressed, or the waveform is not the one fired.

    A squeeze-mode drop separates after the piston has stopped pushing (the paper's campaign:
    1.7-2.8 stroke durations after the stroke's end); before it, the delays are compressed (e.g.
    halved) or the waveform in sequence.json is not the one fired.  Every frame is flagged
    ``delay_inconsistent``; pinch-off and velocities are withheld (`DELAYS_WRONG`).
    """
    if not (np.isfinite(pinch_us) and np.isfinite(max_stroke_us) and pinch_us < max_stroke_us):
        return []
    return [Finding(q.DELAY_INCONSISTENT, tuple(range(n_frames)),
                    f"pinch-off at {pinch_us:g} us is before the end of the stroke ({max_stroke_us:.0f} us after the "
                    "trigger): delays compressed or the waveform is not the one fired; pinch-off and velocities "
                    "not given", DELAYS_WRONG)]


def growth_short_at_max_stroke(grown_nl, delay, attached, grown_by_delay, pinch_us: float, max_stroke_us: float,
                               config: MeasureConfig) -> list[Finding]:
    """The meniscus grown by the maximum stroke is too little of what it grows by the pinch-off: delays stretched.

    The grown volume interpolated at the maximum stroke below
    ``config.min_growth_at_max_stroke_fraction`` of the grown volume just before the pinch-off
    (`mean_at_last_attached_delay`) means the delays are stretched or in another unit.  Every frame
    is flagged ``delay_inconsistent``; pinch-off and velocities are withheld (`DELAYS_WRONG`).
    No finding without a grown volume (no meniscus at rest: all NaN).
    """
    if not (np.isfinite(pinch_us) and np.isfinite(max_stroke_us)):
        return []
    g_at_pinch = mean_at_last_attached_delay(grown_nl, delay, attached, pinch_us)
    d_g = grown_by_delay.index.to_numpy(float)
    if not (np.isfinite(g_at_pinch) and g_at_pinch > 0 and d_g.size >= 2 and d_g.min() <= max_stroke_us <= d_g.max()):
        return []
    g_ms = float(np.interp(max_stroke_us, d_g, grown_by_delay.to_numpy(float)))
    if not g_ms < config.min_growth_at_max_stroke_fraction * g_at_pinch:
        return []
    return [Finding(q.DELAY_INCONSISTENT, tuple(range(len(delay))),
                    f"grown volume at the maximum stroke ({max_stroke_us:.0f} us) is {g_ms:.3g} nl, under "
                    f"{config.min_growth_at_max_stroke_fraction:g} of the {g_at_pinch:.3g} nl grown by the "
                    "pinch-off: delays stretched or in another unit; pinch-off and velocities not given", DELAYS_WRONG)]


def implausible_velocity(velocity_m_s: float, inflight, config: MeasureConfig) -> list[Finding]:
    """A jetting velocity outside ``config.min_jetting_velocity_m_s``..``max_jetting_velocity_m_s``.

    Implausible for drop-on-demand (delays in another unit, or a second moving body): the
    in-flight frames are flagged ``implausible_physics`` and the velocity is withheld.
    """
    if not np.isfinite(velocity_m_s) or (config.min_jetting_velocity_m_s <= velocity_m_s
                                         <= config.max_jetting_velocity_m_s):
        return []
    return [Finding(q.IMPLAUSIBLE, frames_of(inflight),
                    f"jetting velocity {velocity_m_s:.3g} m/s outside {config.min_jetting_velocity_m_s:g}.."
                    f"{config.max_jetting_velocity_m_s:g} m/s, implausible for drop-on-demand (delays in another "
                    "unit, or a second moving body): not given", frozenset({Withheld.VELOCITY}))]
