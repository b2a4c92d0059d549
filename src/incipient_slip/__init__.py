"""Incipient slip detection by vibration injection into a soft sensor (reference implementation)."""
