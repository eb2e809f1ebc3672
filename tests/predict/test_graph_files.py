"""Lane graphs on disk as JSON (issue 42): exact round trip, no code runs on reading, old pickles
read once with a warning and converted."""

from __future__ import annotations

import gzip
import json
import os
import pickle

import numpy as np
import pytest

from sumo_ethics.predict.features import LaneGraph
from sumo_ethics.predict.graph_files import (DATASET_GRAPHS, LEGACY_GRAPHS, decode_graph, encode_graph,
                                             read_dataset_graphs, write_dataset_graphs)
from sumo_ethics.recording.runstore import RunStore


def _graph() -> LaneGraph:
    # values whose decimal form is long: 0.1 + 0.2, 1/3, a bend; one internal lane
    shapes = [np.array([[0.0, 0.0], [100.0 / 3.0, 0.1 + 0.2], [70.0, 1e-7]]), np.array([[0.0, 3.2], [70.0, 3.2]]),
              np.array([[70.0, 0.0], [71.5, 2.0]])]
    return LaneGraph.build(["e_0", "e_1", ":j_0_0"], shapes, [13.89, 13.89, np.inf], [(":j_0_0",), (), ("e_0",)],
                           lengths=[70.1, 70.0, 2.5])


def _same(a: LaneGraph, b: LaneGraph) -> bool:
    return (a.ids == b.ids and a.succ == b.succ and all(np.array_equal(x, y) for x, y in zip(a.shapes, b.shapes))
            and all(np.array_equal(getattr(a, f), getattr(b, f)) for f in ("speed", "left", "right", "lengths")))


def test_a_graph_comes_back_bit_for_bit():
    g = _graph()
    back = decode_graph(encode_graph(g))
    assert _same(g, back)
    assert back.left.tolist() == [1, -1, -1] and back.right.tolist() == [-1, 0, -1]  # e_1 is e_0's left neighbour
    assert back.succ == ((2,), (), (0,))
    assert decode_graph(encode_graph(None)) is None
    assert encode_graph(g) == encode_graph(_graph())  # same graph, same bytes (no gzip timestamp)


def test_a_dataset_folder_holds_json_and_reading_it_runs_no_code(tmp_path):
    write_dataset_graphs(tmp_path, {"b.sumocfg": _graph(), "a.sumocfg": _graph()})
    d = json.loads(gzip.decompress((tmp_path / DATASET_GRAPHS).read_bytes()))
    assert list(d["graphs"]) == ["a.sumocfg", "b.sumocfg"] and d["graphs"]["a.sumocfg"]["ids"][2] == ":j_0_0"
    # a pickle beside it that would run code is never opened once the JSON file is there
    marker = tmp_path / "ran"

    class Evil:
        def __reduce__(self):
            return (os.mkdir, (str(marker),))

    (tmp_path / LEGACY_GRAPHS).write_bytes(pickle.dumps(Evil()))
    graphs = read_dataset_graphs(tmp_path)
    assert sorted(graphs) == ["a.sumocfg", "b.sumocfg"] and _same(graphs["a.sumocfg"], _graph())
    assert not marker.exists()


def test_an_old_folder_is_read_once_with_a_warning_and_converted(tmp_path):
    with open(tmp_path / LEGACY_GRAPHS, "wb") as fh:
        pickle.dump({"s.sumocfg": _graph()}, fh)
    with pytest.warns(UserWarning, match="pickle from an older sumo-ethics"):
        graphs = read_dataset_graphs(tmp_path)
    assert _same(graphs["s.sumocfg"], _graph()) and (tmp_path / DATASET_GRAPHS).is_file()
    (tmp_path / LEGACY_GRAPHS).write_bytes(b"not a pickle any more")  # the second read takes the JSON file
    assert _same(read_dataset_graphs(tmp_path)["s.sumocfg"], _graph())


def test_damaged_or_foreign_files_are_refused(tmp_path):
    with pytest.raises(ValueError, match="not a lane-graph file"):
        decode_graph(b"\x80\x04 a pickle")
    with pytest.raises(ValueError, match="not a lane-graph file"):
        decode_graph(gzip.compress(b'{"graph": null}'))
    with pytest.raises(ValueError, match="not a lane graph"):
        LaneGraph.from_dict({"ids": ["a"], "shapes": [[[0, 0], [1, 0]]], "speed": [], "succ": [[]], "left": [-1],
                             "right": [-1], "lengths": [1.0]})


def test_the_run_store_keeps_graphs_as_json(tmp_path):
    import pandas as pd

    store = RunStore.open(tmp_path, {"runs": [1]})
    store.put(1, pd.DataFrame({"a": [1.0]}), _graph())
    assert [p.name for p in sorted(store.folder.glob("run_*"))] == ["run_000001.graph.json.gz", "run_000001.parquet"]
    rows, g = store.get(1)
    assert rows["a"].tolist() == [1.0] and _same(g, _graph()) and store.done() == {1}
