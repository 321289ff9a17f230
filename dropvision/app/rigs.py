"""Rigs for closed-loop tuning (`identify tune`, `identify.tuning`) that need the measurement layer.

* :class:`SimulatedPrinthead`: renders a synthetic strobe sequence with `dropvision.synth` at the
  proposed (u1, u2), with physics that may differ from the model's (ink viscosity, nozzle
  diameter), and measures it with `dropvision.measurement.measure_sequence` (frames in memory,
  a short delay list around the drop's flight: about 1 s a shot).
* :class:`FolderRig`: prints the proposed waveform, waits for the operator's sequence folder
  ``<folder>/shot_<k>/`` (with its ``sequence.json``) to appear and measures it.

Both are registered under the ``identify.rigs`` entry points (pyproject.toml), so that
``identify`` finds them by name without importing the measurement layer.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from dropvision.config import MeasureConfig
from dropvision.measurement import measure_sequence
from dropvision.io.sequence import sequence_from_arrays
from dropvision.synth.sequence import SynthConfig, synthesize
from identify.physics import SynthPhysics, drop_history
from identify.tuning import RigShot

__all__ = ["SimulatedPrinthead", "FolderRig", "simulated_rig", "folder_rig", "shot_from_summary"]


def shot_from_summary(summary: dict, result=None, extra: dict | None = None) -> RigShot:
    """A :class:`identify.tuning.RigShot` from a measurement's summary.json content."""
    def num(key):
        v = summary.get(key)
        return float("nan") if v is None else float(v)

    return RigShot(inflight_volume_nl=num("inflight_volume_nl"), jetting_velocity_m_s=num("jetting_velocity_m_s"),
                   inflight_volume_uncertainty_nl=num("inflight_volume_uncertainty_nl"),
                   jetting_velocity_se_m_s=num("jetting_velocity_se_m_s"), result=result, extra=dict(extra or {}))


