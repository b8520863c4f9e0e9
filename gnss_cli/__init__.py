"""gnss-solve: batch GNSS positioning from RINEX with a family of least-squares solvers.

Layers (imports flow one way, left to right)::

    errors, constants -> io -> gnss -> solvers / behavior -> sim -> pipeline -> report -> cli
"""

__version__ = "0.1.0"
