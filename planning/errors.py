"""Typed planning errors: a stable machine-readable ``code`` and a message a machinist understands.

The service maps every :class:`PlanningError` to an RFC 9457 problem document with a 4xx status;
the CLI prints ``error [code]: message`` and exits with status 2.
"""

from __future__ import annotations


class PlanningError(Exception):
    """Base class. ``code`` is a short stable identifier (``snake_case``); ``status`` the HTTP status."""

    code = "planning_error"
    status = 422

    def __init__(self, message: str, *, code: str | None = None, **details):
        super().__init__(message)
        self.message = message
        if code is not None:
            self.code = code
        self.details = details

    def __str__(self) -> str:  # pragma: no cover - trivial
        return self.message


class InputError(PlanningError):
    """The submitted cloud cannot be used (unreadable, truncated, empty, NaN, degenerate, too big)."""

    code = "invalid_input"
    status = 422


class InputTooLarge(InputError):
    """The cloud exceeds a configured size limit (points or bytes)."""

    code = "input_too_large"
    status = 413


class ParameterError(PlanningError):
    """A parameter is out of range or inconsistent with another one."""

    code = "invalid_parameter"
    status = 422
