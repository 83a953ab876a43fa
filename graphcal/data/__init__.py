"""The data graphcal works on: the bias model (contract sign convention and units), sensor
models, sites and datasets, the calibration result, ADS-B alignment and plot pairing,
cleaning, correction of plots.
"""
