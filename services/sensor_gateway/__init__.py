"""Sensor gateway: the clip-on device on serial and the camera, stamped on arrival and published one message per sample."""
