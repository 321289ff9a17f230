"""Sequence-, shot- and nozzle-level analysis of the per-frame records."""
