"""Judging what the data can tell: the Cramér-Rao bound, observability (rank, Deg, weak
directions, excitation) and observation selection (greedy, E- and D-optimal, random).
"""
