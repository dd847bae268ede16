"""Metrics, the results store and report pages.

Nothing here knows about algorithms or Mitsuba: it sees images, variances and
result records.  Generated output goes to ``reports/out/`` (not committed).
"""
