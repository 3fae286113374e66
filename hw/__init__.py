"""Device drivers behind small interfaces: servo outputs, warp sensors, calibration."""
