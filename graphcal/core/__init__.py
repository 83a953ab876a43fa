"""Foundations that import nothing else of graphcal: errors carrying file/row/field, coordinate
frames (geodetic, ECEF, ENU, polar, with Jacobians), paper 002's covariance conversion,
atomic writes.
"""
