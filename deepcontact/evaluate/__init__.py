"""Warm starts compared: replay every recorded step from every start, and report."""
