"""Tracks from plots: a constant-velocity Kalman filter and paper 002's covariance-weighted
track fusion.
"""
