"""docs/extending.md's "A new predictor" works as written: its code blocks make a constant-acceleration
predictor module and an entry point for it (in a package of a temporary folder on sys.path), and
the predictor is then listed by the registry, predicts what a person computes by hand, plans a
step in the ethical planner without SUMO, is a choice of the command line (and drives a short
SUMO run of ``sumo-ethics run --predictor ca`` in a process of its own), a value of sweep's --set
and evaluate's --planner keys, and is shared by a fleet's egos. The registry refuses a name taken. Every registration made here is removed again (the registry is per process)."""

from __future__ import annotations

import importlib
import re
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import SCENARIOS, straight_road_scene
from sumo_ethics.errors import ConfigError
from sumo_ethics.predict import registry
from sumo_ethics.types import AgentStates, Observation

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "extending.md"


def _section() -> str:
    """The page's "A new predictor" section, up to the cost term's."""
    text = DOC.read_text(encoding="utf-8")
    return text[text.index("## A new predictor"):text.index("## A cost term")]
MODULE = "my_predictors/constant_acceleration.py"
SHIPPED = ("map_cslstm", "map", "attention", "cslstm", "cv")
#: a fenced block (possibly indented inside a list item): its language and its text, dedented
BLOCK = re.compile(r"^( *)```(\w+)\n(.*?)^\1```", re.M | re.S)


def doc_blocks() -> list[tuple[str, str]]:
    return [(lang, textwrap.dedent(body)) for _, lang, body in BLOCK.findall(_section())]


def module_text() -> str:
    """The module the page builds: its python blocks headed ``# my_predictors/constant_acceleration.py``."""
    parts = [body for lang, body in doc_blocks() if lang == "python" and body.startswith(f"# {MODULE}")]
    assert len(parts) >= 2, "the page should give the predictor and its registration line"
    return "\n\n".join(parts)


def entry_points_txt() -> str:
    tomls = [body for lang, body in doc_blocks() if lang == "toml"]
    assert len(tomls) == 1
    group = tomllib.loads(tomls[0])["project"]["entry-points"][registry.GROUP]
    return f"[{registry.GROUP}]\n" + "".join(f"{k} = {v}\n" for k, v in group.items())


@pytest.fixture
def plugin(tmp_path, monkeypatch):
    """The page's package installed in a folder on sys.path (module + dist-info with the entry
    point), the registry made to look for plugins again; the registration and module are removed after."""
    pkg = tmp_path / "my_predictors"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (tmp_path / MODULE).write_text(module_text())
    dist = tmp_path / "my_predictors-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: my-predictors\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(entry_points_txt())
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    monkeypatch.setattr(registry, "_plugins_loaded", False)
    try:
        yield
    finally:
        registry._ENTRIES.pop("ca", None)
        for name in [m for m in sys.modules if m == "my_predictors" or m.startswith("my_predictors.")]:
            del sys.modules[name]


def _agents(x, y, yaw, speed, accel) -> AgentStates:
    n = len(x)
    return AgentStates(ids=tuple(f"v{i}" for i in range(n)), x=np.array(x, float), y=np.array(y, float),
                       yaw=np.array(yaw, float), speed=np.array(speed, float), accel=np.array(accel, float),
                       length=np.full(n, 4.5), width=np.full(n, 1.8), mass=np.full(n, 1500.0), cls=np.zeros(n, np.int8))


def test_the_page_registers_it_through_its_entry_point(plugin):
    assert "ca" not in registry._ENTRIES  # nothing imported it yet
    assert registry.names() == (*SHIPPED, "ca")  # the first look-up loads the plugin
    entry = registry.get("ca")
    assert entry.summary == "constant acceleration" and entry.shareable and not entry.learned and not entry.needs_map
    assert type(registry.make("ca")).__name__ == "ConstantAccelerationPredictor"
    assert "my_predictors.constant_acceleration" in sys.modules


