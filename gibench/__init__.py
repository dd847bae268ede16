"""The application: command line, suites, studies, the CI gate, sweeps and history.

It sits on top of the layers and is the only package that knows all of them:
it loads a scene (:mod:`core`), runs an own algorithm (:mod:`impl`, through
:mod:`gibench.registry`), gets Mitsuba's reference (:mod:`references`),
computes metrics and writes reports (:mod:`reports`).
"""
