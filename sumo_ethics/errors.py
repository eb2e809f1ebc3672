"""Errors a user can cause or meet; the CLI prints each as one line and exits non-zero."""

import sys


class SumoEthicsError(Exception):
    """Base class: a problem the user can act on, reported without a traceback."""

    exit_code = 1


class ConfigError(SumoEthicsError):
    """Bad input: a missing or malformed file, a nonsense parameter value, an unknown id."""

    exit_code = 2


class SimulationError(SumoEthicsError):
    """SUMO failed or the simulation could not continue."""

    exit_code = 3


class Terminated(KeyboardInterrupt):
    """The process got SIGTERM: handled like Ctrl-C (outputs and summary written), exit 143."""


class OutputError(SumoEthicsError):
    """The outputs could not be written (a full disk, a file size limit): not the input's fault."""

    exit_code = 1


def add_note(exc: BaseException, note: str) -> None:
    """``exc.add_note(note)``: a line the CLI adds to the error's one line (cli.main reads ``__notes__``).

    BaseException.add_note is Python 3.11+; on 3.10 the note goes into the same ``__notes__`` list by hand.
    """
    if sys.version_info >= (3, 11):
        exc.add_note(note)
    else:
        notes = getattr(exc, "__notes__", None)
        if notes is None:
            notes = []
            setattr(exc, "__notes__", notes)  # noqa: B010 (no such attribute in 3.10's BaseException)
        notes.append(note)
