"""Scenarios and their simulation: traffic (synthetic or replayed OpenSky trajectories),
rotating-antenna radar plots with the contract's biases, ADS-B reports, truth.
"""
