"""The calibration pass: from a few frames to what every frame is measured with."""
