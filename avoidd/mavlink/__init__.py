"""MAVLink side of avoidd: connection strings, codec, messages and transports."""
