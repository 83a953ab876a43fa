"""graphcal: joint bias calibration of air-surveillance radar networks."""

__version__ = "0.1.0"
