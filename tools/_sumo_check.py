"""What the SUMO check tools (blinker_check.py, walk_check.py) share: their command line and a
SUMO run of a config whose own outputs go to a scratch folder, never next to the config
(eclipse-sumo's tools/game configs would write into the installed package)."""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def parse_args(prog: str, doc: str | None) -> argparse.Namespace:
    """[SUMOCFG] [--seconds 300] [--seed 1]; a missing config or a non-positive duration: one line, exit 2."""
    ap = argparse.ArgumentParser(prog=prog, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("config", nargs="?", type=Path, default=ROOT / "scenarios" / "urban" / "urban.sumocfg")
    ap.add_argument("--seconds", type=float, default=300.0)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    if not args.config.is_file():
        print(f"{prog}: {args.config}: no such file", file=sys.stderr)
        sys.exit(2)
    if not args.seconds > 0:
        print(f"{prog}: --seconds {args.seconds:g}: must be positive", file=sys.stderr)
        sys.exit(2)
    return args


@contextmanager
def sumo_running(cfg: Path, seed: int) -> Iterator[object]:
    """libsumo started on ``cfg`` (0.1 s steps, ``seed``), closed afterwards; yields the libsumo module."""
    import libsumo as ls

    from sumo_ethics.sim.scenario import read_scenario, redirected
    from sumo_ethics.sim.session import output_args

    with tempfile.TemporaryDirectory() as scratch:
        ls.start(["sumo", "-c", str(cfg), "--seed", str(seed), "--step-length", "0.1", "--no-step-log", "true",
                  "--no-warnings", "true"] + output_args(redirected(read_scenario(cfg), Path(scratch))[0]))
        try:
            yield ls
        finally:
            ls.close()
