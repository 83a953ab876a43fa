"""Estimators; each takes a Dataset and returns a Calibration: paper 003's ls, fl, fl-ls; paper
001's wls and wls-pruned; the GTSAM factor graph (graph, with the target-state formulation).
The GTSAM adapter wraps GTSAM's camelCase API.
"""
