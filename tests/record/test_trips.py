"""record.trips against real SUMO runs: the bundled urban scenario (vehicles of five classes and
walking persons, cut at 120 s with the unfinished trips written) and a small plan of rides and
stops on its network. Counts and totals are checked against what SUMO reports itself."""

from __future__ import annotations

import math
import re
import subprocess
import xml.etree.ElementTree as ET
import zlib
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest

from sumo_ethics.record.trips import COLUMNS, TRIPS, read_tripinfo, write_trips
from sumo_ethics.sim.scenario import declared, read_scenario
from sumo_ethics.types import RoadUserClass

from conftest import sumo_binary

pytestmark = pytest.mark.sumo

ROOT = Path(__file__).resolve().parents[2]
URBAN = ROOT / "scenarios" / "urban" / "urban.sumocfg"
URBAN_NET = ROOT / "networks" / "urban" / "urban.net.xml"
END = 120.0


def run_sumo(folder: Path, *args: str) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    subprocess.run([sumo_binary("sumo"), *args, "--no-step-log", "--no-warnings", "--tripinfo-output.write-unfinished", "true"],
                   cwd=folder, check=True, capture_output=True, timeout=120)


def run_urban(folder: Path, tripinfo: str, *extra: str) -> Path:
    run_sumo(folder, "-c", str(URBAN), "--end", str(END), "--seed", "1", "--tripinfo-output", tripinfo, *extra)
    return folder / tripinfo


@pytest.fixture(scope="module")
def urban(tmp_path_factory) -> dict:
    """The urban scenario to END: tripinfo.xml, and SUMO's own per-step counts of vehicles and persons."""
    folder = tmp_path_factory.mktemp("urban")
    path = run_urban(folder, "tripinfo.xml", "--summary-output", "summary.xml",
                     "--person-summary-output", "persons.xml")
    last = {name: list(ET.parse(folder / f"{name}.xml").getroot())[-1].attrib for name in ("summary", "persons")}
    types = declared(read_scenario(URBAN)).types
    return {"folder": folder, "path": path, "types": types, "vehicles": last["summary"],
            "persons": last["persons"], "df": read_tripinfo(path, vclass_of=types)}


def test_one_row_per_departed_vehicle_and_person(urban):
    df = urban["df"]
    assert list(df.columns) == list(COLUMNS) and "route_length" not in COLUMNS  # one meaning per name: distance
    assert df["id"].is_unique
    vehicles, persons = df[df.kind == "vehicle"], df[df.kind == "person"]
    assert len(vehicles) == int(urban["vehicles"]["inserted"]) > 0
    assert len(persons) == int(urban["persons"]["inserted"]) > 0
    assert len(df) == len(vehicles) + len(persons)
    # persons loaded ahead of their departure are in the file (depart="-1"), not in the table
    text = urban["path"].read_text()
    assert re.search(r'<personinfo id="[^"]+" depart="-1"', text)
    assert vehicles.arrived.sum() == int(urban["vehicles"]["arrived"])
    assert persons.arrived.sum() == int(urban["persons"]["arrived"])


def test_vehicle_times_and_lengths(urban):
    v = urban["df"][urban["df"].kind == "vehicle"]
    done, going = v[v.arrived], v[~v.arrived]
    assert len(done) and len(going)
    assert ((done.duration - (done.arrival - done.depart)).abs() < 1e-6).all()
    assert (done.distance > 0).all()
    # SUMO's duration of a trip under way is the time so far: depart + duration is the end
    assert going.arrival.isna().all()
    assert ((going.depart + going.duration - END).abs() < 1e-6).all()
    assert (v.time_loss <= v.duration + 1e-9).all()
    assert (v.waiting_time <= v.duration + 1e-9).all()
    assert (v[["depart", "duration", "distance", "time_loss", "waiting_time"]] >= 0).all().all()


