"""A drop watcher, replayed: a sequence folder's frames written into another folder as a camera's
software would write them (`replay_sequence`), for trying ``dropvision watch`` and measuring it
(`tools/bench_watch.py`, `tests/app/test_watch.py`).
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

from dropvision.io.sequence import SEQUENCE_JSON, open_sequence

__all__ = ["replay_sequence"]


def replay_sequence(src, dst, *, rate_hz: float = 20.0, pause_s: float = 0.01, stop_after: int | None = None
                    ) -> dict[str, float]:
    """Write a sequence folder's frames into ``dst`` as a drop watcher would: sequence.json
    first, then one frame every ``1 / rate_hz`` s, each in two writes ``pause_s`` apart (so a
    reader can find it half-written). For trying ``dropvision watch`` and measuring it.

    Parameters
    ----------
    src : str or Path
        A complete sequence folder (frames in sequence.json's list order, else natural name order).
    dst : str or Path
        The folder to fill (created).
    rate_hz : float
        Frames per second.
    pause_s : float
        Pause between the two halves of each file.
    stop_after : int, optional
        Write only this many frames.

    Returns
    -------
    dict
        File name -> when it was complete (``time.time()`` after it was closed, s).
    """
    src, dst = Path(src), Path(dst)
    with open_sequence(src, require_pixel_size=False) as seq:  # the listed order
        names = list(dict.fromkeys(r.file for r in sorted(seq.meta.frames, key=lambda r: r.listed_index)))
    dst.mkdir(parents=True, exist_ok=True)
    if (src / SEQUENCE_JSON).is_file():
        shutil.copyfile(src / SEQUENCE_JSON, dst / SEQUENCE_JSON)
    complete: dict[str, float] = {}
    t0 = time.monotonic()
    for k, name in enumerate(names[:stop_after]):
        time.sleep(max(0.0, t0 + k / rate_hz - time.monotonic()))
        data = (src / name).read_bytes()
        with open(dst / name, "wb") as fh:
            fh.write(data[:len(data) // 2])
            fh.flush()
            time.sleep(pause_s)
            fh.write(data[len(data) // 2:])
        complete[name] = time.time()
    return complete
