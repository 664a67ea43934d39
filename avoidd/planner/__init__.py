"""The local planner: obstacle memory, free distance per direction, direction choice, speed law.

Pure functions and plain state on numpy arrays: no asyncio, no MAVLink. The daemon feeds it the
merged scan and the vehicle state and sends what it decides; the simulator runs the same code in
lockstep.
"""