def test_classes_from_the_vtypes(urban):
    df = urban["df"]
    v, p = df[df.kind == "vehicle"], df[df.kind == "person"]
    assert (v.vclass == v.type_id.map(urban["types"])).all()
    assert (v.cls == [RoadUserClass.from_vclass(c).label for c in v.vclass]).all()
    assert {"car", "bicycle"} <= set(v.cls)
    assert (v[v.type_id == "bicycle"].cls == "bicycle").all()
    assert (p.cls == "pedestrian").all() and (p.vclass == "pedestrian").all()
    # without the vTypes' classes a vehicle's class is unknown, a person still a pedestrian
    bare = read_tripinfo(urban["path"])
    assert (bare[bare.kind == "vehicle"].cls == "other").all()
    assert (bare[bare.kind == "vehicle"].vclass == "").all()
    assert (bare[bare.kind == "person"].cls == "pedestrian").all()


def test_walking_persons(urban):
    p = urban["df"][urban["df"].kind == "person"]
    done, going = p[p.arrived], p[~p.arrived]
    assert len(going)
    assert ((done.duration - (done.arrival - done.depart)).abs() < 1e-6).all()
    assert (done.distance > 0).all() and (done.time_loss <= done.duration).all()
    # walkers under way: the time so far; length and time loss SUMO fills in only when a walk ends
    assert ((going.depart + going.duration - END).abs() < 1e-6).all()
    assert going[["arrival", "distance", "time_loss"]].isna().all().all()


def test_egos_are_flagged(urban):
    df = urban["df"]
    egos = {df[df.kind == "vehicle"].id.iloc[3], df[df.kind == "person"].id.iloc[0], "no_such_id"}
    flagged = read_tripinfo(urban["path"], egos=egos, vclass_of=urban["types"])
    assert set(flagged[flagged.ego].id) == egos - {"no_such_id"}
    assert not df.ego.any()
    pd.testing.assert_frame_equal(flagged.drop(columns="ego"), df.drop(columns="ego"))


def test_gzip_and_human_readable_time_give_the_same_rows(urban, tmp_path):
    for name, extra in (("tripinfo.xml.gz", ()), ("tripinfo.xml", ("--human-readable-time",))):
        path = run_urban(tmp_path / name.replace(".", "_") / "x", name, *extra)
        if name.endswith(".gz"):
            assert path.read_bytes()[:2] == b"\x1f\x8b"
        else:
            assert 'depart="00:0' in path.read_text()
        pd.testing.assert_frame_equal(read_tripinfo(path, vclass_of=urban["types"]), urban["df"])


def _entries(text: str) -> list[tuple[str, int]]:
    """(id, end offset) of the departed trips of a tripinfo text, read with a regex (not the parser)."""
    pattern = re.compile(r'<(tripinfo|personinfo) id="([^"]+)" depart="([^"]+)"[^>]*?(?:/>|>.*?</personinfo>)', re.S)
    return [(m[2], m.end()) for m in pattern.finditer(text) if not m[3].startswith("-")]


