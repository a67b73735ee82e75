"""Error types. The CLI turns these into one clear line and exit code 2."""


class GS2EError(Exception):
    """Base class of errors gs2e reports to the user without a traceback."""


class InputError(GS2EError):
    """Bad input data: unreadable/corrupt file, too few views, NaN poses, ...

    The message must name the offending file (or item).
    """


class ConfigError(GS2EError):
    """Invalid configuration or scenes table; the message names the key."""
