"""Error types. The CLI turns these into one clear line and exit code 2."""


class GS2EError(Exception):
    """Base class of errors gs2e reports to the user without a traceback."""


class InputError(GS2EError):
    """Bad input data: unreadable/corrupt file, too few views, NaN poses, ...

    The message must name the offending file (or item).
    """


class ConfigError(GS2EError):
    """Invalid configuration or scenes table; the message names the key."""


class Terminated(BaseException):
    """Raised in the main thread when the process receives SIGTERM (Slurm's time
    limit, ``kill``, Snakemake stopping a job), so that outputs in progress are
    cleaned up exactly as after an exception. A BaseException: ``except
    Exception`` in library code must not swallow it."""

    def __init__(self, signum: int):
        import signal

        self.signum = signum
        super().__init__(f"terminated by {signal.Signals(signum).name}")
