"""Calibration: recording sessions -> settled poses -> estimation -> report."""
