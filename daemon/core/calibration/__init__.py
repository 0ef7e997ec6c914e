"""Calibration runs: simulated characteristics (``sim`` composed with ``calib``), the global run
with its closed loop, whole displays (per controller, per pixel) and audience regions."""
