"""Vision stages: pure functions on arrays (calibration, rectification, grey, matching, depth)."""
