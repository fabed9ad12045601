"""Executables of sysid_node: replay, record, offline, validate."""
