"""The offline commands: identify, predict, simulate, diagnose, calibrate, their plots and file I/O.

They import the flight code in ``warpbridge.bridge``; the flight code never imports them.
"""