def test_its_prediction_is_constant_acceleration_by_hand(plugin):
    """At t = 1 s (step 10 of 0.1 s): x0 + v t + a t^2 / 2 along the heading, a braking one standing
    where it stopped (v^2 / 2|a|), and sigma = 0.2 + 0.6 t = 0.8 m along and across."""
    cur = _agents(x=[0.0, 5.0, 20.0], y=[0.0, 2.0, -1.0], yaw=[0.0, np.pi / 2, np.pi], speed=[10.0, 8.0, 1.0],
                  accel=[1.0, -2.0, -2.0])
    obs = Observation(time=0.0, dt=0.1, history=np.zeros((3, 0, 2)), valid=np.zeros((3, 0), bool), current=cur,
                      ego=AgentStates.empty())
    pred = registry.make("ca").predict(obs, 20, 0.1)
    assert pred.mean.shape == (3, 20, 2) and pred.cov.shape == (3, 20, 2, 2)
    at_1s = pred.mean[:, 9]
    np.testing.assert_allclose(at_1s[0], [10.0 + 0.5, 0.0], atol=1e-9)  # 10 m/s, +1 m/s^2
    np.testing.assert_allclose(at_1s[1], [5.0, 2.0 + 8.0 - 1.0], atol=1e-9)  # north at 8 m/s, -2 m/s^2
    np.testing.assert_allclose(at_1s[2], [20.0 - 0.25, -1.0], atol=1e-9)  # west at 1 m/s: stands after 0.5 s, 0.25 m
    np.testing.assert_allclose(pred.mean[2, 4], [19.75, -1.0], atol=1e-9)  # t = 0.5 s: just stopped
    np.testing.assert_allclose(pred.cov[:, 9], np.broadcast_to(0.8**2 * np.eye(2), (3, 2, 2)), atol=1e-12)
    np.testing.assert_allclose(pred.cov[0, 19], 1.4**2 * np.eye(2), atol=1e-12)  # t = 2 s


def test_the_ethical_planner_plans_a_step_with_it(plugin):
    """On the conftest road without SUMO: a car 30 m ahead at 8 m/s, slowing by 1 m/s^2. The planner's
    recorded prediction (priors off: the predictor's own numbers) has it at 40 + 8 - 0.5 m at 1 s."""
    from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig

    others = _agents(x=[40.0], y=[0.0], yaw=[0.0], speed=[8.0], accel=[-1.0])
    hist = np.stack([40.0 - 8.0 * 0.1 * np.arange(29, -1, -1), np.zeros(30)], -1)[None]  # 3 s behind it
    planner = EthicalPlanner(PlannerConfig(predictor="ca", braking_prior=0.0, lateral_prior=0.0))
    d = planner.act(straight_road_scene(others, hist))
    c = d.command
    assert np.all(np.isfinite([c.x, c.y, c.yaw, c.speed]))
    assert 0.5 < c.x - 10.0 < 1.5 and abs(c.y) < 0.5  # one 0.1 s step at about 10 m/s, along the road
    assert d.info["n_fallback"] == 0
    pred = d.trace.prediction
    assert pred.ids == ("v0",) and pred.dt == pytest.approx(0.1)
    np.testing.assert_allclose(pred.mean[0, 9], [47.5, 0.0], atol=1e-9)
    assert planner.predictor_info["kind"] == "ca"


def test_the_command_line_offers_it(plugin):
    from sumo_ethics.cli import cli

    runner = CliRunner()
    for command in ("run", "sweep"):
        out = runner.invoke(cli, [command, "--help"])
        assert out.exit_code == 0, out.output
        assert "[map_cslstm|map|attention|cslstm|cv|ca]" in out.output
    cfg = str(SCENARIOS / "urban" / "urban.sumocfg")
    ctx = cli.commands["run"].make_context("run", [cfg, "--predictor", "ca"])
    assert ctx.params["predictor"] == "ca"
    bad = runner.invoke(cli, ["run", cfg, "--predictor", "cq"])
    assert bad.exit_code == 2 and "'cq' is not one of" in bad.output


@pytest.mark.sumo
def test_a_run_of_the_command_line_in_a_new_process_predicts_with_it(tmp_path):
    """The page's package on PYTHONPATH (as if installed): ``sumo-ethics run --predictor ca`` in a
    process of its own finds it through the entry point and records it in summary.json."""
    import json
    import os

    plug = tmp_path / "plug"
    (plug / "my_predictors").mkdir(parents=True)
    (plug / "my_predictors" / "__init__.py").write_text("")
    (plug / MODULE).write_text(module_text())
    (plug / "my_predictors-0.1.dist-info").mkdir()
    (plug / "my_predictors-0.1.dist-info" / "METADATA").write_text("Metadata-Version: 2.1\nName: my-predictors\n"
                                                                   "Version: 0.1\n")
    (plug / "my_predictors-0.1.dist-info" / "entry_points.txt").write_text(entry_points_txt())
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(plug), str(ROOT)])}
    out = subprocess.run([sys.executable, "-m", "sumo_ethics.cli", "run", str(SCENARIOS / "urban" / "urban.sumocfg"),
                          "--predictor", "ca", "--end", "5", "--quiet", "--out", str(tmp_path / "run")],
                         capture_output=True, text=True, timeout=300, cwd=tmp_path, env=env)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["predictor"]["kind"] == "ca"


