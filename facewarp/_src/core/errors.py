"""Error types shared by every stage.

Anything the user can get wrong (a path, a file's contents, a flag value) raises
:class:`InputError` with a one-line message that names the input and what was wrong.
The CLI turns these into one line on stderr and a non-zero exit code.
"""

from __future__ import annotations


class FacewarpError(Exception):
    """Base class of all errors raised deliberately by facewarp."""


class InputError(FacewarpError, ValueError):
    """Bad user input: a missing or malformed file, a bad value, mismatched topology."""


class SimulationError(FacewarpError, RuntimeError):
    """A simulation diverged (NaN, inverted element); the message names step and element."""
