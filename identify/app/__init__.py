"""Application layer of identify: command line and Rerun views of identification.

Imports the modelling layer (`identify`) and the foundations (`dvcore`) only; nothing below
imports it (docs/ARCHITECTURE.md)."""
