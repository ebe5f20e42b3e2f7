"""Fusion service: error-state Kalman filter under the trocar's remote centre of motion."""
