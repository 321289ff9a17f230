"""Shots of one rig: one calibration for all of them, the shots measured in parallel (issue 30 item 4).

A drop watcher's shots differ by their waveform; what does not change between them -- the background
(illumination), the holder's place and orientation, the blur reference, the pixel size -- is computed
once (`calibrate_rig`) and every shot is measured with it (`measure_each`), in forked worker
processes where the engine `dvcore.parallel.map_in_order` allows it (its fork-safety rules, issue 29:
this process runs one thread when it forks, OpenCV's pool is never started before,
`dvcore.parallel.serial_native_pools`; every wait on a worker is bounded by the watchdog).

Robustness: the calibration shots (up to ``config.calibration_frames``, spread over the folder, the
first included) are compared with each other by their fingerprint (`fingerprint`: the frame reduced
to some 512 px, over its bright level): the shift of the static scene (the outlines of the dark
bodies touching the frame's edge: holder, nozzle) and the change of the background's shape beyond a
gain (`scene_distance`, `disagreement`). The shot agreeing with most others (the medoid) is the
reference of the first group: those agreeing with it; the same again among the shots left, while a
group holds two or more, up to `MAX_GROUPS` groups (`calibrate_rigs`: several rigs, or the holder
at several places, in one folder, each place with its own calibration; one by default, see there). A
group's calibration is its reference's own, the one that shot gets alone (its row in the folder is its
row alone; with the frames of several shots the blur reference would be the sharpest body of all, and
with three or more a drop at the same place in all of them would be folded into the background as
static dust: a drop watcher's drops fly at the same place shot after shot). Every shot is
checked against the groups' references, in that order, and measured with the first calibration that
holds for it; one for which none holds (another camera position, another illumination, another size)
is measured alone, as a folder holding only that image is, with a note. Fewer than two calibration
shots agreeing: no shared calibration, every shot alone (as before).

Costs (tools/bench_shots.py): a forked worker sends back what a shot's tables are made of
(`dropvision.measurement.MeasuredParts`), and the tables are made in the calling process, so pandas
(some 0.5 s of CPU to import) loads once, not once more in every worker -- each shot's as it comes
back, while the workers measure the next ones (they are all forked before); a calibration shot that
agrees with no group is not decoded and compared again.

What differs from a shot measured alone (all but the references): the background, the liquid's level,
the blur reference and the orientation are its group's reference shot's; hence volumes within a
fraction of their uncertainty of the solo ones (tools/bench_shots.py prints the table: within 0.3 u on
the 12 synthetic shots and the 2 real ones of one holder place; the references to the bit).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dropvision.config import MeasureConfig
from dropvision.io.sequence_meta import FrameRef, SequenceError

__all__ = ["Fingerprint", "RigCalibration", "ShotOutcome", "calibrate_rig", "calibrate_rigs", "disagreement", "fingerprint",
           "measure_each"]

#: Longest side (px) of the reduced frame a fingerprint is taken on.
FINGERPRINT_SIDE_PX = 512
#: Largest shift (px, full frame) of a shot's scene against the reference's for the shared
#: calibration to hold for it (the holder's place, the tip plane, the axis move with the camera).
MAX_SHIFT_PX = 2.0
#: Largest change of the background's shape beyond a gain (the ratio of the two frames over their
#: bright pixels, block by block, off its median: `scene_distance`) for the shared calibration to hold.
MAX_BACKGROUND_CHANGE = 0.05
#: Most groups of agreeing calibration shots that get a shared calibration (`calibrate_rigs`). One: on the
#: real drop-watcher frames a second group (frames 3 and 4 of watcher-dod, at one holder place) gave answers of
#: another kind than alone -- calibrated from both, a speck of frame 4 became a satellite (1 -> 2, outside its
#: accepted count); with the reference's own calibration (frame 4's, which finds no nozzle), frame 3 was
#: measured without a nozzle (quality ok -> no_nozzle, attached volume NaN, +0.38 u) -- so further groups are
#: calibrated alone shot by shot.
MAX_GROUPS = 1
#: Fewest shots measured in forked processes (a shot costs a decoding and an assembly, ~50-100 ms
#: for a 2048 x 1536 JPEG: far more than a fork).
MIN_SHOTS_FOR_PROCESSES = 4


@dataclass(frozen=True)
class Fingerprint:
    """A frame reduced to some `FINGERPRINT_SIDE_PX` px (area mean) over its bright level
    (95th percentile); ``scale`` full-frame px per reduced px, ``shape`` the full frame's."""

    image: np.ndarray
    scale: float
    shape: tuple[int, int]
    #: `_static_edges` of ``image`` (computed once)
    edges: np.ndarray | None = None