def test_sweep_and_evaluate_take_it(plugin):
    from sumo_ethics.suite.evaluate import parse_planner
    from sumo_ethics.sweep.grid import parse_set

    assert parse_set(["predictor=ca,cv"]) == {"predictor": ["ca", "cv"]}
    with pytest.raises(ConfigError, match=r"--set predictor: unknown predictor 'cq'; known: .*cv, ca"):
        parse_set(["predictor=ca,cq"])
    spec = parse_planner("ca=base=ours;predictor=ca")
    assert spec.name == "ca" and spec.options["predictor"] == "ca"
    with pytest.raises(ConfigError, match="predictor 'ca' .*has none"):
        parse_planner("ca=base=ours;predictor=ca;predictor_weights=x.pt")


def test_a_fleet_shares_it_unless_it_says_not(plugin):
    """Two egos of one fleet get one shared prediction of the constant-acceleration predictor; a
    predictor registered with shareable=False gets one predictor per ego."""
    from sumo_ethics.config import FleetSpec
    from sumo_ethics.plan.ethical import PlannerConfig
    from sumo_ethics.runner.fleet import SharedPrediction, make_fleet_controllers

    make = make_fleet_controllers(SimpleNamespace(fleet=FleetSpec(egos=2), planner=PlannerConfig(predictor="ca")))
    a, b = make("ethical", "a"), make("ethical", "b")
    assert isinstance(a.predictor, SharedPrediction) and a.predictor is b.predictor
    assert type(a.predictor.base).__name__ == "ConstantAccelerationPredictor"

    registry.register("ca_own", registry.get("ca").factory, shareable=False)
    try:
        make = make_fleet_controllers(SimpleNamespace(fleet=FleetSpec(egos=2),
                                                      planner=PlannerConfig(predictor="ca_own")))
        a, b = make("ethical", "a"), make("ethical", "b")
        assert not isinstance(a.predictor, SharedPrediction) and a.predictor is not b.predictor
    finally:
        registry.unregister("ca_own")
    assert "ca_own" not in registry.names()


def test_a_name_taken_is_refused(plugin):
    cv = registry.get("cv")
    with pytest.raises(registry.RegistryError, match="predictor 'cv' is already registered .*unregister it first"):
        registry.register("cv", lambda: None)
    assert registry.get("ca")  # loads the page's plugin
    with pytest.raises(registry.RegistryError, match="predictor 'ca' is already registered "
                                                     r"\(by my_predictors.constant_acceleration:ConstantAcc"):
        registry.register("ca", registry.get("ca").factory)
    with pytest.raises(registry.RegistryError, match="letters, digits or '_'"):
        registry.register("c a", lambda: None)
    with pytest.raises(registry.RegistryError, match="callable or 'module:attribute'"):
        registry.register("cz", "no_colon")
    with pytest.raises(registry.RegistryError, match="a map-aware predictor must be shareable"):
        registry.register("cz", "m:f", needs_map=True, shareable=False)
    assert registry.get("cv") is cv and registry.names() == (*SHIPPED, "ca")
    with pytest.raises(ConfigError, match="unknown predictor 'cq'; known: map_cslstm, map, attention, cslstm, cv, ca"):
        registry.get("cq")


def test_the_pages_shipped_lines_are_the_registrys():
    """The page's copy of registry.py's lines registers what the registry holds."""
    block = next(body for lang, body in doc_blocks() if lang == "python"
                 and body.startswith("# sumo_ethics/predict/registry.py"))
    seen: dict[str, registry.Entry] = {}

    def register(name, factory, **kw):
        opts = {k: v for k, v in kw.items() if k not in ("learned", "needs_map", "shareable", "summary")}
        seen[name] = registry.Entry(name, factory, **{k: v for k, v in kw.items() if k not in opts}, options=opts)

    exec(block, {"register": register, "_LSTM": "sumo_ethics.predict.predictor:lstm"})
    assert seen and all(registry.get(n) == e for n, e in seen.items())


def test_naming_and_making_the_shipped_predictors_imports_no_torch():
    code = ("import sys\nfrom sumo_ethics.predict import registry\nfrom sumo_ethics.plan.ethical import PlannerConfig\n"
            "import sumo_ethics.cli\n"
            "assert registry.names()[:5] == ('map_cslstm', 'map', 'attention', 'cslstm', 'cv')\n"
            "PlannerConfig(predictor='map'); registry.make('cv')\nprint('torch' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "False"
