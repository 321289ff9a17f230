"""Application layer of identify: command line and Rerun views of identification.

Imports the modelling layer (`identify`) only; nothing below imports it."""