def test_a_file_cut_off_gives_the_rows_before_the_cut(urban, tmp_path):
    full, text = urban["df"], urban["path"].read_text()
    entries = _entries(text)
    assert [i for i, _ in entries] == list(full.id)
    walker = text.index("<walk ", text.index("<personinfo "))
    for cut in (len(text) // 2, walker, text.index("<tripinfo ") + 10):  # mid-file, inside a person, first vehicle
        path = tmp_path / "cut.xml"
        path.write_text(text[:cut])
        df = read_tripinfo(path, vclass_of=urban["types"])
        assert list(df.id) == [i for i, end in entries if end <= cut]
        pd.testing.assert_frame_equal(df, full.iloc[:len(df)])
    empty = tmp_path / "empty.xml"
    empty.write_bytes(b"")
    assert read_tripinfo(empty).empty and list(read_tripinfo(empty).columns) == list(COLUMNS)


def _decodable(data: bytes) -> bytes:
    """What zlib decodes of a cut gzip stream of many members."""
    out = b""
    while data:
        z = zlib.decompressobj(wbits=31)
        out += z.decompress(data)
        if not z.eof:
            return out + z.flush()
        data = z.unused_data
    return out


def test_a_gzip_file_cut_off_gives_the_rows_before_the_cut(urban, tmp_path):
    data = run_urban(tmp_path / "gz", "tripinfo.xml.gz").read_bytes()
    full = urban["df"]
    for cut in (len(data) // 2, len(data) - 100, 1):
        path = tmp_path / "cut.xml.gz"
        path.write_bytes(data[:cut])
        df = read_tripinfo(path, vclass_of=urban["types"])
        assert list(df.id) == [i for i, _ in _entries(_decodable(data[:cut]).decode())]
        pd.testing.assert_frame_equal(df, full.iloc[:len(df)])
        assert len(df) < len(full) and (len(df) > 0) == (cut > 1)
        if cut > 2:  # a crash can leave zeros at the end
            path.write_bytes(data[:cut] + bytes(4096))
            pd.testing.assert_frame_equal(read_tripinfo(path, vclass_of=urban["types"]), df)


def test_written_twice_the_same_bytes(urban, tmp_path):
    a, b = tmp_path / "a.parquet", tmp_path / "b.parquet"
    write_trips(urban["df"], a)
    write_trips(read_tripinfo(urban["path"], vclass_of=urban["types"]), b)
    assert a.read_bytes() == b.read_bytes()
    table = pq.read_table(a)
    assert table.schema.equals(TRIPS) and table.num_rows == len(urban["df"])
    assert "distance" in table.schema.names and "route_length" not in table.schema.names  # one meaning per name:
    pd.testing.assert_frame_equal(table.to_pandas(), urban["df"][list(COLUMNS)])  # distance is the whole route
    empty = tmp_path / "empty.parquet"
    write_trips(urban["df"].iloc[:0], empty)
    assert pq.read_table(empty).schema.equals(TRIPS) and pq.read_table(empty).num_rows == 0


# ---- persons riding a bus and stopping on the way ------------------------------------------------
PLAN = """<routes>
    <vType id="bus" vClass="bus"/>
    <vType id="ped" vClass="pedestrian"/>
    <vehicle id="bus0" type="bus" depart="20" line="L1">
        <route edges="W_in E_out"/><stop lane="W_in_1" endPos="150" duration="5"/>
    </vehicle>
    <vehicle id="bus1" type="bus" depart="100" line="L1">
        <route edges="W_in E_out"/><stop lane="W_in_1" endPos="150" duration="5"/>
    </vehicle>
    <person id="p_ride" depart="0" type="ped" departPos="100">
        <walk edges="W_in" arrivalPos="148"/><ride from="W_in" to="E_out" lines="L1"/>
        <walk edges="E_out" arrivalPos="180"/>
    </person>
    <person id="p_stop" depart="1" type="ped" departPos="10">
        <walk edges="N_in S_out" arrivalPos="20"/><stop duration="5" actType="shopping"/>
        <walk edges="S_out" arrivalPos="60"/>
    </person>
    <person id="p_late" depart="50" type="ped" departPos="100">
        <walk edges="W_in" arrivalPos="148"/><ride from="W_in" to="E_out" lines="L1"/>
    </person>
    <person id="p_never" depart="900" type="ped"><walk edges="N_in N_out"/></person>
</routes>
"""


@pytest.fixture(scope="module")
def plan(tmp_path_factory) -> dict[float, tuple[pd.DataFrame, dict[str, dict[str, str]]]]:
    """end -> (rows, SUMO's own personinfo attributes by id) of the plan run to that end."""
    folder = tmp_path_factory.mktemp("plan")
    (folder / "plan.rou.xml").write_text(PLAN)
    out = {}
    for end in (130.0, 400.0):
        name = f"tripinfo_{end:.0f}.xml"
        run_sumo(folder, "-n", str(URBAN_NET), "-r", "plan.rou.xml", "--end", str(end), "--tripinfo-output", name)
        info = {e.get("id"): e.attrib for e in ET.parse(folder / name).getroot().iter("personinfo")}
        out[end] = (read_tripinfo(folder / name, vclass_of={"bus": "bus"}).set_index("id"), info)
    return out


def test_rides_and_stops_finished(plan):
    df, info = plan[400.0]
    assert set(df.index) == {"bus0", "bus1", "p_ride", "p_stop", "p_late"}  # p_never did not depart
    assert (df.loc[["bus0", "bus1"], "cls"] == "bus").all()
    persons = df[df.kind == "person"]
    assert persons.arrived.all()
    for pid, row in persons.iterrows():
        sumo_total = info[pid]
        if "duration" in sumo_total:  # SUMO >= 1.20 writes the person's totals too
            assert row.duration == pytest.approx(float(sumo_total["duration"]))
            assert row.time_loss == pytest.approx(float(sumo_total["timeLoss"]), abs=0.011)  # rounded parts
            assert row.waiting_time == pytest.approx(float(sumo_total["waitingTime"]))
        assert row.duration == pytest.approx(row.arrival - row.depart)
        assert 0 < row.time_loss < row.duration and row.distance > 0
    # a rider's length includes the ride (W_in to E_out in the bus: about 250 m), a walker's the walks only
    assert persons.loc["p_ride", "distance"] > 250 + 48
    if "traveltime" in info["p_stop"]:  # SUMO's travel time leaves out the 5 s stop, the duration does not
        assert persons.loc["p_stop", "duration"] == pytest.approx(float(info["p_stop"]["traveltime"]) + 5)
    assert persons.loc["p_late", "waiting_time"] > 0  # waited for bus1


def test_rides_and_stops_under_way(plan):
    df, info = plan[130.0]
    assert "p_never" not in df.index and info["p_never"]["depart"].startswith("-")
    assert df.loc["p_ride", "arrived"] and not df.loc["p_late", "arrived"] and not df.loc["p_stop", "arrived"]
    # in the bus at the end (waited for it, then rode) and walking at the end: the time so far
    for pid in ("p_late", "p_stop"):
        row = df.loc[pid]
        assert row.duration == pytest.approx(130.0 - row.depart)
        assert math.isnan(row.arrival) and math.isnan(row.distance) and math.isnan(row.time_loss)
    assert df.loc["p_late", "waiting_time"] > 0
    assert not df.loc["bus1", "arrived"] and df.loc["bus1", "duration"] == pytest.approx(130.0 - 100.0)


def test_removed_early_is_not_arrived_and_own_types_keep_their_class(tmp_path):
    """A vehicle TraCI removes has an arrival time but did not arrive; one TraCI gave a vType of
    its own (``bus@bus1``) keeps its base type's vClass."""
    import libsumo

    (tmp_path / "plan.rou.xml").write_text(PLAN)
    out = tmp_path / "tripinfo.xml"
    libsumo.start([sumo_binary("sumo"), "-n", str(URBAN_NET), "-r", str(tmp_path / "plan.rou.xml"), "--end", "130",
                   "--tripinfo-output", str(out), "--tripinfo-output.write-unfinished", "true",
                   "--no-step-log", "--no-warnings"])
    try:
        while libsumo.simulation.getTime() < 130:
            libsumo.simulationStep()
            if libsumo.simulation.getTime() == 30:
                libsumo.vehicle.remove("bus0")
            if libsumo.simulation.getTime() == 110:
                libsumo.vehicle.setLength("bus1", 13.0)
    finally:
        libsumo.close()
    df = read_tripinfo(out, vclass_of={"bus": "bus"}).set_index("id")
    assert df.loc["bus0", "arrival"] == pytest.approx(30.0) and not df.loc["bus0", "arrived"]
    assert df.loc["bus1", "type_id"] == "bus@bus1"
    assert df.loc["bus1", "vclass"] == "bus" and df.loc["bus1", "cls"] == "bus"
