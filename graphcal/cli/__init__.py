"""The ``graphcal`` command line.
"""
