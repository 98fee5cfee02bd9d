"""Codecs: bytes <-> EventChunk (EVT3, EVT2, mono, ROS 2 CDR EventPacket)."""
