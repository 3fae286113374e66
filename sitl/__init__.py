"""Everything simulated: mock autopilot, simulated wing, servo-board emulator, scenarios."""
