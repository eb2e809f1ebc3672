"""Errors a user can cause or meet; the CLI prints each as one line and exits non-zero."""


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