class SimulatedPrinthead:
    """A synthetic printhead and drop watcher whose physics may differ from the model's.

    Parameters
    ----------
    physics : SynthPhysics, optional
        The nominal printhead (default: the one the demo's campaign is rendered with).
    viscosity_factor : float
        Ink viscosity x this (`SynthPhysics.viscosity_mpa_s`).
    nozzle_diameter_factor : float
        Nozzle inner and outer diameters x this (`SynthPhysics.nozzle_inner_diameter_um`,
        ``nozzle_outer_diameter_um``).
    width_px, height_px : int
        Frame size (canonical: nozzle at the top), 4.73 µm pixels.
    before_us, after_us, step_us : float
        Strobe delays from ``before_us`` before the printhead's pinch-off instant to ``after_us``
        after it, every ``step_us``, plus one frame at 0 µs (the nozzle at rest).
    noise : float
        Sensor noise scale (`SynthConfig.noise`).
    seed : int
        Shot k renders with seed + k.

    Raises
    ------
    ValueError
        A factor that is not a positive number, or physics the synthesizer refuses.
    """

    name = "simulated"

    def __init__(self, physics: SynthPhysics | None = None, *, viscosity_factor: float = 1.0,
                 nozzle_diameter_factor: float = 1.0, width_px: int = 128, height_px: int = 384,
                 before_us: float = 60.0, after_us: float = 200.0, step_us: float = 10.0, noise: float = 0.5,
                 seed: int = 0):
        for name, v in (("--viscosity-factor", viscosity_factor), ("--nozzle-diameter-factor", nozzle_diameter_factor)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        base = physics or SynthPhysics()
        self.physics = replace(base, viscosity_mpa_s=base.viscosity_mpa_s * viscosity_factor,
                               nozzle_inner_diameter_um=base.nozzle_inner_diameter_um * nozzle_diameter_factor,
                               nozzle_outer_diameter_um=base.nozzle_outer_diameter_um * nozzle_diameter_factor)
        self.width_px, self.height_px = int(width_px), int(height_px)
        self.before_us, self.after_us, self.step_us = float(before_us), float(after_us), float(step_us)
        self.noise, self.seed = float(noise), int(seed)
        self.options = {"viscosity_factor": float(viscosity_factor),
                        "nozzle_diameter_factor": float(nozzle_diameter_factor),
                        "viscosity_mpa_s": self.physics.viscosity_mpa_s,
                        "nozzle_inner_diameter_um": self.physics.nozzle_inner_diameter_um,
                        "width_px": self.width_px, "height_px": self.height_px,
                        "delays": f"0 and pinch-off -{self.before_us:g}..+{self.after_us:g} us every {self.step_us:g} us",
                        "noise": self.noise, "seed": self.seed}

    def truth(self, u1_um_per_ms: float, u2_um: float) -> dict:
        """The printhead's exact in-flight volume (nl), jetting velocity (m/s) and pinch-off (µs)."""
        h = drop_history(self.physics, u1_um_per_ms, u2_um)
        return {"inflight_volume_nl": h.inflight_volume_nl, "jetting_velocity_m_s": h.jetting_velocity_m_s,
                "pinchoff_us": h.pinchoff_instant_us}

    def config(self, u1_um_per_ms: float, u2_um: float, shot: int) -> SynthConfig:
        """The synthetic sequence of one shot."""
        tp = self.physics.pinchoff_instant_us(u1_um_per_ms, u2_um)
        first = self.step_us * math.floor((tp - self.before_us) / self.step_us)
        delays = [0.0] + [float(d) for d in np.arange(max(first, self.step_us), tp + self.after_us + 1e-9, self.step_us)]
        return SynthConfig(u1_um_per_ms=float(u1_um_per_ms), u2_um=float(u2_um), seed=self.seed + int(shot),
                           width_px=self.width_px, height_px=self.height_px, tip_row=30.4,
                           axis_col=self.width_px / 2 - 0.4, delays_us=tuple(delays), noise=self.noise,
                           physics=self.physics)

    def __call__(self, u1_um_per_ms: float, u2_um: float, shot: int) -> RigShot:
        cfg = self.config(u1_um_per_ms, u2_um, shot)
        frames, delays = [], []
        for img, truth in synthesize(cfg, progress=False):
            frames.append(img)
            delays.append(truth.delay_us)
        ph = self.physics
        seq = sequence_from_arrays(
            np.stack(frames), delays, pixel_size_um=cfg.pixel_size_um, orientation="down",
            nozzle_inner_diameter_um=ph.nozzle_inner_diameter_um, nozzle_outer_diameter_um=ph.nozzle_outer_diameter_um,
            waveform={"u1_um_per_ms": float(u1_um_per_ms), "u2_um": float(u2_um), "u3_um_per_ms": ph.u3_um_per_ms,
                      "hold_us": ph.hold_us, "dead_time_us": ph.dead_time_us},
            name=f"simulated shot {shot}")
        res = measure_sequence(seq, config=MeasureConfig(workers=1))
        t = self.truth(u1_um_per_ms, u2_um)
        return shot_from_summary(res.summary, res, {"truth_inflight_volume_nl": t["inflight_volume_nl"],
                                                    "truth_jetting_velocity_m_s": t["jetting_velocity_m_s"]})


class FolderRig:
    """The operator fires the printhead; dropvision waits for the sequence folder and measures it.

    For shot k it prints the proposed waveform and the folder it waits for,
    ``<folder>/shot_<k>/`` (two digits), and measures it once its ``sequence.json`` exists
    (`dropvision.measurement.measure_sequence`; the folder's own sequence.json describes the
    frames, docs/FORMAT.md). Put the files in place first and write sequence.json last.

    Parameters
    ----------
    folder : path
        Where the shot folders appear.
    timeout_s : float
        Give up on a shot after this long (ValueError naming the folder).
    poll_s : float
        How often to look.
    out : file
        Where the instructions are printed (default stderr).
    """

    name = "folder"

    def __init__(self, folder, *, timeout_s: float = 3600.0, poll_s: float = 1.0, out=None):
        if not (math.isfinite(timeout_s) and timeout_s > 0 and math.isfinite(poll_s) and poll_s > 0):
            raise ValueError(f"--rig-timeout-s must be > 0, got {timeout_s!r}")
        self.folder = Path(folder)
        self.timeout_s, self.poll_s = float(timeout_s), float(poll_s)
        self.out = out
        self.options = {"folder": str(self.folder), "timeout_s": self.timeout_s}

    def shot_folder(self, shot: int) -> Path:
        return self.folder / f"shot_{int(shot):02d}"

    def __call__(self, u1_um_per_ms: float, u2_um: float, shot: int) -> RigShot:
        where = self.shot_folder(shot)
        print(f"shot {shot}: fire u1 = {u1_um_per_ms:.3f} um/ms, u2 = {u2_um:.3f} um and put the strobe "
              f"sequence into {where}/ (sequence.json last)", file=self.out or sys.stderr, flush=True)
        deadline = time.monotonic() + self.timeout_s
        while not (where / "sequence.json").is_file():
            if time.monotonic() > deadline:
                raise ValueError(f"{where}: no sequence.json after {self.timeout_s:g} s (shot {shot})")
            time.sleep(self.poll_s)
        res = measure_sequence(where)
        return shot_from_summary(res.summary, res)


def simulated_rig(*, viscosity_factor: float = 1.0, nozzle_diameter_factor: float = 1.0, seed: int = 0,
                  **_ignored) -> SimulatedPrinthead:
    """Entry point ``identify.rigs: simulated``: a :class:`SimulatedPrinthead`."""
    return SimulatedPrinthead(viscosity_factor=viscosity_factor, nozzle_diameter_factor=nozzle_diameter_factor,
                              seed=seed)


def folder_rig(*, rig_folder=None, rig_timeout_s: float = 3600.0, **_ignored) -> FolderRig:
    """Entry point ``identify.rigs: folder``: a :class:`FolderRig` on ``--rig-folder``."""
    if rig_folder is None:
        raise ValueError("--rig folder needs --rig-folder DIR (where the shot folders appear)")
    return FolderRig(rig_folder, timeout_s=rig_timeout_s)
