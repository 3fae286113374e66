"""The running program: MAVLink link, mixer, per-wing controller, parameters, telemetry, CLI."""
