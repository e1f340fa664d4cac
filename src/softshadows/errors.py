"""Errors raised for bad user input. The CLI turns them into one-line messages and exit code 2."""


class SoftShadowsError(ValueError):
    """Bad input from the user: a file, field, value, method or parameter. Message is one line."""


class SceneError(SoftShadowsError):
    """A scene file, mesh file, light or camera is missing or malformed."""
