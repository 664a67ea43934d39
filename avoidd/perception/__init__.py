"""Perception: from depth to obstacles and the sector grid around the vehicle."""
