"""Bench simulator: FR3 holding the instrument through a trocar, sensor and camera models, ground truth."""
