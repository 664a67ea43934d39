"""MAVLink side of avoidd: codec, messages and transports (connection strings: avoidd.config)."""
