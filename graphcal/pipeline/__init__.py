"""Runs that put the layers together: calibrate (load, select, solve, bound, warn), simulate
for the Python API, Monte-Carlo comparison of methods, correction of a dataset folder.
"""
