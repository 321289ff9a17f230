"""Application layer of dropvision: command line, campaigns, demo, Rerun views.

Imports the measurement layer (`dropvision`) and the modelling layer (`identify`); nothing
below imports it."""
