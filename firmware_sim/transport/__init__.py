"""Simulator side of the wire: navd.types samples -> MAVLink bytes / DroneCAN CAN frames.

Written from the message definitions, independently of the decoders in ``navd.io``, so a
round trip through both checks units and field semantics instead of echoing one mistake.
"""
