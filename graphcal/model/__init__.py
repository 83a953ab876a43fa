"""The calibration problem, defined once: parameters (free, fixed, priors), each radar's
measurement model (function, Jacobians, covariance), observation blocks (ADS-B and cross-
radar factors, paper 001's linear observations), robust kernels, and one rank / pseudo-
inverse / Deg routine.
"""
