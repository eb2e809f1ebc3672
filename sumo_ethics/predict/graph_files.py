"""Lane graphs on disk as gzip-compressed JSON: a file that cannot run code when it is read.

A dataset folder keeps ``lane_graphs.json.gz`` (scenario path -> lane graph) and a dataset build
in progress one ``run_NNNNNN.graph.json.gz`` per finished run. Folders written before this
format hold ``lane_graphs.pkl``; :func:`read_dataset_graphs` reads it once, with a warning
(unpickling a file from elsewhere can run code: only for folders you trust), and writes the
JSON file beside it, which every later read uses.
"""

from __future__ import annotations

import gzip
import json
import warnings
from pathlib import Path

from sumo_ethics.predict.features import LaneGraph

__all__ = ["DATASET_GRAPHS", "LEGACY_GRAPHS", "encode_graph", "decode_graph", "write_dataset_graphs",
           "read_dataset_graphs", "has_graphs"]

DATASET_GRAPHS = "lane_graphs.json.gz"
LEGACY_GRAPHS = "lane_graphs.pkl"
FORMAT = "sumo-ethics lane graphs"


def _gzip_json(obj: object) -> bytes:
    """Deterministic bytes: fixed key order from the caller, no timestamp in the gzip header."""
    return gzip.compress(json.dumps(obj, separators=(",", ":")).encode(), compresslevel=6, mtime=0)


def encode_graph(graph: LaneGraph | None) -> bytes:
    """One graph (None: a run that recorded no network) as gzip-compressed JSON."""
    return _gzip_json({"format": FORMAT, "graph": None if graph is None else graph.to_dict()})


def decode_graph(data: bytes) -> LaneGraph | None:
    """Inverse of :func:`encode_graph`; ValueError for anything else."""
    d = _load(data)
    return None if d.get("graph") is None else LaneGraph.from_dict(d["graph"])


def _load(data: bytes) -> dict:
    try:
        d = json.loads(gzip.decompress(data))
    except (OSError, EOFError, ValueError) as exc:
        raise ValueError(f"not a lane-graph file ({type(exc).__name__}: {exc})") from None
    if not isinstance(d, dict) or d.get("format") != FORMAT:
        raise ValueError("not a lane-graph file (no 'format' of sumo-ethics lane graphs)")
    return d


def write_dataset_graphs(folder: Path, graphs: dict[str, LaneGraph]) -> Path:
    """``folder``/lane_graphs.json.gz for scenario path -> graph (keys sorted); the path."""
    path = Path(folder) / DATASET_GRAPHS
    path.write_bytes(_gzip_json({"format": FORMAT, "graphs": {k: graphs[k].to_dict() for k in sorted(graphs)}}))
    return path


def has_graphs(folder: Path) -> bool:
    """Whether ``folder`` holds lane graphs in either format."""
    return (Path(folder) / DATASET_GRAPHS).is_file() or (Path(folder) / LEGACY_GRAPHS).is_file()


def read_dataset_graphs(folder: Path) -> dict[str, LaneGraph]:
    """Scenario path -> lane graph of a dataset folder; ValueError for a damaged file.

    An old folder with only ``lane_graphs.pkl``: read with pickle after a warning, and the JSON
    file written beside it when the folder is writable (the pickle is left as it is)."""
    folder = Path(folder)
    path = folder / DATASET_GRAPHS
    if path.is_file():
        d = _load(path.read_bytes())
        return {k: LaneGraph.from_dict(g) for k, g in d.get("graphs", {}).items()}
    legacy = folder / LEGACY_GRAPHS
    warnings.warn(f"{legacy} is a pickle from an older sumo-ethics: reading it can run code, so only use folders "
                  f"you trust; it is converted to {DATASET_GRAPHS} now", stacklevel=2)
    import pickle

    with open(legacy, "rb") as fh:
        graphs = pickle.load(fh)  # noqa: S301 - the old format, read once after the warning
    graphs = {k: LaneGraph.from_dict(g.to_dict()) for k, g in graphs.items()}  # exactly what the JSON file holds
    try:
        write_dataset_graphs(folder, graphs)
    except OSError:  # a read-only folder: it stays in the old format
        pass
    return graphs
