"""Adaptive notch filter bank following the structural modes identified by sysid_node."""
