"""Unit factors, defined once for the package (SI inside; see :mod:`navd`)."""

import math

DEG = math.pi / 180.0  # rad per degree
RAD2DEG = 180.0 / math.pi
G0 = 9.80665  # standard gravity, m/s^2: the "g" of mG on every wire (MAVLink, PX4, ArduPilot)
ARCSEC = DEG / 3600.0  # rad per arc second
DEG_PER_H = DEG / 3600.0  # rad/s per deg/h
