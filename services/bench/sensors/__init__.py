"""Sensor models: the clip-on device's IMU, ToF and magnetometer with its clock (device), the
vision error model (vision_model), pose-locked error fields (pose_field), and the true and
as-calibrated bench constants (calibration)."""
