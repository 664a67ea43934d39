"""Stereo calibration: boards, detection, solving, a virtual rig, dataset importers."""
