"""The per-frame stages: edges, segmentation, bodies, volumes, body classes."""
