"""Validation of the numbers of sequence.json, and of the options that give or override them.

Every number is checked against its accepted physical range (`RANGES`, docs/FORMAT.md);
`check_overrides` validates values given as options (`OVERRIDE_KEYS`) like the file's own, and
`merge_overrides` lays them over the file's document.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from dvcore.schema import RANGES
from dropvision.io.orientation import ORIENTATIONS
from dropvision.io.readers.base import is_number
from dropvision.io.sequence_meta import SequenceError
from dvcore.waveform import (
    DEAD_TIME_US, HOLD_PRESET_US, U3_PRESET_UM_PER_MS, Waveform, drive_from_document, template_from_dict,
)


#: Keys of sequence.json that options may give or override (`open_sequence` ``overrides``):
#: the same validation and ranges apply. ``delay_us`` is the delay of a sequence of one frame.
OVERRIDE_KEYS = (
    "pixel_size_um", "nozzle_outer_diameter_um", "nozzle_inner_diameter_um", "orientation",
    "delay_us", "frame_rate_hz", "first_frame_delay_us", "trigger_frame", "waveform",
    "bit_depth", "nozzle_tip_row", "axis_col", "ink",
)
#: Accepted physical ranges of the numbers of sequence.json: `dvcore.schema.RANGES` (one place).


def finite_or_none(value, what: str, where: str) -> float | None:
    if value is None:
        return None
    try:
        ok = is_number(value) and math.isfinite(float(value))
    except OverflowError:
        ok = False
    if not ok:
        raise SequenceError(f"{where}: {what} must be a finite number or null, got {value!r}")
    return float(value)


def ranged_value(value, key: str, what: str, where: str, *, positive: bool = True) -> float | None:
    """A number of sequence.json within ``RANGES[key]`` (None stays None)."""
    if value is None:
        return None
    if not is_number(value):
        raise SequenceError(f"{where}: {what} must be a number"
                            f"{' > 0' if positive else ''}, got {value!r}")
    try:
        v = float(value)
    except OverflowError:
        v = math.inf if value > 0 else -math.inf
    if positive and not v > 0:
        raise SequenceError(f"{where}: {what} must be a number > 0, got {value!r}")
    lo, hi, unit = RANGES[key]
    if not (math.isfinite(v) and lo <= v <= hi):
        shown = f"{v:g}" if math.isfinite(v) else "a number too large to use"
        raise SequenceError(f"{where}: {what} {shown} is outside the accepted range "
                            f"{lo:g}..{hi:g} {unit}")
    return v


def check_in_image(tip_row, axis_col, original_shape, where: str) -> None:
    """nozzle_tip_row / axis_col (stored image) must lie on the stored image."""
    h, w = int(original_shape[0]), int(original_shape[1])
    for key, value, n, axis in (("nozzle_tip_row", tip_row, h, "rows"),
                                ("axis_col", axis_col, w, "columns")):
        if value is not None and not -0.5 <= value <= n - 0.5:
            raise SequenceError(f"{where}: {key} {value:g} is outside the stored image "
                                f"({axis} -0.5..{n - 0.5:g} of a {w}x{h} (WxH) image)")


def delay_value(value, what: str) -> float:
    """A delay from sequence.json: a finite number, or a string like "1150" or "1150us"."""
    out = None
    if is_number(value):
        out = float(value)
    elif isinstance(value, str):
        text = value.strip()
        try:
            out = float(text)
        except ValueError:
            m = re.fullmatch(r"([-+]?\d+(?:\.\d+)?)\s*(?:us|µs|μs)", text, re.IGNORECASE)
            out = float(m.group(1)) if m else None
    if out is None or not math.isfinite(out):
        raise SequenceError(f"{what}: unparsable delay_us {value!r} (expected a number of µs)")
    lo, hi, unit = RANGES["delay_us"]
    if not lo <= out <= hi:
        raise SequenceError(f"{what}: delay_us {out:g} is outside the accepted range "
                            f"{lo:g}..{hi:g} {unit}")
    return out


def validate_waveform(value, where: str) -> dict | None:
    if value is None:
        return None
    if not isinstance(value, dict):
        raise SequenceError(f"{where}: 'waveform' must be an object")
    if "template" in value:  # a waveform template in the lab's own parameters (issue 31)
        return _validate_template_waveform(value, where)
    out = dict(value)
    out.setdefault("u3_um_per_ms", U3_PRESET_UM_PER_MS)
    out.setdefault("hold_us", HOLD_PRESET_US)
    out.setdefault("dead_time_us", DEAD_TIME_US)
    for key in ("u1_um_per_ms", "u2_um", "u3_um_per_ms", "hold_us", "dead_time_us"):
        if key not in out or not is_number(out[key]):
            raise SequenceError(f"{where}: waveform {key} must be a number, got {out.get(key)!r}")
        if key in ("hold_us", "dead_time_us") and out[key] < 0:
            raise SequenceError(f"{where}: waveform {key} must be >= 0, got {out[key]!r}")
        out[key] = ranged_value(out[key], key, f"waveform {key}", where,
                           positive=key not in ("hold_us", "dead_time_us"))
    try:
        Waveform(out["u1_um_per_ms"], out["u2_um"], out["u3_um_per_ms"], out["hold_us"])
    except ValueError as exc:
        raise SequenceError(f"{where}: {exc}") from None
    if out["dead_time_us"] < 0:
        raise SequenceError(f"{where}: waveform dead_time_us must be >= 0")
    return out


def _validate_template_waveform(value: dict, where: str) -> dict:
    """The template form of sequence.json's ``waveform`` (`dvcore.schema.WAVEFORM`): checked by
    `dvcore.waveform.drive_from_document` and returned complete (constants and dead time filled
    in); a paper-form key beside ``template`` is refused rather than ignored. The trapezoid template
    comes back in the paper's flat form (``u1_um_per_ms``, ``u2_um``, ``u3_um_per_ms``, ``hold_us``,
    ``dead_time_us``), the one form the campaign and the summary read (u1, u2) from.

    Without ``parameters`` the template alone comes back (``{template, <constants>,
    dead_time_us}``): in a shot folder each shot's labels are its parameters
    (`dropvision.analysis.shots.label_waveform`); a strobe sequence is measured without them, and
    `dropvision campaign` leaves it out of the dataset, saying why."""
    stray = sorted(set(value) & {"u1_um_per_ms", "u2_um"})
    if stray:
        raise SequenceError(f"{where}: waveform {', '.join(stray)} beside template {value.get('template')!r}: "
                            "give the template's parameters under 'parameters'")
    if "dead_time_us" in value:
        ranged_value(value["dead_time_us"], "dead_time_us", "waveform dead_time_us", where)
    if "parameters" not in value:  # the parameters are each shot's labels (dropvision.analysis.shots.label_waveform)
        try:
            template = template_from_dict({k: v for k, v in value.items() if k != "dead_time_us"})
        except ValueError as exc:
            raise SequenceError(f"{where}: {exc}") from None
        return {**template.to_dict(), "dead_time_us": float(value.get("dead_time_us", DEAD_TIME_US))}
    try:
        drive = drive_from_document(value, where)
    except ValueError as exc:
        raise SequenceError(str(exc)) from None
    if drive.template.name == "trapezoid":  # the paper's own form, which every reader of (u1, u2) knows
        return {**drive.values, **drive.template.constants(), "dead_time_us": drive.dead_time_us}
    return drive.to_dict()


def validate_ink(value, where: str) -> dict | None:
    if value is None:
        return None
    if not isinstance(value, dict):
        raise SequenceError(f"{where}: 'ink' must be an object")
    out = dict(value)
    for key in ("density_kg_m3", "viscosity_mPa_s", "surface_tension_mN_m"):
        if key in out:
            out[key] = ranged_value(out[key], key, f"ink {key}", where)
    return out


def validate_diameters(d_in, d_out, where: str) -> tuple[float | None, float | None]:
    d_in = ranged_value(d_in, "nozzle_diameter_um", "nozzle_inner_diameter_um", where)
    d_out = ranged_value(d_out, "nozzle_diameter_um", "nozzle_outer_diameter_um", where)
    if d_in is not None and d_out is not None and not d_out > d_in:
        raise SequenceError(f"{where}: nozzle_outer_diameter_um {d_out:g} must be larger than "
                            f"nozzle_inner_diameter_um {d_in:g}")
    return d_in, d_out


#: key of an option labels dict (`check_overrides`) saying who asked: ``"command line"`` (the options of
#: `dropvision.app.options`) or absent (a Python call); messages then name ``--pixel-size-um`` or
#: ``pixel_size_um=``.
CALLER_KEY = "_caller"


def from_command_line(labels: dict | None) -> bool:
    """Whether the caller is the command line (its option labels carry ``CALLER_KEY``), not Python."""
    return (labels or {}).get(CALLER_KEY) == "command line"


def how_to_give(key: str, labels: dict | None) -> str:
    """How the caller gives sequence.json key ``key``: the option (``--pixel-size-um``) on the command
    line, the keyword argument (``pixel_size_um=``) in Python."""
    if from_command_line(labels):
        return "--" + key.replace("_", "-")
    return f"{key}="


def merged_keywords(overrides: dict | None, metadata: dict, call: str) -> dict | None:
    """``overrides`` with sequence.json keys given as keyword arguments (`dropvision.io.sequence.open_sequence`
    takes ``pixel_size_um=3`` as `dropvision.measure` does); an unknown keyword or a key given both ways is
    a TypeError naming it."""
    if not metadata:
        return overrides
    unknown = sorted(set(metadata) - set(OVERRIDE_KEYS))
    if unknown:
        raise TypeError(f"{call}: unknown keyword argument {', '.join(unknown)} (keys of sequence.json: "
                        f"{', '.join(OVERRIDE_KEYS)})")
    both = sorted(set(metadata) & {k for k, v in (overrides or {}).items() if v is not None})
    if both:
        raise TypeError(f"{call}: {', '.join(both)} given both as a keyword and in overrides")
    return {**(overrides or {}), **{k: v for k, v in metadata.items() if v is not None}}


def check_overrides(overrides, labels=None) -> dict:
    """Validate values given for sequence.json keys outside the file (options, arguments).

    The same checks and ranges as the file's keys (docs/FORMAT.md, ``RANGES``); a bad value
    is a :class:`SequenceError` naming the option.

    Parameters
    ----------
    overrides : dict
        sequence.json key (one of ``OVERRIDE_KEYS``) -> value; None values are dropped.
        ``waveform`` may be partial (its keys replace those of the file's waveform).
    labels : dict, optional
        key -> how the user gave it, for messages and sources (default ``"argument <key>"``).

    Returns
    -------
    dict
        The given keys with validated values (orientation lower-case).
    """
    labels = labels or {}
    out = {}
    for key, value in (overrides or {}).items():
        if value is None:
            continue
        where = labels.get(key, f"argument {key}")
        if key not in OVERRIDE_KEYS:
            raise SequenceError(f"{where}: {key} cannot be given as an option (one of {', '.join(OVERRIDE_KEYS)})")
        if key == "pixel_size_um":
            value = ranged_value(value, key, key, where)
        elif key in ("nozzle_outer_diameter_um", "nozzle_inner_diameter_um"):
            value = ranged_value(value, "nozzle_diameter_um", key, where)
        elif key == "frame_rate_hz":
            value = ranged_value(value, key, key, where)
        elif key in ("delay_us", "first_frame_delay_us"):
            value = delay_value(value, where)
        elif key == "orientation":
            value = value.strip().lower() if isinstance(value, str) else value
            if value not in ORIENTATIONS:
                raise SequenceError(f"{where}: orientation must be one of {ORIENTATIONS}, got {value!r}")
        elif key == "bit_depth":
            if not is_number(value) or value not in (8, 12, 16):
                raise SequenceError(f"{where}: bit_depth must be 8, 12 or 16, got {value!r}")
            value = int(value)
        elif key in ("nozzle_tip_row", "axis_col"):
            value = finite_or_none(value, key, where)
        elif key == "trigger_frame":
            if not isinstance(value, int) or isinstance(value, bool):
                raise SequenceError(f"{where}: trigger_frame must be an integer frame index, got {value!r}")
        elif key in ("waveform", "ink") and not isinstance(value, dict):
            raise SequenceError(f"{where}: {key} must be an object (a dict)")
        elif key == "ink":
            value = validate_ink(value, where)
        out[key] = value
    d_in, d_out = out.get("nozzle_inner_diameter_um"), out.get("nozzle_outer_diameter_um")
    if d_in is not None and d_out is not None:
        validate_diameters(d_in, d_out, labels.get("nozzle_outer_diameter_um", "arguments"))
    return out


def merged_waveform(old: dict, given: dict) -> dict:
    """sequence.json's ``waveform`` with the one given as options or arguments laid over it: key by key
    (a template's ``parameters`` one by one). A template given without parameters
    (``--waveform-template``: the shots' labels give them) replaces the file's waveform but for its
    ``dead_time_us`` and, for the same template, its constants."""
    if "template" in given and "parameters" not in given:
        keep = {k: v for k, v in old.items()
                if k == "dead_time_us" or (old.get("template") == given["template"] and k not in ("parameters",))}
        return {**keep, **given}
    params = given.get("parameters")
    value = {**old, **given}
    if isinstance(params, dict) and isinstance(old.get("parameters"), dict):
        value["parameters"] = {**old["parameters"], **params}  # a template's parameters one by one
    return value


def merge_overrides(doc: dict | None, given: dict, labels: dict, json_path: Path
                     ) -> tuple[dict | None, dict]:
    """sequence.json merged with validated options; returns (doc, key -> where) where
    ``where`` names the option for overridden keys and the file for the others."""
    wheres = {}
    if not given:
        return doc, wheres
    merged = dict(doc or {})
    for key, value in given.items():
        where = labels.get(key, f"argument {key}")
        wheres[key] = where
        if key == "waveform" and isinstance(merged.get("waveform"), dict):
            value = merged_waveform(merged["waveform"], value)
        if key == "frame_rate_hz" and merged.get("frames") is not None:
            raise SequenceError(f"{where}: {json_path} has a frames list (delays per frame); "
                                "frame_rate_hz gives the delays of a recording instead: not both")
        if key == "delay_us":
            continue  # applied to the listed frame (one frame only)
        merged[key] = value
    if "waveform" in given:
        validate_waveform(merged["waveform"], wheres["waveform"])
    return merged, wheres
