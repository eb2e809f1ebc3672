"""errors.add_note: the note the CLI prints after an interrupt (cli.main reads ``__notes__``), also on
Python 3.10, where BaseException has no add_note (found by mypy with python_version 3.10)."""

from __future__ import annotations

import types

import pytest

from sumo_ethics import errors
from sumo_ethics.errors import Terminated, add_note


@pytest.mark.parametrize("version", [(3, 10, 14), (3, 11, 0)])
def test_add_note_fills_the_notes_the_cli_reads(monkeypatch, version):
    if version >= (3, 11) and not hasattr(BaseException, "add_note"):
        pytest.skip("BaseException.add_note is Python 3.11+")
    monkeypatch.setattr(errors, "sys", types.SimpleNamespace(version_info=version))
    exc = Terminated()
    add_note(exc, "the steps so far are written")
    add_note(exc, "and a summary")
    assert exc.__notes__ == ["the steps so far are written", "and a summary"]


def test_is_number_the_one_check_of_a_given_number():
    import numpy as np

    from sumo_ethics.errors import is_number

    # real numbers, Python's or numpy's, finite; never a bool, a string or None
    assert is_number(1) and is_number(2.5) and is_number(np.float32(2.0)) and is_number(np.int64(-3))
    assert not any(is_number(v) for v in (True, np.bool_(False), "3", None, float("nan"), float("inf"), -np.inf))
    # ranges: closed by default, either end open on request
    assert is_number(0.0, 0.0, 1.0) and is_number(1.0, 0.0, 1.0) and not is_number(1.0000001, 0.0, 1.0)
    assert not is_number(0, 0, lo_open=True) and is_number(1e-300, 0, lo_open=True)
    assert not is_number(64, 0, 64, hi_open=True) and is_number(63, 0, 64, hi_open=True)
    # integer: an integer type (a float that happens to be whole is not one)
    assert is_number(3, integer=True) and is_number(np.int16(3), integer=True) and not is_number(3.0, integer=True)
    assert is_number(2**70, integer=True)  # Python ints of any size


def test_configs_refuse_what_is_number_refuses():
    """The checks that now use is_number keep their one-line messages (bad input: ConfigError)."""
    import pytest

    from sumo_ethics.config import EgoVehicle, FleetSpec, RunConfig
    from sumo_ethics.errors import ConfigError
    from sumo_ethics.plan.sampling import SamplingConfig

    with pytest.raises(ConfigError, match="ego.width must be a finite positive number, got 0"):
        EgoVehicle(width=0)
    with pytest.raises(ConfigError, match="--penetration must be a share from 0 to 1, got True"):
        FleetSpec(penetration=True)
    with pytest.raises(ConfigError, match=r"seed must be an integer in \[0, 2\^31\), got 2.0"):
        RunConfig(scenario="x.sumocfg", out="o", seed=2.0)
    import numpy as np

    assert type(RunConfig(scenario="x.sumocfg", out="o", seed=np.int64(7)).seed) is int  # config.json holds a plain int
    with pytest.raises(ConfigError, match=r"sampling.n_offsets must be an integer >= 1, got 2.0"):
        SamplingConfig(n_offsets=2.0)
