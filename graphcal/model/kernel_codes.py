"""Codes shared by the compiled loops (:mod:`graphcal.model.path_loops`) and their callers
(:mod:`graphcal.model.path_kernels`), in a module that imports nothing, so that a caller
has them without loading Numba."""

from __future__ import annotations

#: Kinds of a free bias term's column in ``path_loops.plot_linearisation``: a unit
#: entry on the term's row, the true range (the range gain), or the time offset's
#: ``-(d h / d p) v``.
TERM_ADDITIVE, TERM_RANGE_GAIN, TERM_TIME_OFFSET = 0, 1, 2

__all__ = ["TERM_ADDITIVE", "TERM_RANGE_GAIN", "TERM_TIME_OFFSET"]
