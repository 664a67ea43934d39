"""Benchmarks that print figures: vision stages (``bench``) and MAVLink input (``bench-link``)."""
