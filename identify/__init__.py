"""identify: ARX, equivalent-circuit and hybrid models of drop formation (Wang & Chiu)."""

__version__ = "0.1.0"
