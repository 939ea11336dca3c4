"""Errors clrender reports to its users: each carries a one-line message that says what to do."""


class ClrenderError(Exception):
    """Base of every error the command line prints as one line (no traceback)."""


class ParameterError(ClrenderError, ValueError):
    """A parameter is out of range or unknown; the message names it and the accepted values."""


class DeviceError(ClrenderError):
    """No OpenCL platform, or no device matches the request."""


class KernelBuildError(ClrenderError):
    """An OpenCL program failed to build; the message carries the compiler log."""