def fingerprint(image: np.ndarray) -> Fingerprint:
    """The `Fingerprint` of a frame (grey levels, any orientation: compare like with like)."""
    import cv2

    img = np.asarray(image, np.float32)
    h, w = img.shape[:2]
    f = max(1, int(math.ceil(max(h, w) / FINGERPRINT_SIDE_PX)))
    small = cv2.resize(img, (max(1, w // f), max(1, h // f)), interpolation=cv2.INTER_AREA) if f > 1 else img
    level = float(np.percentile(small, 95))
    norm = (small / max(level, 1e-6)).astype(np.float32)
    return Fingerprint(norm, float(f), (int(h), int(w)), _static_edges(norm))


def _static_edges(image: np.ndarray) -> np.ndarray:
    """Edge strength of a fingerprint along its static scene only: the outlines of the dark bodies
    (below half the bright level) that touch the frame's edge -- the holder, the nozzle, a vignetted
    corner -- within `_BAND` px; detached drops, which differ from shot to shot, do not count."""
    import cv2

    mask = (image < 0.5).astype(np.uint8)
    _, lab = cv2.connectedComponents(mask, connectivity=8)
    edge = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    touching = np.isin(lab, edge[edge > 0]).astype(np.uint8)
    k = np.ones((_BAND, _BAND), np.uint8)
    band = cv2.dilate(touching, k) - cv2.erode(touching, k)
    smooth = cv2.GaussianBlur(image, (0, 0), 1.0)
    grad = cv2.magnitude(cv2.Sobel(smooth, cv2.CV_32F, 1, 0), cv2.Sobel(smooth, cv2.CV_32F, 0, 1))
    return grad * band


#: Width (reduced px) of the band about the static outlines, and the most shift searched (reduced px).
_BAND, _SEARCH = 9, 16
#: Blocks across the frame (each way) in which the background's change is judged.
_BLOCKS = 16


def scene_distance(fp: Fingerprint, ref: Fingerprint, max_shift_px: float = math.inf) -> tuple[float, float]:
    """(shift of the static scene in full-frame px, change of the background's shape) of ``fp``
    against ``ref``; (inf, inf) for frames of other sizes.

    The shift: the best match (normalised cross-correlation, to a tenth of a reduced px) of the
    reference's static outlines (`_static_edges`, less a margin of `_SEARCH` px) in the frame's;
    the margin where the match is at the edge of the search. The change: the frame over the
    reference in `_BLOCKS` x `_BLOCKS` blocks (the median over the pixels bright in both and 2 px
    away from any dark body, blocks at least half such), over their median; the 90th percentile of
    their departures from 1 (a drop spoils a few blocks, another light most). A shift beyond
    ``max_shift_px``: the change is not computed (NaN)."""
    import cv2

    if fp.shape != ref.shape or fp.image.shape != ref.image.shape:
        return math.inf, math.inf
    m = min(_SEARCH, min(ref.image.shape) // 4)
    res = cv2.matchTemplate(fp.edges, ref.edges[m:-m, m:-m], cv2.TM_CCORR_NORMED)
    _, _, _, (x, y) = cv2.minMaxLoc(res)

    def sub(c: float, lo: float, hi: float) -> float:
        d = lo - 2.0 * c + hi
        return 0.0 if d == 0 else float(np.clip(0.5 * (lo - hi) / d, -0.5, 0.5))

    dx = x - m + (sub(res[y, x], res[y, x - 1], res[y, x + 1]) if 0 < x < res.shape[1] - 1 else 0.0)
    dy = y - m + (sub(res[y, x], res[y - 1, x], res[y + 1, x]) if 0 < y < res.shape[0] - 1 else 0.0)
    shift = math.hypot(dx, dy) * fp.scale
    if shift > max_shift_px:
        return float(shift), math.nan
    dark = ((fp.image < 0.5) | (ref.image < 0.5)).astype(np.uint8)
    both = cv2.dilate(dark, np.ones((5, 5), np.uint8)) == 0  # bright in both, away from any body's edge
    h, w = both.shape
    bh, bw = h // _BLOCKS, w // _BLOCKS
    if bh < 2 or bw < 2:
        return float(shift), math.inf
    ratio = np.where(both, fp.image / np.maximum(ref.image, 1e-6), np.nan)[:bh * _BLOCKS, :bw * _BLOCKS]
    blocks = ratio.reshape(_BLOCKS, bh, _BLOCKS, bw).transpose(0, 2, 1, 3).reshape(_BLOCKS * _BLOCKS, -1)
    count = np.isfinite(blocks).sum(axis=1)
    keep = count >= 0.5 * bh * bw
    blocks, count = np.sort(blocks[keep], axis=1), count[keep]  # NaN sorts last
    if len(blocks) < 8:
        return float(shift), math.inf
    rows = np.arange(len(blocks))
    med = 0.5 * (blocks[rows, (count - 1) // 2] + blocks[rows, count // 2])  # the median of each block's values
    med = med / float(np.median(med))
    return float(shift), float(np.percentile(np.abs(med - 1.0), 90))


class Disagreement(str):
    """Why a shared calibration does not hold for a shot (the text, written in notes), and whether the
    shot is of the same view as the reference (``same_view``: same size, its scene compared, shifted or
    lit otherwise): such a shot measured alone is measured from its frame as decoded, in the
    reference's orientation.  Decisions read ``same_view``, never the text."""

    same_view: bool

    def __new__(cls, text: str, same_view: bool = False):
        out = super().__new__(cls, text)
        out.same_view = same_view
        return out


def disagreement(fp: Fingerprint, ref: Fingerprint) -> Disagreement | None:
    """Why the shared calibration (of the reference ``ref``) does not hold for a frame, or None.

    Another frame size; its scene shifted by more than `MAX_SHIFT_PX` (the camera or the holder
    moved); its background's shape changed by more than `MAX_BACKGROUND_CHANGE` beyond a gain
    (the light moved, or another backlight): the last two are of the same view (``same_view``)."""
    if fp.shape != ref.shape:
        return Disagreement(f"its size {fp.shape[1]}x{fp.shape[0]} differs from the shared calibration's "
                            f"{ref.shape[1]}x{ref.shape[0]}")
    shift, change = scene_distance(fp, ref, MAX_SHIFT_PX)
    if shift > MAX_SHIFT_PX:
        return Disagreement(f"its scene is shifted by {shift:.1f} px against the shared calibration's (most "
                            f"{MAX_SHIFT_PX:g} px)", same_view=True)
    if change > MAX_BACKGROUND_CHANGE:
        return (Disagreement(f"its background differs by {100 * change:.0f} % from the shared calibration's beyond "
                             f"a gain (most {100 * MAX_BACKGROUND_CHANGE:.0f} %)", same_view=True)
                if math.isfinite(change) else
                Disagreement("too little background in common with the shared calibration's"))
    return None


def _agree(fp: Fingerprint, ref: Fingerprint) -> bool:
    shift, change = scene_distance(fp, ref, MAX_SHIFT_PX)
    return shift <= MAX_SHIFT_PX and change <= MAX_BACKGROUND_CHANGE


@dataclass
class RigCalibration:
    """The calibration the shots of one rig share (`calibrate_rig`).

    Attributes
    ----------
    meta : SequenceMeta
        The reference shot's metadata (orientation, pixel size, bit depth, sources); a shot's own is
        this with its file and delay.
    dtype : numpy dtype
    cal, sigma_px, ctx
        As `dropvision.calibrate.calibration_pass.calibrate_sequence` gives them.
    flags : list of str
        Quality codes every shot measured with it gets (`dropvision.measurement.calibration_flags`).
    reference : Fingerprint
        The reference shot's (canonical orientation): a shot is checked against it.
    reference_name : str
    calibrated_from : list of str
        The shots the calibration comes from.
    left_out : dict
        Calibration shot -> why it was left out (it disagrees with the reference).
    """

    meta: object
    dtype: np.dtype
    cal: object
    sigma_px: float
    ctx: object
    flags: list[str]
    reference: Fingerprint
    reference_name: str
    calibrated_from: list[str]
    left_out: dict[str, str] = field(default_factory=dict)

    def to_dict(self) -> dict:
        """summary.json's ``shared_calibration``."""
        return {"reference": self.reference_name, "calibrated_from": list(self.calibrated_from),
                "left_out": [{"file": k, "reason": v} for k, v in self.left_out.items()]}


#: Pixel-size sources that are a file's own metadata (`dropvision.io.readers`): not shared between shots.
_FILE_PIXEL_SIZE = ("ome", "imagej", "tiff-description")


def _spread(n: int, k: int) -> list[int]:
    """Up to ``k`` indices spread over ``range(n)``, the first included."""
    return [int(i) for i in np.unique(np.round(np.linspace(0, n - 1, min(n, max(1, k)))).astype(int))]


def _shot_ref(path: Path, name: str, delay_us: float, index: int = 0) -> FrameRef:
    return FrameRef(index, path.name if index == 0 else str(path), None, float(delay_us), 0, index)


def _inside_own_folder(path: Path) -> bool:
    """The image is no symbolic link resolving outside its folder (such a shot is measured alone:
    `dropvision.io.sequence.open_sequence` refuses it and says why)."""
    try:
        return os.path.dirname(os.path.realpath(path)) == os.path.realpath(path.parent)
    except OSError:
        return False


def calibrate_rig(shots, config: MeasureConfig = MeasureConfig(), *, overrides: dict | None = None,
                  option_labels: dict | None = None) -> tuple[RigCalibration | None, str | None]:
    """The calibration most of the calibration shots share (the first of `calibrate_rigs`), or
    None and why there is none."""
    rigs, why, _ = calibrate_rigs(shots, config, overrides=overrides, option_labels=option_labels)
    return (rigs[0] if rigs else None), why


def calibrate_rigs(shots, config: MeasureConfig = MeasureConfig(), *, overrides: dict | None = None,
                   option_labels: dict | None = None, max_groups: int | None = None
                   ) -> tuple[list[RigCalibration], str | None, dict[int, str]]:
    """The calibrations the shots share, from up to ``config.calibration_frames`` of them: one per
    group of calibration shots that agree (several rigs, or one camera at several places, in one folder).

    The calibration shots are compared pairwise (`fingerprint`, `scene_distance`); the shot agreeing
    with most others (the first of them on a tie) and those agreeing with it are the first group, the
    largest; the same again among the shots left, while a group holds two or more. Each group is
    calibrated from its shots together (the reference: that shot).

    Parameters
    ----------
    shots : dropvision.analysis.shots.ShotInput
    config : MeasureConfig
    overrides, option_labels : dict, optional
        As for `dropvision.io.sequence.open_sequence` (they apply to every shot).
    max_groups : int, optional
        Most groups calibrated (`MAX_GROUPS` by default); the shots of the others are measured alone.

    Returns
    -------
    (list of RigCalibration, reason, alone)
        The groups' calibrations, the largest first (empty, and why, when no two calibration shots
        agree, the reference cannot be opened or calibrated: every shot is then measured alone);
        ``alone``: calibration shot index -> why it agrees with no group (it is measured alone
        without being compared again).
    """
    from dropvision.io.sequence import open_sequence, pixel_size_from_nozzle

    max_groups = MAX_GROUPS if max_groups is None else max_groups
    n = len(shots.paths)
    if n < 2:
        return [], "a single shot", {}
    picks = [i for i in _spread(n, config.calibration_frames) if _inside_own_folder(shots.paths[i])
             and not _own_metadata(shots, i)]
    stored: dict[int, np.ndarray] = {}
    first_meta = None
    for i in picks:  # decoded as stored (no warnings here: each shot gives its own when measured)
        path = shots.paths[i]
        try:
            if first_meta is None:
                first_meta = open_sequence(path.parent, overrides=overrides, labels=option_labels,
                                           only_files=[path.name]).meta
            probe = _stored_sequence(first_meta, path, shots.names[i])
            stored[i] = probe._decode(probe.meta.frames[0], warn=False)
        except Exception:  # noqa: BLE001 - an unreadable calibration shot is left out (measured alone, it says why)
            continue
    if len(stored) < 2:
        return [], "fewer than two calibration shots could be read", {}
    if first_meta.pixel_size_source in _FILE_PIXEL_SIZE:
        return [], f"the pixel size is each image's own (its {first_meta.pixel_size_source} metadata)", {}
    if pixel_size_from_nozzle(first_meta):
        return [], "the pixel size is each shot's own needle width (no pixel size given)", {}
    prints = {i: fingerprint(img) for i, img in stored.items()}
    keys = list(prints)
    agree: dict[int, set[int]] = {i: {i} for i in keys}
    for a, i in enumerate(keys):  # the distance is near symmetric: each pair judged once
        for j in keys[a + 1:]:
            if _agree(prints[j], prints[i]):
                agree[i].add(j)
                agree[j].add(i)
    rigs: list[RigCalibration] = []
    failed: list[str] = []
    grouped: set[int] = set()
    left = list(keys)
    while len(left) >= 2 and len(rigs) + len(failed) < max_groups:
        groups = {i: sorted(agree[i] & set(left)) for i in left}
        reference = max(left, key=lambda i: (len(groups[i]), -keys.index(i)))  # the first of the most agreeing
        members = groups[reference]
        if len(members) < 2:
            break
        left = [i for i in left if i not in members]
        # the reference's own calibration (its answer in the folder is its answer alone): with several
        # frames, the blur reference would be the sharpest body of all, and with three or more a body dark
        # in all of them is folded into the background as static dust -- a drop watcher's drops fly at the
        # same place shot after shot (`dropvision.calibrate.background.estimate_background`)
        rig, why = _calibrate_group(shots, config, overrides, option_labels, first_meta, picks, stored,
                                    [reference], reference)
        if rig is None:
            failed.append(why)
        else:
            rigs.append(rig)
            grouped |= set(members)
    if not rigs:
        return [], (failed[0] if failed else
                    f"no two of the {len(keys)} calibration shots agree (camera position or light differ)"), {}
    # the calibration shots in no group: measured alone, as the largest group's reference judged them
    main_ref = next(i for i in keys if shots.names[i] == rigs[0].reference_name)
    alone = {i: disagreement(prints[i], prints[main_ref]) or "it agrees with no shared calibration"
             for i in keys if i not in grouped}
    rigs[0].left_out = {shots.names[i]: why for i, why in alone.items()}
    return rigs, None, alone


def _stored_sequence(meta, path: Path, name: str):
    """A one-frame `dropvision.io.sequence.Sequence` of the image at ``path`` read as stored."""
    from dropvision.io.sequence import Sequence

    return Sequence(dataclasses.replace(meta, path=path.parent, orientation="down", shape=(0, 0),
                                        frames=(_shot_ref(path, name, 0.0),)), np.uint8)


def _calibrate_group(shots, config, overrides, option_labels, first_meta, picks, stored, members, reference
                     ) -> tuple[RigCalibration | None, str | None]:
    """The `RigCalibration` of one group of agreeing calibration shots (``members``, indices into
    ``shots``; ``stored``: their images as stored), or None and why it failed."""
    from dropvision.calibrate.calibration_pass import calibrate_sequence
    from dropvision.measurement import calibration_flags, check_scale_in_focus
    from dropvision.io.orientation import to_canonical
    from dropvision.io.sequence import ArraySequence, open_sequence

    first = members[0]
    try:
        meta = first_meta if first == picks[0] else open_sequence(
            shots.paths[first].parent, overrides=overrides, labels=option_labels,
            only_files=[shots.paths[first].name]).meta
        images = [to_canonical(stored[i], meta.orientation) for i in members]
        if any(img.shape != meta.shape or img.dtype != images[0].dtype for img in images):
            return None, "the calibration shots differ in size or pixel type"
        delay = float((overrides or {}).get("delay_us") or 0.0)
        # the calibration shots as a sequence in memory (distinct delays: each is a calibration frame)
        frames = tuple(FrameRef(k, str(shots.paths[i]), None, float(k), 0, k) for k, i in enumerate(members))
        pseudo = ArraySequence(dataclasses.replace(meta, frames=frames), images)
        # the drops of shots at one strobe delay sit at nearly one place: not dust (as for a shot alone)
        cal, sigma, ctx = calibrate_sequence(pseudo, config, static_dust=False)
        if not cal.nozzle_found:  # whether the nozzle is found differs between shots of one place (real frames)
            return None, ("the reference shot's calibration finds no nozzle (a shot of its place may find one "
                          "alone): no shared calibration")
        cal = dataclasses.replace(cal, rest_meniscus_delay_us=(delay if math.isfinite(cal.rest_meniscus_delay_us)
                                                               else cal.rest_meniscus_delay_us))
        check_scale_in_focus(cal, meta)
    except (SequenceError, ValueError) as exc:
        return None, f"the shared calibration failed ({exc})"
    names = [shots.names[i] for i in members]
    shared = (f"calibration shared by the shots of one rig: from {len(members)} shot(s) ("
              + ", ".join(names[:3]) + (", ..." if len(names) > 3 else "") + ")")
    cal = dataclasses.replace(cal, notes=cal.notes + (shared,))
    rig = RigCalibration(meta=meta, dtype=images[0].dtype, cal=cal, sigma_px=float(sigma), ctx=ctx,
                         flags=calibration_flags(cal, sigma, config),
                         reference=fingerprint(to_canonical(stored[reference], meta.orientation)),
                         reference_name=shots.names[reference], calibrated_from=names)
    return rig, None


@dataclass
class ShotOutcome:
    """One shot measured (`measure_each`): its result or why not, and how it was calibrated.

    ``result`` a `dropvision.measurement.MeasureResult` (None with ``error``); ``shared`` whether the
    shared calibration measured it; ``note`` why it was measured alone (None: shared, or no shared
    calibration at all); ``warnings`` (category, message) raised while measuring it."""

    name: str
    result: object = None
    error: str | None = None
    #: what the shot's tables are made of (`dropvision.measurement.MeasuredParts`), until `measure_each` makes them
    parts: object = None
    shared: bool = False
    note: str | None = None
    warnings: list = field(default_factory=list)


#: Labels that are a shot's own metadata (a shots.csv column, sequence.json ``shots`` key): a folder of pendant
#: drops hanging from needles of several sizes, each shot with its needle's diameter.
SHOT_METADATA_LABELS = ("pixel_size_um", "nozzle_outer_diameter_um", "nozzle_inner_diameter_um")


def shot_metadata(shots, name: str, overrides: dict | None, option_labels: dict | None
                  ) -> tuple[dict | None, dict | None]:
    """The sequence.json values of one shot: the options', and its own labels named like
    `SHOT_METADATA_LABELS` (they win: they are the shot's own), and how each was given."""
    own = {k: v for k, v in shots.labels.get(name, {}).items() if k in SHOT_METADATA_LABELS}
    if not own:
        return overrides, option_labels
    how = dict(option_labels or {})
    for key in own:
        how[key] = f"{shots.label_sources.get(key, 'labels')} ({name})"
    return {**(overrides or {}), **own}, how


def _own_metadata(shots, i: int) -> bool:
    """Whether shot ``i`` has sequence.json values of its own (its pixel size or nozzle diameters
    as labels, `dropvision.analysis.shots.shot_metadata`): it is calibrated alone."""
    return any(k in SHOT_METADATA_LABELS for k in shots.labels.get(shots.names[i], {}))


def _alone(shots, i: int, config: MeasureConfig, overrides, option_labels):
    """Shot ``i`` measured as a folder holding only that image is (`dropvision.measurement.measure_parts`)."""
    from dropvision.measurement import measure_parts
    from dropvision.io.sequence import open_sequence
    path = shots.paths[i]
    over, how = shot_metadata(shots, shots.names[i], overrides, option_labels)
    seq = open_sequence(path.parent, overrides=over, labels=how, only_files=[path.name])
    return measure_parts(seq, config)


def _with_rig(path: Path, name: str, rigs, config: MeasureConfig, delay_us: float, decoded: dict | None = None):
    """(parts, None) measured with the first shared calibration that holds for the shot (a
    `dropvision.measurement.MeasuredParts`), or (None, why none holds: the first's reason).
    ``decoded`` receives (orientation, shape, dtype) -> (frame, fingerprint or why not) of the shot."""
    from dropvision.frame.measure_frame import measure_frame
    from dropvision.measurement import MeasuredParts, light_calibration
    from dropvision.io.sequence import Sequence

    if isinstance(rigs, RigCalibration):
        rigs = [rigs]
    if not _inside_own_folder(path):
        return None, "a link outside its folder"
    first_why = None
    decoded = {} if decoded is None else decoded
    for rig in rigs:
        meta = dataclasses.replace(rig.meta, path=path.parent, frames=(_shot_ref(path, name, delay_us),),
                                   reordered=False)
        key = (rig.meta.orientation, rig.meta.shape, np.dtype(rig.dtype).str)
        if key not in decoded:
            seq = Sequence(meta, rig.dtype)
            try:
                fr = seq.read(0)
                decoded[key] = (fr, None if fr.image is None else fingerprint(fr.image))
            except SequenceError as exc:  # another size or pixel type: its own calibration says what it is
                decoded[key] = (None, str(exc).split(": ", 1)[-1])
            finally:
                seq.close()
        fr, fp = decoded[key]
        if fr is None or fr.image is None:
            why = fp if fr is None else fr.error
        else:
            why = disagreement(fp, rig.reference)
        if why is None:
            rec = measure_frame(fr.image, rig.ctx, fr.ref)
            rec.flags = list(rig.flags) + rec.flags
            return MeasuredParts([rec], light_calibration(rig.cal), rig.sigma_px, float(rig.ctx.blur.reference_spread_px),
                                 rig.ctx.blur.reference, meta, []), None
        first_why = first_why or why
        if fr is None or fr.image is None:
            break
    return None, first_why


def _alone_as_decoded(path: Path, name: str, rig: RigCalibration, config: MeasureConfig, delay_us: float,
                      decoded: dict):
    """The parts of a shot measured alone (its own calibration, as `_alone`) from its frame as decoded
    in the shared calibration's geometry (orientation, size, pixel type: its scene was compared with the
    reference's, so it is the same view), without opening it again: None when not decoded so (another
    size or pixel type, unreadable: `_alone` says what it is)."""
    from dropvision.measurement import measure_parts
    from dropvision.io.sequence import ArraySequence, Sequence

    meta = dataclasses.replace(rig.meta, path=path.parent, frames=(_shot_ref(path, name, delay_us),),
                               reordered=False)
    key = (rig.meta.orientation, rig.meta.shape, np.dtype(rig.dtype).str)
    sources = dict(rig.meta.sources or {})
    sources["orientation"] = (f"the shared calibration's reference's, {rig.reference_name} (the same view, its scene "
                              f"compared): {sources.get('orientation')}")
    if key not in decoded:
        seq = Sequence(meta, rig.dtype)
        try:
            fr = seq.read(0)
            decoded[key] = (fr, None)
        except SequenceError:
            return None
        finally:
            seq.close()
    fr = decoded[key][0]
    if fr is None or fr.image is None:
        return None
    return measure_parts(ArraySequence(dataclasses.replace(meta, sources=sources), [fr.image]), config)


def _measure_one(i: int, state) -> ShotOutcome:
    """Shot ``i``: with a shared calibration where one holds, else alone (its own calibration);
    its warnings recorded (given in the calling process, in order). The outcome holds the shot's
    `dropvision.measurement.MeasuredParts` (``parts``): its tables are made by `measure_each`."""
    shots, rigs, known_alone, config, overrides, option_labels = state
    path, name = shots.paths[i], shots.names[i]
    out = ShotOutcome(name)
    delay = float((overrides or {}).get("delay_us") or 0.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            why, decoded, same_view = None, {}, False
            if rigs and _own_metadata(shots, i):
                why = "its own pixel size or nozzle diameter labels"
            elif rigs and i in known_alone:  # a calibration shot that agrees with no group: compared already
                why = known_alone[i]
                same_view = getattr(why, "same_view", False)
            elif rigs:
                out.parts, why = _with_rig(path, name, rigs, config, delay, decoded)
                out.shared = out.parts is not None
                same_view = out.parts is None and getattr(why, "same_view", False)
            if out.parts is None and same_view:  # its scene was compared: the same view, measured alone
                out.parts = _alone_as_decoded(path, name, rigs[0], config, delay, decoded)
            if out.parts is None:
                out.parts = _alone(shots, i, config, overrides, option_labels)
            if not out.shared and why is not None:
                out.note = f"calibrated alone: {why}"
        except SequenceError as exc:
            out.parts, out.error = None, str(exc)
    out.warnings = [(w.category, str(w.message)) for w in caught]
    return out


def measure_each(shots, config: MeasureConfig = MeasureConfig(), *, overrides: dict | None = None,
                 option_labels: dict | None = None, shared: bool = True, workers: int | None = None
                 ) -> tuple[list[ShotOutcome], list[RigCalibration], str | None]:
    """Measure every shot: with a shared calibration (`calibrate_rigs`) where one holds, else alone.

    Parameters
    ----------
    shots : dropvision.analysis.shots.ShotInput
    config : MeasureConfig
    overrides, option_labels : dict, optional
        As for `dropvision.io.sequence.open_sequence`.
    shared : bool
        False: every shot alone, as a folder holding only that image (no shared calibration).
    workers : int, optional
        Forked processes (``config.workers`` by default; 1: in this process). The outcomes are the
        same either way. A worker sends back what the tables are made of
        (`dropvision.measurement.MeasuredParts`); the tables are made here, after the workers are
        done (pandas, whose import starts a thread and costs more than a shot, loads once, here).

    Returns
    -------
    (outcomes in the shots' order, the shared calibrations (the largest group's first; empty
    when none), why there is none or None)
    """
    from dvcore.parallel import map_in_order, processes_usable, relay_warnings, serial_native_pools

    workers = max(1, config.workers if workers is None else workers)
    n = len(shots.paths)
    forked = processes_usable(n, workers, min_items=MIN_SHOTS_FOR_PROCESSES)
    rigs, known_alone, why = [], {}, "not asked for" if not shared else None
    with serial_native_pools(forked):  # this process still runs one thread when it forks (issue 29)
        if shared:
            rigs, why, known_alone = calibrate_rigs(shots, config, overrides=overrides, option_labels=option_labels)
        state = (shots, rigs, known_alone, config, overrides, option_labels)
        # the engine decides again at the fork (the calibration started no thread: it forks); each shot's
        # tables made here as it comes back, while the workers measure the next ones. A shot records its
        # own warnings (`_measure_one`): never on threads (catch_warnings is not thread-safe)
        outcomes = []
        each = map_in_order(lambda i: _measure_one(i, state), range(n), workers if forked else 1, threads=False,
                            min_items=MIN_SHOTS_FOR_PROCESSES, max_chunk=8,
                            label=str(shots.inputs[0]) if shots.inputs else "", unit="shot")
        try:
            for out in each:
                outcomes.append(_tables(out, config))
        finally:
            each.close()
    for out in outcomes:  # the colour note of every shot is its own (each shot is a sequence of one frame)
        relay_warnings(out.warnings)
    return outcomes, rigs, why


def _tables(out: ShotOutcome, config: MeasureConfig) -> ShotOutcome:
    """A shot's result (its tables) made from its parts, their warnings recorded (given in order by
    `measure_each`)."""
    if out.parts is not None:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                out.result = out.parts.result(config)
            except SequenceError as exc:
                out.result, out.error = None, str(exc)
        out.parts = None
        out.warnings += [(w.category, str(w.message)) for w in caught]
    return out
