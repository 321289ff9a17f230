"""Where an output may go: never onto, into or around what the command reads.

:func:`check_outside_inputs` is the one check every command runs, before any work, on each
output path it will write (a model file, a report or dataset folder, a Rerun recording):
whatever ``--overwrite`` says, an output that is an input, lies inside an input folder (a
dataset, a sequence) or contains an input is refused. Writing a model over
``DATASET/summary.parquet`` would destroy the data; a file added inside a sequence folder changes
its input hash and with it a campaign's resume.
"""

from __future__ import annotations

from typing import Iterable

from dvcore.atomic import OutputError, check_not_input

__all__ = ["OutputError", "check_outside_inputs"]


def check_outside_inputs(inputs: Iterable, *outputs) -> None:
    """Refuse any of ``outputs`` (paths; None: not written) that equals, lies inside or contains
    one of ``inputs`` (files or folders; links resolved).

    Raises
    ------
    OutputError
        One line naming the output and the input.
    """
    inputs = [p for p in inputs if p is not None]
    for out in outputs:
        if out is not None:
            check_not_input(out, inputs)
