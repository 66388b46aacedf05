"""The exception hierarchy of factorloc.

Every error the library raises on purpose derives from :class:`FactorlocError`,
so a caller can catch the library's errors without catching programming bugs.
Messages name the offending field and its value.
"""

from __future__ import annotations


class FactorlocError(Exception):
    """Base class of every error factorloc raises on purpose."""


class InputError(FactorlocError, ValueError):
    """An input (array, image, pose, sigma, file) is malformed or out of range."""


class UnusableInputError(InputError):
    """An input a step needs is present but unusable (a reference cloud with nothing in the height band, a scan
    beyond the search's reach): the pipeline reports the step ``skipped`` with ``unusable: <why>`` and a failed
    ``<step>.inputs_usable`` check, not "inputs absent"."""


class ConfigError(FactorlocError, ValueError):
    """A configuration value or key is invalid."""


class DatasetError(InputError):
    """A scenario or log on disk is missing, damaged or of an unknown version."""


class FusionError(FactorlocError):
    """Fusion could not produce a result (e.g. no estimate to fuse)."""


class UnknownIdError(DatasetError, KeyError):
    """A query or reference id that a scenario does not hold (also a ``KeyError``)."""

    def __str__(self) -> str:  # KeyError would quote the message
        return Exception.__str__(self)
