"""Application layer of dropvision: command line, campaigns, demo, Rerun views.

Imports the measurement layer (`dropvision`), the modelling layer (`identify`) and the
foundations (`dvcore`); nothing below imports it (docs/ARCHITECTURE.md)."""
