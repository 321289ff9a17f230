"""What a sequence-level check found: a quality code for some frames, a note, outputs withheld.

The checks (`dropvision.analysis.plausibility`, the pinch-off rules and the main-drop track in
`dropvision.analysis.sequence_summary` and `dropvision.analysis.tracking`) do not touch the sequence's flags, notes or
values: each returns `Finding` objects, and `dropvision.analysis.sequence_summary.apply_findings` is the one place
that turns them into quality flags, notes and withheld outputs.  What each `Withheld` member
blanks is declared beside it (`WITHHELD_FRAME_COLUMNS`, `WITHHELD_SUMMARY_KEYS`; the values the
later steps still use are blanked by `apply_findings` at once).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class Withheld(enum.Enum):
    """An output a finding withholds (made NaN, or left out of what follows)."""

    #: per frame (the frames of the finding): not in flight (no in-flight value, no velocity fit).
    INFLIGHT = "inflight"
    #: per frame: every number of the frame (its intensities are not trusted).
    FRAME_NUMBERS = "frame numbers"
    #: per frame: its attached volume, out of the initial meniscus, grown volumes and flow.
    ATTACHED_IN_GROWTH = "attached volume in the growth"
    #: the pinch-off delay (and what the attached frames are, which depends on it).
    PINCHOFF = "pinch-off"
    #: grown volumes, flow velocities and the initial meniscus (no meniscus at rest to grow from).
    GROWN = "grown volume"
    #: flow velocities (per frame and at the maximum stroke).
    FLOW = "flow velocity"
    #: the jetting velocity and its standard error.
    VELOCITY = "jetting velocity"
    #: the summary's length-dependent values: volumes and velocities (the pixel size is wrong).
    LENGTH_SCALED = "length-scaled values"


#: Columns of the frames table a withheld output makes NaN (at the end, `dropvision.analysis.sequence_summary.withhold`).
WITHHELD_FRAME_COLUMNS: dict[Withheld, tuple[str, ...]] = {
    Withheld.FLOW: ("flow_velocity_m_s",),
}
#: Keys of the summary a withheld output makes NaN (at the end, `dropvision.analysis.sequence_summary.withhold`).
WITHHELD_SUMMARY_KEYS: dict[Withheld, tuple[str, ...]] = {
    Withheld.FLOW: ("flow_velocity_at_max_stroke_m_s",),
    Withheld.VELOCITY: ("jetting_velocity_m_s", "jetting_velocity_se_m_s"),
    Withheld.LENGTH_SCALED: ("grown_volume_at_pinchoff_nl", "initial_meniscus_volume_nl", "inflight_volume_nl",
                             "inflight_volume_std_nl", "inflight_volume_uncertainty_nl",
                             "grown_volume_at_pinchoff_uncertainty_nl", "initial_meniscus_volume_uncertainty_nl",
                             "jetting_velocity_m_s", "jetting_velocity_se_m_s", "flow_velocity_at_max_stroke_m_s"),
}


@dataclass(frozen=True)
class Finding:
    """What one check found.

    Attributes
    ----------
    flag : str or None
        Quality code (`dropvision.quality`) given to ``frames`` (once: a frame that has it keeps
        its place), None for none.
    frames : tuple of int
        Indices of the frames concerned (into the sequence's records): flagged, and the frames
        whose per-frame outputs (`Withheld.INFLIGHT`, `FRAME_NUMBERS`, `ATTACHED_IN_GROWTH`) are
        withheld.
    note : str or None
        One sentence for the summary's ``notes``.
    withheld : frozenset of Withheld
        Outputs no longer given.
    """

    flag: str | None = None
    frames: tuple[int, ...] = ()
    note: str | None = None
    withheld: frozenset[Withheld] = frozenset()


def frames_of(mask) -> tuple[int, ...]:
    """Indices of the true entries of a boolean mask (the ``frames`` of a `Finding`)."""
    return tuple(int(k) for k, v in enumerate(mask) if v)
