"""Calibrations of the installation from external references (a block adjusted with ground control)."""
