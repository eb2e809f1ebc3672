"""A screenshot of ``sumo-ethics run --gui`` at a given simulation time, taken by sumo-gui itself.

    xvfb-run -s "-screen 0 1280x1024x24" python tools/gui_screenshot.py \\
        scenarios/urban_grid/urban_grid.sumocfg --seed 3 --at 78 --png docs/gui.png

Runs the scenario in sumo-gui (``runner.run(..., gui=...)``, what ``run --gui`` calls) until a
few steps past ``--at``, asking sumo-gui at ``--at`` for a screenshot of its view
(``gui.screenshot``; the file is written while the next step is simulated). The image is the
view's size, set through the window's (``--window``: about 10 x 215 pixels more than the view).
The run folder (``--out``, default a temporary one) holds what ``run`` writes. Needs a display
(DISPLAY, e.g. from xvfb-run). docs/gui.png is made so. ``--config`` (a ``run --config`` TOML file, e.g.
``[perception] occlusion = true``) and ``--ego-from``/``--ego-to``/``--ego-depart`` as for ``run``
(docs/occlusion.md's screenshot is made so).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from sumo_ethics.config import RunConfig
from sumo_ethics.errors import SumoEthicsError
from sumo_ethics.runner import make_controller, run
from sumo_ethics.settings import load_run_toml, planner_config
from sumo_ethics.sim.backend import sumo
from sumo_ethics.sim.gui import VIEW, GuiOptions


class Screenshot:
    """A run hook asking sumo-gui for a PNG of its view at simulation time ``at`` [s]."""

    def __init__(self, png: Path, at: float) -> None:
        self.png, self.at, self.asked = Path(png), at, False

    def __call__(self, snap, world) -> None:
        if not self.asked and snap.time >= self.at - 1e-9:
            sumo.gui.screenshot(VIEW, str(self.png.resolve()))
            self.asked = True


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", type=Path)
    ap.add_argument("--png", type=Path, required=True, help="the screenshot to write")
    ap.add_argument("--at", type=float, required=True, help="simulation time of the screenshot [s]")
    ap.add_argument("--seed", type=int, default=42)
    ap.add_argument("--window", default="1010,915", help="sumo-gui's window size W,H in pixels (default 1010,915: "
                    "a view of about 1000 x 700)")
    ap.add_argument("--out", type=Path, help="run folder (default: a temporary one)")
    ap.add_argument("--config", type=Path, help="a run --config TOML file ([planner], [perception])")
    ap.add_argument("--ego-from", help="insert our own ego on a route from this edge ...")
    ap.add_argument("--ego-to", help="... to this edge")
    ap.add_argument("--ego-depart", type=float, help="when the inserted ego departs [s]")
    a = ap.parse_args(argv)
    a.png.parent.mkdir(parents=True, exist_ok=True)
    a.png.unlink(missing_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        # a few steps past the shot: the file is written while the next step is simulated
        try:
            planner = planner_config(load_run_toml(a.config)[0]) if a.config is not None else None
            cfg = RunConfig(scenario=a.scenario, out=a.out or Path(tmp) / "run", seed=a.seed, end=a.at + 0.5,
                            progress=False, sumo_args=("--window-size", a.window), planner=planner,
                            ego_from=a.ego_from, ego_to=a.ego_to, ego_depart=a.ego_depart)
            run(cfg, controller=make_controller(cfg), hooks=(Screenshot(a.png, a.at),), gui=GuiOptions())
        except SumoEthicsError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return exc.exit_code
    if not a.png.is_file():
        print(f"error: no screenshot: the run ended before t={a.at:g} s", file=sys.stderr)
        return 1
    print(a.png)
    return 0


if __name__ == "__main__":
    sys.exit(main())
