"""Foundations that import nothing else of graphcal: errors carrying file/row/field, coordinate
frames (geodetic, ECEF, ENU, polar, with Jacobians), atmospheric refraction of radar rays,
paper 002's covariance conversion, atomic writes.
"""
