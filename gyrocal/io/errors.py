"""One exception hierarchy for everything gyrocal refuses to do.

Every message is a single line that names the file (or config key) and says what was
expected and what was found. The CLI prints it as is; the workflow records it as the
unit's failure. ``exit_status`` follows the contract: 2 for bad input, 1 otherwise.
"""

from __future__ import annotations

import os


class GyrocalError(Exception):
    """Base of every error gyrocal raises on purpose."""

    exit_status = 1

    def __init__(self, message: str, *, source: str | os.PathLike | None = None):
        text = " ".join(str(message).split())  # one line, whatever the caller passed
        if source is not None:
            text = f"{os.fspath(source)}: {text}"
        super().__init__(text)
        self.source = None if source is None else os.fspath(source)


class InputError(GyrocalError):
    """The input (log, calibration file, config, manifest) is not what the contract says."""

    exit_status = 2


class LogFormatError(InputError):
    """A rig log breaks the log contract: columns, types, units, time order."""


class CorruptFileError(InputError):
    """A file cannot be read at all (missing, not Parquet/JSON, truncated)."""


class EmptyLogError(LogFormatError):
    """A log holds no usable rows."""


class CalibrationFileError(InputError):
    """A calibration file is malformed, of an unknown format version or inconsistent."""


class ConfigError(InputError):
    """A configuration value or model specification is invalid."""


class SegmentationError(InputError):
    """The data do not contain what the protocol needs (no holds, no stable temperature)."""


class IdentifiabilityError(InputError):
    """The observations do not excite some model parameters; names them."""

    def __init__(self, message: str, *, parameters: tuple[str, ...] = (), source=None):
        super().__init__(message, source=source)
        self.parameters = tuple(parameters)


class MissingInputError(InputError):
    """A model term needs a log column or covariate that is absent."""


def first_line(exc: BaseException) -> str:
    """An exception's first line, for a one-line error (Arrow's messages run to many, and
    its dataset errors wrap the reader's reason, which comes last, in sentences that repeat
    the file's path: the reason alone is kept)."""
    text = str(exc).strip().splitlines()
    line = text[0] if text else type(exc).__name__
    if line.startswith("Error creating dataset") and ": " in line:
        line = line.rsplit(": ", 1)[1].rstrip(".")
    return line


def or_exit(call, *args, **kwargs):
    """``call(*args, **kwargs)``; where it raises a :class:`GyrocalError`, that error's one
    line on standard error and an exit with its status, as the CLI ends: the workflow's plan
    (the Snakefile's settings, manifest and registry) stops so, not with Snakemake's frames."""
    import sys

    try:
        return call(*args, **kwargs)
    except GyrocalError as exc:
        print(f"gyrocal: error: {exc}", file=sys.stderr)
        sys.exit(exc.exit_status)
