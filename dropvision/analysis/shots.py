"""Shots as labs record them: a folder of images with no delay to tell, one row per image.

A drop watcher exports one image per shot, each of another setting (its voltages and pulse times in
the file name), not a strobe sequence. `find_shots` decides (`dropvision.io.discovery.images_without_delay`):
a folder with no frames list nor frame rate (sequence.json or options), of two or more single-frame
images none of which tells a delay, is a folder of shots; several image files are too. Anything else
is a sequence (`dropvision.measurement.measure_sequence`, unchanged).

`measure_shots` measures the shots of one rig with the calibration they share (`dropvision.analysis.shot_rig`:
background, holder's place and orientation, blur reference, pixel size computed once from up to
``calibration_frames`` shots; the shots in forked worker processes); a shot that disagrees with it
(another camera position or light) is measured alone, exactly as a folder holding only that image
(`dropvision.io.sequence.open_sequence` with ``only_files``, then `measure_sequence`), with a note. It writes

- ``frames.parquet`` / ``bodies.parquet``: the per-frame tables of every shot (``file`` tells them apart);
- ``shots.parquet`` (`dvcore.schema.SHOTS`): one row per image, its labels as numbers
  (`dropvision.io.labels`), built from the frames table by `shots_table` (nothing is measured again);
- ``summary.json`` (`dvcore.schema.SHOTS_SUMMARY`): the count, the medians, what was parsed from where.

A waveform template declared without its parameters (sequence.json ``waveform: {"template":
"three_pulse"}``, or ``--waveform-template three_pulse``) makes each shot's labels its parameters
(`label_waveform`: ``images_V1--86_V2-12_V3--30_w1-26_w2-10_w3-31_d1-7_d2-5.jpg`` is V1 = -86 V, ...,
d2 = 5 us): every parameter must be a label of every shot, each within the template's ranges, and no
other label may stand beside them (a one-line error naming the image otherwise); summary.json
``waveform`` records the template.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dropvision.config import MeasureConfig
from dropvision.io.discovery import images_without_delay
from dropvision.io.labels import (
    LABEL_TABLE, LabelError, compile_pattern, labels_from_document, labels_from_name, labels_from_pattern, merge_labels,
    read_label_table,
)
from dropvision.io.readers import IMAGE_SUFFIXES
from dropvision.analysis.shot_rig import SHOT_METADATA_LABELS, shot_metadata
from dropvision.io.sequence import SEQUENCE_JSON
from dropvision.io.sequence_meta import SequenceError
from dvcore import schema
from dvcore.atomic import atomic_dir, check_output_dir
from dvcore.jsonio import load_json_hardened
from dvcore.versions import software_versions

if TYPE_CHECKING:  # pandas loads where a table is made
    import pandas as pd

__all__ = ["ShotInput", "ShotsResult", "find_shots", "is_shot_folder", "sequence_settings_given", "shots_of",
           "measure_shots", "label_waveform", "shots_table", "one_line", "double_exposure_velocity", "shot_metadata",
           "STROBE_INTERVAL_LABEL", "SHOT_METADATA_LABELS"]

#: sequence.json keys (and options) that make a folder a sequence, not shots
_SEQUENCE_KEYS = ("frames", "frame_rate_hz", "video")


@dataclass
class ShotInput:
    """The images of a shot folder and their labels.

    Attributes
    ----------
    paths : list of Path
        The images (absolute).
    names : list of str
        How each is named in the tables: relative to the folder, or the path as given when the files
        come from several folders.
    inputs : list of Path
        The folder(s) read (outputs may not lie there).
    labels : dict
        Name -> label name -> value.
    label_sources : dict
        Label name -> where it was read (``file names``, ``--label-pattern``, ``sequence.json`` (its
        ``shots`` list), ``shots.csv``; several joined by `` and ``).
    from_folder : bool
        One folder was given (else image files).
    """

    paths: list[Path]
    names: list[str]
    inputs: list[Path]
    labels: dict[str, dict[str, float]] = field(default_factory=dict)
    label_sources: dict[str, str] = field(default_factory=dict)
    from_folder: bool = True

    @property
    def label_names(self) -> list[str]:
        """Label names in the order first met."""
        out: list[str] = []
        for labels in self.labels.values():
            out += [k for k in labels if k not in out]
        return out


@dataclass
class ShotsResult:
    """Tables and summary of a shot folder (see `measure_shots`)."""

    shots: pd.DataFrame
    frames: pd.DataFrame
    summary: dict
    bodies: pd.DataFrame | None = None
    #: outline of each row of ``bodies`` in the canonical frame and in the camera's
    #: (`dropvision.measurement.MeasureResult.outlines`)
    outlines: list | None = field(default=None, repr=False)
    outlines_camera: list | None = field(default=None, repr=False)

    def __repr__(self) -> str:
        from dropvision.output.annotate import short_repr
        return short_repr(self)

    def annotate(self, shot=0, image=None, *, ax=None, labels: bool = True):
        """Draw shot ``shot`` (a position in ``.frames`` or a file name) as the camera took it, with
        its bodies, axis and volumes (`dropvision.output.annotate.annotate`); returns the matplotlib Axes."""
        from dropvision.output.annotate import annotate
        return annotate(self, shot, image, ax=ax, labels=labels)


def _sequence_doc(folder: Path) -> dict | None:
    """sequence.json of a folder when it is there and an object; None otherwise (open_sequence
    reports a broken one)."""
    json_path = folder / SEQUENCE_JSON
    try:
        if not json_path.is_file():
            return None
        doc = load_json_hardened(json_path, SequenceError)
    except (OSError, SequenceError):
        return None
    return doc if isinstance(doc, dict) else None


def _is_sequence_folder(folder: Path, overrides: dict | None) -> bool:
    if overrides and any(overrides.get(k) is not None for k in _SEQUENCE_KEYS):
        return True
    try:
        present = (folder / SEQUENCE_JSON).is_file()
    except OSError:
        return True
    doc = _sequence_doc(folder)
    if present and doc is None:
        return True  # unreadable or not an object: open_sequence reports it
    return doc is not None and any(doc.get(k) is not None for k in _SEQUENCE_KEYS)


def find_shots(paths, *, overrides: dict | None = None, label_pattern: str | None = None) -> ShotInput | None:
    """The shots among ``paths``, or None when they are a sequence.

    Parameters
    ----------
    paths : path or list of paths
        One folder, or image files (two or more: shots; one file is a folder of one, a sequence).
    overrides : dict, optional
        The sequence.json values given as options (``frame_rate_hz`` makes a sequence).
    label_pattern : str, optional
        Regular expression with named groups, replacing the file-name rule (`dropvision.io.labels`).

    Returns
    -------
    ShotInput or None
        None: a sequence folder (a frames list or a frame rate, a delay in a file name, one image).

    Raises
    ------
    LabelError
        Labels that cannot be read or contradict each other (naming the file).
    SequenceError
        A file that is not an image, a folder among several paths.
    """
    paths = [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]
    if len(paths) == 1 and paths[0].is_dir():
        folder = paths[0].absolute()
        if _is_sequence_folder(folder, overrides):
            return None
        names = images_without_delay(folder)
        if names is None:
            return None
        shots = ShotInput([folder / n for n in names], names, [folder])
    else:
        if len(paths) == 1:
            return None  # a file alone: a folder of one (a sequence of one frame)
        for p in paths:
            if p.is_dir():
                raise SequenceError(f"{p}: a folder among image files (give one folder, or image files)")
            if not p.is_file():
                raise SequenceError(f"{p}: no such image file")
            if p.suffix.lower() not in IMAGE_SUFFIXES:
                raise SequenceError(f"{p}: not an image file ({', '.join(IMAGE_SUFFIXES)})")
        absolute = [p.absolute() for p in paths]
        if len(set(absolute)) != len(absolute):
            dup = next(p for p in absolute if absolute.count(p) > 1)
            raise SequenceError(f"{dup}: given twice")
        parents = sorted({p.parent for p in absolute})
        names = [p.name for p in absolute] if len(parents) == 1 else [str(p) for p in paths]
        shots = ShotInput(absolute, names, parents, from_folder=False)
    _read_labels(shots, label_pattern)
    return shots


def is_shot_folder(folder, *, overrides: dict | None = None) -> bool:
    """Whether `find_shots` takes ``folder`` for a folder of shots (its rule, without reading the labels):
    no frames list nor frame rate (sequence.json or ``overrides``), two or more single-frame images none
    of which tells a delay. `dropvision campaign` finds shot folders with it."""
    folder = Path(folder)
    if not folder.is_dir():
        return False
    folder = folder.absolute()
    return not _is_sequence_folder(folder, overrides) and images_without_delay(folder) is not None


def sequence_settings_given(folder, *, overrides: dict | None = None) -> bool:
    """Whether a frames list or a frame rate (sequence.json, ``overrides``) makes ``folder`` a sequence
    whatever its images are (an unreadable sequence.json counts: `open_sequence` reports it)."""
    return _is_sequence_folder(Path(folder).absolute(), overrides)


def shots_of(folder, names, *, label_pattern: str | None = None) -> ShotInput:
    """The images ``names`` of ``folder`` (in that order) as shots, their labels read as `find_shots` reads
    them (the names or the pattern, shots.csv and sequence.json's shots list); a table may list images not
    among them (not arrived yet: `dropvision watch`)."""
    folder = Path(folder).absolute()
    shots = ShotInput([folder / n for n in names], list(names), [folder], from_folder=False)
    _read_labels(shots, label_pattern)
    shots.from_folder = True  # one folder: its summary names the folder
    return shots


def _read_labels(shots: ShotInput, label_pattern: str | None) -> None:
    """Fill ``shots.labels`` / ``label_sources`` from the names (or the pattern) and shots.csv."""
    rx = compile_pattern(label_pattern) if label_pattern else None
    tables: dict[tuple[Path, str], dict] = {}  # (folder, source) -> file -> labels
    for folder in shots.inputs:
        doc = _sequence_doc(folder)
        if doc is not None and doc.get("shots") is not None:
            tables[folder, SEQUENCE_JSON] = labels_from_document(doc["shots"], folder / SEQUENCE_JSON)
        if (folder / LABEL_TABLE).is_file():
            tables[folder, LABEL_TABLE] = read_label_table(folder / LABEL_TABLE)
    if shots.from_folder:  # a folder: its tables list its images
        for (folder, source), table in tables.items():
            unknown = [f for f in table if f not in set(shots.names)]
            if unknown:
                raise LabelError(f"{folder / source}: {unknown[0]} is not an image of the folder")
    sources: dict[str, list[str]] = {}
    for path, name in zip(shots.paths, shots.names):
        given = [("--label-pattern", labels_from_pattern(path.name, rx)) if rx is not None
                 else ("file name", labels_from_name(path.name))]
        for source in (SEQUENCE_JSON, LABEL_TABLE):
            table = tables.get((path.parent, source))
            if table is not None and path.name in table:
                given.append((source, table[path.name]))
        labels, origin = merge_labels(str(path), given)
        shots.labels[name] = labels
        for key, where in origin.items():
            for src in where.split(" and "):
                src = "file names" if src == "file name" else src
                if src not in sources.setdefault(key, []):
                    sources[key].append(src)
    shots.label_sources = {k: " and ".join(v) for k, v in sources.items()}


def label_columns(names: list[str]) -> dict[str, str]:
    """Label name -> its column in shots.parquet: the name, or ``label_<name>`` where the name is a
    declared column."""
    declared = set(schema.SHOTS.column_names)
    return {n: (f"label_{n}" if n in declared else n) for n in names}


#: A label (shots.csv column, sequence.json ``shots`` key, --label-pattern group) giving a double exposure's
#: strobe interval: each drop is seen twice, that many µs apart (`double_exposure_velocity`).
STROBE_INTERVAL_LABEL = "strobe_interval_us"


def double_exposure_velocity(drop_z_um: float, drop_volume_nl: float, drop_volume_uncertainty_nl: float,
                             bodies: pd.DataFrame | None, interval_us: float, pixel_size_um: float,
                             pixel_size_relative_uncertainty: float = 0.0) -> tuple[float, float, str, float]:
    """The main drop's velocity from a double exposure: its two images ``interval_us`` apart.

    The other image is the detached body (``bodies``: one shot's rows of bodies.parquet, main drop
    and satellites) whose volume is the main drop's within three standard uncertainties of their
    difference (``sqrt(2)`` times the drop's: the same drop measured twice), the nearest in volume.
    The velocity is their distance along the jetting axis over the interval (m/s, positive away from
    the nozzle); its uncertainty: half a pixel on each centroid and the pixel size's.

    Returns
    -------
    (velocity_m_s, uncertainty_m_s, note, second_image_volume_nl)
        NaN and the reason as the note when there is no second image.
    """
    nan = float("nan")
    if not (np.isfinite(interval_us) and interval_us > 0):
        return nan, nan, f"{STROBE_INTERVAL_LABEL} {interval_us:g} is not a positive number: no velocity", nan
    if not (np.isfinite(drop_z_um) and np.isfinite(drop_volume_nl)):
        return nan, nan, "double exposure: no main drop, no velocity", nan
    b = bodies
    if b is None or not len(b):
        return nan, nan, "double exposure: the main drop's second image is not found (no other detached body)", nan
    b = b[b["body_class"].isin(("main_drop", "satellite")) & np.isfinite(b["z_um"].to_numpy(float))
          & np.isfinite(b["volume_nl"].to_numpy(float))]
    b = b[np.abs(b["z_um"].to_numpy(float) - drop_z_um) > 0.5 * pixel_size_um]  # not the main drop itself
    u = math.sqrt(2.0) * drop_volume_uncertainty_nl if np.isfinite(drop_volume_uncertainty_nl) else 0.0
    dv = np.abs(b["volume_nl"].to_numpy(float) - drop_volume_nl)
    if not dv.size or dv.min() > 3.0 * u:
        return nan, nan, ("double exposure: no detached body of the main drop's volume (within 3 uncertainties) "
                          "is its second image: no velocity"), nan
    other = b.iloc[int(np.argmin(dv))]
    dz = abs(float(other["z_um"]) - drop_z_um)
    v = dz / interval_us  # um/us = m/s
    u_v = v * math.hypot(pixel_size_relative_uncertainty, math.sqrt(2.0) * 0.5 * pixel_size_um / dz)
    return v, u_v, "", float(other["volume_nl"])


def _shot_pixel_sizes(names: list[str], calibrations: dict[str, dict] | None) -> tuple[np.ndarray, np.ndarray]:
    """Each shot's pixel size (µm; nan where its calibration has none) and that size's uncertainty."""
    calibrations = calibrations or {}
    pixel = np.array([float((calibrations.get(n) or {}).get("pixel_size_um", np.nan) or np.nan) for n in names])
    u_pixel = np.array([float((calibrations.get(n) or {}).get("pixel_size_uncertainty_um", 0.0) or 0.0)
                        for n in names])
    u_pixel[~np.isfinite(pixel)] = np.nan
    return pixel, u_pixel


def _shot_geometry(f: pd.DataFrame) -> dict[str, np.ndarray]:
    """The shots' main-drop columns and what they give: sphere diameter, trajectory angle, tail length."""
    volume = f["drop_volume_nl"].to_numpy(dtype=float)
    u_volume = f["drop_volume_uncertainty_nl"].to_numpy(dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        sphere = np.cbrt(6.0 * volume * 1e6 / math.pi)  # 1 nl = 1e6 µm³
        u_sphere = sphere * u_volume / (3.0 * volume)
        x, z = f["drop_x_um"].to_numpy(dtype=float), f["drop_z_um"].to_numpy(dtype=float)
        angle = 1000.0 * np.arctan2(x, z)
    length, width = f["drop_length_um"].to_numpy(dtype=float), f["drop_diameter_um"].to_numpy(dtype=float)
    with np.errstate(invalid="ignore"):
        tail = np.maximum(length - width, 0.0)  # the main body's length beyond a round head as wide as it
    return {"volume": volume, "u_volume": u_volume, "sphere": sphere, "u_sphere": u_sphere, "x": x, "z": z,
            "angle": angle, "length": length, "width": width, "tail": tail}


def _angle_refused(quality: str, x: float, z: float) -> str | None:
    """Why a shot has no trajectory angle (None: it has one)."""
    if schema.Quality.NO_NOZZLE in quality.split("; "):
        return "no trajectory angle: the nozzle is not found in the frame"
    if not (np.isfinite(x) and np.isfinite(z)):
        return "no trajectory angle: no main drop"
    return None


def _shot_notes(f, names, g: dict, shots: ShotInput, notes, unmeasured, missing, pixel, u_pixel, bodies,
                strobe_interval_us) -> dict:
    """Per shot: its quality (a joined tail), velocity (a double exposure), satellites less a double
    exposure's second image, angle (nan where refused) and its notes."""
    volume, u_volume, x, z, angle = g["volume"], g["u_volume"], g["x"], g["z"], g["angle"].copy()
    velocity = np.full(len(names), np.nan)
    n_sat = f["n_satellites"].astype("Int64").to_numpy().copy()
    sat_volume = (f["detached_volume_nl"] - f["drop_volume_nl"]).to_numpy(dtype=float).copy()
    u_velocity = np.full(len(names), np.nan)
    inflight = f["inflight"].astype(bool).to_numpy()
    quality = f["quality"].astype(str).to_numpy().copy()
    row_notes = []
    for i, name in enumerate(names):
        own = list(notes.get(name, []))
        if missing[i]:
            row_notes.append(unmeasured.get(name, "not measured"))
            continue
        if np.isfinite(volume[i]) and not inflight[i]:  # measured, but not compact: its tail is joined
            quality[i] = schema.Quality.TAIL if quality[i] == schema.Quality.OK else f"{quality[i]}; {schema.Quality.TAIL}"
            own.append(f"the main drop's tail is joined to it: {g['tail'][i]:.0f} um beyond its head "
                       f"({g['length'][i]:.0f} um long, {g['width'][i]:.0f} um wide): not in flight; its volume "
                       "holds the tail")
        interval = shots.labels.get(name, {}).get(STROBE_INTERVAL_LABEL, strobe_interval_us)
        if interval is not None:
            rel = u_pixel[i] / pixel[i] if np.isfinite(pixel[i]) and pixel[i] > 0 else 0.0
            shot_bodies = None if bodies is None else bodies[bodies["file"] == name]
            velocity[i], u_velocity[i], why, second_nl = double_exposure_velocity(
                z[i], volume[i], u_volume[i], shot_bodies, float(interval),
                pixel[i] if np.isfinite(pixel[i]) else 1.0, rel)
            if np.isfinite(second_nl):  # the main drop's second image is no satellite
                n_sat[i] -= 1
                sat_volume[i] -= second_nl
            own.append(why or (f"double exposure {float(interval):g} us apart: velocity from the main drop's two "
                               "images (its second image is not counted as a satellite; other satellites are seen "
                               "twice and counted twice)"))
        refused = _angle_refused(str(f["quality"].iloc[i]), x[i], z[i])
        if refused is not None:
            angle[i] = np.nan
            own.append(refused)
        row_notes.append("; ".join(own))
    return {"velocity": velocity, "u_velocity": u_velocity, "n_sat": n_sat, "sat_volume": sat_volume,
            "inflight": inflight, "quality": quality, "angle": angle, "notes": row_notes}


def shots_table(frames: pd.DataFrame, shots: ShotInput, notes: dict[str, list[str]],
                unmeasured: dict[str, str] | None = None, delay_us: float = 0.0, *,
                bodies: pd.DataFrame | None = None, calibrations: dict[str, dict] | None = None,
                strobe_interval_us: float | None = None) -> pd.DataFrame:
    """shots.parquet from the frames table of the measured shots.

    Parameters
    ----------
    frames : DataFrame
        The frames table (`dvcore.schema.FRAMES` columns), one row per measured shot, ``file`` the
        shot's name.
    shots : ShotInput
        Names (one row each, in their order) and labels.
    notes : dict
        Shot name -> its own notes.
    unmeasured : dict, optional
        Shot name -> why it could not be measured: its row has no value, quality ``not_measured``
        and the reason as its note.
    delay_us : float
        The delay of an unmeasured shot's row (the measured ones have theirs).
    bodies : DataFrame, optional
        bodies.parquet of the shots (``file`` the shot's name): a double exposure's second image.
    calibrations : dict, optional
        Shot name -> its summary.json ``calibration`` (its pixel size and that size's uncertainty).
    strobe_interval_us : float, optional
        Every shot is a double exposure this many µs apart (a shot's `STROBE_INTERVAL_LABEL` label
        wins): ``drop_velocity_m_s`` (`double_exposure_velocity`).

    Returns
    -------
    DataFrame
        `dvcore.schema.SHOTS` columns, then one float column per label (`label_columns`).
    """
    import pandas as pd

    unmeasured = unmeasured or {}
    names = list(shots.names)
    f = frames.set_index("file").reindex(names)
    missing = f["quality"].isna().to_numpy()
    f.loc[missing, "quality"] = schema.Quality.NOT_MEASURED
    f.loc[missing, "delay_us"] = delay_us
    f.loc[missing, "inflight"] = False
    g = _shot_geometry(f)
    pixel, u_pixel = _shot_pixel_sizes(names, calibrations)
    s = _shot_notes(f, names, g, shots, notes, unmeasured, missing, pixel, u_pixel, bodies, strobe_interval_us)
    out = pd.DataFrame({
        "file": names,
        "delay_us": f["delay_us"].to_numpy(dtype=float),
        "drop_volume_nl": g["volume"],
        "drop_volume_uncertainty_nl": g["u_volume"],
        "drop_sphere_diameter_um": g["sphere"],
        "drop_sphere_diameter_uncertainty_um": g["u_sphere"],
        "drop_length_um": g["length"],
        "drop_diameter_um": g["width"],
        "tail_length_um": g["tail"],
        "drop_velocity_m_s": s["velocity"],
        "drop_velocity_uncertainty_m_s": s["u_velocity"],
        "n_satellites": s["n_sat"],
        "satellites_volume_nl": s["sat_volume"],
        "drop_z_um": g["z"],
        "drop_x_um": g["x"],
        "trajectory_angle_mrad": s["angle"],
        "attached_volume_nl": f["attached_volume_nl"].to_numpy(dtype=float),
        "attached_volume_uncertainty_nl": f["attached_volume_uncertainty_nl"].to_numpy(dtype=float),
        "pixel_size_um": pixel,
        "pixel_size_uncertainty_um": u_pixel,
        "inflight": s["inflight"],
        "quality": s["quality"],
        "notes": s["notes"],
    })
    out["n_satellites"] = out["n_satellites"].astype("Int64")
    for label, column in label_columns(shots.label_names).items():
        out[column] = [float(shots.labels[n].get(label, np.nan)) for n in names]
    return out


def label_waveform(shots: ShotInput, overrides: dict | None = None, option_labels: dict | None = None) -> dict | None:
    """The waveform template whose parameters are the shots' labels, checked shot by shot.

    The template is sequence.json's ``waveform`` (of each folder read), or the one given as an
    option (``overrides``' ``waveform``, laid over the file's: `dropvision.io.overrides.merged_waveform`),
    in the template form without ``parameters``. Each shot's labels named like the template's
    parameters are its parameters, in the template's units; labels with a meaning of their own
    (`SHOT_METADATA_LABELS`, `STROBE_INTERVAL_LABEL`) may stand beside them, no other.

    Returns
    -------
    dict or None
        ``{template, <constants>, dead_time_us, parameters_from: "labels"}`` (summary.json
        ``waveform``); None where no template waits for the labels (no waveform, the paper's flat
        form, a template with its parameters).

    Raises
    ------
    SequenceError
        One line naming the image: a parameter missing from its labels, a label that is no
        parameter of the template, a value outside the template's range; or naming the option or
        sequence.json: an unknown template, folders of different templates.
    """
    from dropvision.io.overrides import merged_waveform, validate_waveform
    from dvcore.waveform import template_from_dict

    given = (overrides or {}).get("waveform")
    where_given = (option_labels or {}).get("waveform", "argument waveform")
    by_folder: dict[Path, dict] = {}
    for folder in shots.inputs:
        doc = _sequence_doc(folder) or {}
        wf, where = doc.get("waveform"), str(folder / SEQUENCE_JSON)
        if isinstance(given, dict):
            wf, where = (merged_waveform(wf, given) if isinstance(wf, dict) else given), where_given
        if not isinstance(wf, dict):
            continue  # none, or not an object: open_sequence reports it
        wf = validate_waveform(wf, where)
        if "template" in wf and "parameters" not in wf:
            by_folder[folder] = wf
    if not by_folder:
        return None
    declared = list(by_folder.values())
    if any(d != declared[0] for d in declared[1:]):
        raise SequenceError(f"{shots.inputs[0]}: the folders of these images declare different waveform templates "
                            f"({', '.join(sorted({d['template'] for d in declared}))}): measure each folder alone")
    other = (*SHOT_METADATA_LABELS, STROBE_INTERVAL_LABEL)
    for path, name in zip(shots.paths, shots.names):
        wf = by_folder.get(path.parent)
        if wf is None:
            continue
        template = template_from_dict({k: v for k, v in wf.items() if k != "dead_time_us"})
        params = template.parameter_names
        labels = shots.labels.get(name, {})
        missing = [p for p in params if p not in labels]
        if missing:
            found = ", ".join(labels) or "none"
            raise SequenceError(f"{path}: no label {', '.join(missing)} of waveform template {template.name} (its "
                                f"parameters: {', '.join(params)}; this image's labels: {found})")
        unknown = [k for k in labels if k not in params and k not in other]
        if unknown:
            raise SequenceError(f"{path}: label {unknown[0]} is no parameter of waveform template {template.name} "
                                f"({', '.join(params)}); name only its parameters, or pick them with --label-pattern")
        try:
            template.check({p: labels[p] for p in params}, str(path))
        except ValueError as exc:
            raise SequenceError(str(exc)) from None
    return {**declared[0], "parameters_from": "labels"}


def _median(values) -> float | None:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else None


def _extreme(values, fn) -> float | None:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return float(fn(v)) if v.size else None


@dataclass
class _Collected:
    """The measured shots' parts, in the shots' order (`_collect`)."""

    frames: list = field(default_factory=list)
    bodies: list = field(default_factory=list)
    outlines: list = field(default_factory=list)
    per_shot: list = field(default_factory=list)
    errors: list = field(default_factory=list)
    measured: list = field(default_factory=list)


_SHOT_SOURCES = ("orientation", "orientation_source", "pixel_size_source", "nozzle_outer_diameter_source",
                 "nozzle_inner_diameter_source", "delay_source", "waveform_source", "bit_depth_source")


def _collect(outcomes, shots: ShotInput) -> _Collected:
    """Each shot's outcome of `measure_each`: its tables' parts and summary entry, or its error."""
    c = _Collected()
    for out in outcomes:
        name = out.name
        if out.error is not None:
            c.errors.append({"file": name, "reason": out.error})
            c.per_shot.append({"file": name, "labels": shots.labels.get(name, {}), "error": out.error})
            continue
        res = out.result
        s = res.summary
        if len(res.frames) != 1:
            reason = s["errors"][0]["reason"] if s.get("errors") else "not measured"
            c.errors.append({"file": name, "reason": reason})
            c.per_shot.append({"file": name, "labels": shots.labels.get(name, {}), "error": reason})
            continue
        c.frames.append(res.frames.assign(file=name))
        if res.bodies is not None and len(res.bodies):
            c.bodies.append(res.bodies.assign(file=name))
            c.outlines.append((res.outlines, res.outlines_camera, len(res.bodies)))
        cal = dict(s["calibration"])
        c.per_shot.append({"file": name, "labels": shots.labels.get(name, {}),
                           **{k: s.get(k) for k in _SHOT_SOURCES},
                           "shared_calibration": out.shared,
                           "notes": list(s.get("notes") or []) + list(cal.get("notes") or [])
                           + ([out.note] if out.note else []),
                           "calibration": cal})
        c.measured.append(name)
    return c


def _common_notes(per_shot: list[dict]) -> tuple[list[str], dict[str, list[str]]]:
    """The notes every measured shot has (the summary's) and each shot's own others."""
    all_notes = [entry["notes"] for entry in per_shot if "notes" in entry]
    common = [n for n in all_notes[0] if all(n in other for other in all_notes[1:])]
    own = {entry["file"]: [n for n in entry["notes"] if n not in common] for entry in per_shot if "notes" in entry}
    return common, own


def _shots_summary(shots: ShotInput, c: _Collected, table, common, rigs, no_rig, waveform,
                   config: MeasureConfig) -> dict:
    """summary.json of a folder of shots (`dvcore.schema.SHOTS_SUMMARY`)."""
    return {
        "schema_version": schema.SHOTS_SUMMARY.schema,
        "kind": "shots",
        "inputs": [str(p) for p in (shots.inputs if shots.from_folder else shots.paths)],
        "n_shots": len(shots.paths),
        "n_measured": len(c.measured),
        "labels": shots.label_names,
        "label_sources": shots.label_sources,
        "label_columns": label_columns(shots.label_names),
        "drop_volume_median_nl": _median(table["drop_volume_nl"]),
        "drop_volume_min_nl": _extreme(table["drop_volume_nl"], np.min),
        "drop_volume_max_nl": _extreme(table["drop_volume_nl"], np.max),
        "drop_sphere_diameter_median_um": _median(table["drop_sphere_diameter_um"]),
        "n_satellites_median": _median(table["n_satellites"].astype(float)),
        "trajectory_angle_median_mrad": _median(table["trajectory_angle_mrad"]),
        "attached_volume_median_nl": _median(table["attached_volume_nl"]),
        "quality_counts": dict(Counter(table["quality"])),
        "errors": c.errors,
        "notes": common,
        "shots": c.per_shot,
        "shared_calibration": ({**rigs[0].to_dict(), "others": [r.to_dict() for r in rigs[1:]]} if rigs
                               else {"reference": None, "calibrated_from": [], "left_out": [], "others": [],
                                     "reason": no_rig}),
        **({"waveform": waveform} if waveform is not None else {}),
        "software": software_versions(),
        "config": asdict(config),
    }


def _stacked_outlines(parts: list) -> tuple[list, list]:
    """The shots' body outlines (canonical and camera frame) in bodies.parquet's order (an empty
    outline per body of a shot that has none)."""
    outlines = [o for part, _, n in parts for o in (part or [np.zeros((0, 2), np.float32)] * n)]
    outlines_camera = [o for _, part, n in parts for o in (part or [np.zeros((0, 2), np.float32)] * n)]
    return outlines, outlines_camera


def measure_shots(paths, out_dir=None, config: MeasureConfig = MeasureConfig(), *, overrides: dict | None = None,
                  option_labels: dict | None = None, label_pattern: str | None = None, csv: bool = False,
                  overwrite: bool = False, shared_calibration: bool = True,
                  workers: int | None = None, strobe_interval_us: float | None = None) -> ShotsResult:
    """Measure a folder of shots (or image files) with the calibration they share.

    Parameters
    ----------
    paths : path, list of paths or ShotInput
        A shot folder, image files, or what `find_shots` gave.
    out_dir : str or Path, optional
        Write frames.parquet, bodies.parquet, shots.parquet and summary.json there (atomically; not in
        an input folder; an existing folder only when it holds an earlier result of ours).
    config : MeasureConfig
    overrides, option_labels : dict, optional
        sequence.json values given as options and how they were given
        (`dropvision.io.sequence.open_sequence` ``overrides`` / ``labels``); they apply to every shot.
    label_pattern : str, optional
        Regular expression with named groups for the labels (`dropvision.io.labels.labels_from_pattern`).
    csv : bool
        Also write frames.csv.
    overwrite : bool
        Write into an existing ``out_dir`` that holds files we did not write.
    shared_calibration : bool
        Shots of one rig share one calibration (`dropvision.analysis.shot_rig`): a shot that disagrees with
        it is measured alone, with a note. False: every shot alone, as a folder holding only that
        image is measured.
    workers : int, optional
        Forked processes measuring the shots (``config.workers`` by default; 1: this process);
        the rows are the same either way.
    strobe_interval_us : float, optional
        Every image is a double exposure this many µs apart (a shot's ``strobe_interval_us`` label
        wins): the main drop's velocity from its two images (`shots_table`).

    Returns
    -------
    ShotsResult

    Raises
    ------
    SequenceError
        Not a shot folder, labels unreadable or contradictory, no shot measured.
    dvcore.atomic.OutputError
        ``out_dir`` overlaps an input or holds files we did not write.
    """
    from dropvision.analysis.shot_rig import measure_each

    shots = paths if isinstance(paths, ShotInput) else find_shots(paths, overrides=overrides,
                                                                     label_pattern=label_pattern)
    if shots is None:
        raise SequenceError(f"{paths}: a sequence, not a folder of shots (its frames tell their delays, or "
                            "sequence.json lists them): measure it with measure_sequence")
    waveform = label_waveform(shots, overrides, option_labels)  # before any image is measured
    if out_dir is not None:
        check_output_dir(out_dir, inputs=shots.inputs, overwrite=overwrite)
    # pandas (with pyarrow's allocator thread) only after the worker processes are forked
    outcomes, rigs, no_rig = measure_each(shots, config, overrides=overrides, option_labels=option_labels,
                                         shared=shared_calibration, workers=workers)
    import pandas as pd
    c = _collect(outcomes, shots)
    if not c.measured:
        first = c.errors[0] if c.errors else {"file": "?", "reason": "no image"}
        raise SequenceError(f"{first['file']}: no shot could be measured ({len(c.errors)} image(s); first problem: "
                            f"{first['reason']})")
    frames = pd.concat(c.frames, ignore_index=True)
    bodies = pd.concat(c.bodies, ignore_index=True) if c.bodies else None
    common, own = _common_notes(c.per_shot)
    table = shots_table(frames, shots, own, {e["file"]: e["reason"] for e in c.errors},
                        delay_us=float((overrides or {}).get("delay_us") or 0.0), bodies=bodies,
                        calibrations={e["file"]: e["calibration"] for e in c.per_shot if "calibration" in e},
                        strobe_interval_us=strobe_interval_us)
    summary = _shots_summary(shots, c, table, common, rigs, no_rig, waveform, config)
    result = ShotsResult(table, frames, summary, bodies, *_stacked_outlines(c.outlines))
    if out_dir is not None:
        from dropvision.output.result_writer import check_shots_result, write_shots_result

        checked = check_shots_result(result, out_dir)
        with atomic_dir(out_dir, inputs=shots.inputs, overwrite=overwrite, kind="measurement") as tmp:
            write_shots_result(result, tmp, checked, csv=csv)
    return result


def one_line(summary: dict, out) -> str:
    """The command line's one-line result of a shot folder: the count, the medians, the labels' source.

    ``measured 8 shots -> O; main drop volume median 20.9 nl (13.5-27.1), 8 labelled from file names (V1, V2, ...)``
    """
    n, m = summary["n_shots"], summary["n_measured"]
    text = f"measured {m} shots" if m == n else f"measured {m} of {n} shots"
    text += f" -> {out}"
    med = summary.get("drop_volume_median_nl")
    if med is not None:
        text += (f"; main drop volume median {med:.3g} nl ({summary['drop_volume_min_nl']:.3g}-"
                 f"{summary['drop_volume_max_nl']:.3g})")
    else:  # pendant drops: what hangs from the nozzle is what was measured
        att = summary.get("attached_volume_median_nl")
        text += "; no main drop" + (f", attached volume median {att:.4g} nl" if att is not None else "")
    labels = summary.get("labels") or []
    if labels:
        labelled = sum(1 for s in summary["shots"] if s["labels"])
        by_source: dict[str, list[str]] = {}
        for name in labels:
            by_source.setdefault(summary["label_sources"].get(name, "?"), []).append(name)
        parts = [f"{src} ({', '.join(names[:4])}{', ...' if len(names) > 4 else ''})"
                 for src, names in by_source.items()]
        text += f", {labelled} labelled from {'; '.join(parts)}"
    else:
        text += ", no labels"
    if summary.get("errors"):
        text += f"; {len(summary['errors'])} image(s) skipped"
    return text

