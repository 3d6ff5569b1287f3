"""Offline analyses: heading-error metrics, Allan deviation, evaluation, tuning, model gap.

Pure functions over arrays and drive logs; the ``main`` functions at the bottom of each module
are the thin command-line edges.
"""
