"""avoidd: stereo-vision obstacle avoidance service for drones."""

__version__ = "0.1.0"
