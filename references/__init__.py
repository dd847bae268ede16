"""Mitsuba 3 ground truth: variant choice (:mod:`references.mitsuba_env`) and
the content-addressed reference store (:mod:`references.reference`).

Stored entries live in ``references/store/<key>/``.  Nothing outside this
package imports Mitsuba for rendering; no own algorithm imports this package.
"""
