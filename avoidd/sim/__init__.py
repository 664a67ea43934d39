"""Simulation: worlds, the vehicle simulator, scenarios and runners for real SITL autopilots."""
