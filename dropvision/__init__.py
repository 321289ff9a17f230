"""dropvision: stroboscopic measurement of drop-on-demand drop formation."""

__version__ = "0.1.0"
