"""The long-red variant of the bundled urban_grid, a scenario of the shipped predictor's training
data (tools/train_shipped.py, stage "long_red"): every green phase of LONG_RED_MIN_PHASE s or more
LONG_RED_FACTOR times as long, so queues of cyclists and pedestrians wait long at red."""

from __future__ import annotations

from pathlib import Path

#: the long-red runs (stage "long_red"): urban_grid with every green phase of 30 s or more three times
#: as long (37 -> 111 s, so a red holds 119 s), seeds 1-7 x 600 s; long queues of cyclists and
#: pedestrians wait at red, most of them back from the stop line, as at real city lights and the
#: game configs' lights that never switch. Only their cyclists' and pedestrians' training samples
#: are trained on (train --extra-dataset WORK_long_red --extra-groups cyclist,pedestrian)
LONG_RED_FACTOR, LONG_RED_MIN_PHASE = 3.0, 30.0
LONG_RED_GROUPS = ("cyclist", "pedestrian")


def long_red_scenario(folder: Path, net: Path, routes: Path) -> Path:
    """Write the long-red variant of urban_grid into ``folder`` and return its .sumocfg: a config
    reading ``net`` and ``routes`` (the bundled networks/urban_grid/urban_grid.net.xml and
    scenarios/urban_grid/urban_grid.rou.xml) plus an additional file with each light's program,
    green phases of LONG_RED_MIN_PHASE s or more LONG_RED_FACTOR times as long, which replaces the
    net's."""
    import xml.etree.ElementTree as ET

    lines = ["<additional>"]
    for tl in ET.parse(net).getroot().iter("tlLogic"):
        lines.append(f'    <tlLogic id="{tl.get("id")}" type="static" programID="long_red" offset="{tl.get("offset")}">')
        for ph in tl.iter("phase"):
            d = float(ph.get("duration", "0"))
            lines.append(f'        <phase duration="{d * LONG_RED_FACTOR if d >= LONG_RED_MIN_PHASE else d:g}" '
                         f'state="{ph.get("state")}"/>')
        lines.append("    </tlLogic>")
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "urban_grid_long_red.add.xml").write_text("\n".join(lines + ["</additional>"]) + "\n")
    cfg = folder / "urban_grid_long_red.sumocfg"
    cfg.write_text(f"""<configuration>
    <input>
        <net-file value="{net}"/>
        <route-files value="{routes}"/>
        <additional-files value="urban_grid_long_red.add.xml"/>
    </input>
    <time><begin value="0"/><end value="600"/><step-length value="0.1"/></time>
</configuration>
""")
    return cfg
