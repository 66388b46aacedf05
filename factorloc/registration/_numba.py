"""Imported first by :mod:`factorloc.registration`: numba's cache directory is set before any kernel is decorated."""

from factorloc.jit import configure

configure()
