"""Read an .rrd back with Rerun's own reader (``rerun.chunk.RrdReader``) for tests."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import pandas as pd
import pyarrow as pa


# --- reading back (independent: rerun.chunk.RrdReader + pyarrow) -------------------------------


class Rrd:
    """All chunks of the first recording in an .rrd, grouped by entity path."""

    def __init__(self, path: Path) -> None:
        import rerun as rr

        self.reader = rr.chunk.RrdReader(path)
        self.static: dict[str, dict[str, list]] = defaultdict(dict)
        temporal: dict[str, list[pa.RecordBatch]] = defaultdict(list)
        for chunk in self.reader.stream():
            batch = chunk.to_record_batch()
            if chunk.is_static:
                for name in batch.schema.names:
                    if ":" in name:
                        self.static[chunk.entity_path][name] = batch.column(name).to_pylist()[-1]
            else:
                temporal[chunk.entity_path].append(batch)
        self.temporal = dict(temporal)

    def entities(self) -> set[str]:
        return set(self.static) | set(self.temporal)

    def series(self, entity: str, component: str) -> pd.DataFrame:
        """Rows of one temporal component sorted by frame/delay: columns delay_ns, frame, value."""
        parts = []
        for batch in self.temporal[entity]:
            if component not in batch.schema.names:
                continue
            frame = (batch.column("frame").to_pylist() if "frame" in batch.schema.names
                     else [None] * batch.num_rows)
            parts.append(pd.DataFrame({
                "delay_ns": batch.column("delay").cast(pa.int64()).to_pylist(),
                "frame": frame,
                "value": batch.column(component).to_pylist(),
            }))
        out = pd.concat(parts, ignore_index=True)
        return out.sort_values(["delay_ns"], kind="stable").reset_index(drop=True)


