"""Recorded decisions: what the planner weighed at a step, stored compactly so that
``sumo-ethics explain`` and ``replay`` can draw it afterwards.

One file per recorded planning step, ``RUN/decisions/step_NNNNNN.npz`` (a zip of ``.npy`` arrays,
written under a temporary name and renamed, with fixed zip timestamps so the same seed gives the
same bytes); a fleet run keeps each ego's in its own folder,
``RUN/decisions/<ego folder>/step_NNNNNN.npz`` (:func:`ego_folder`). ``step`` is the steps.parquet
row the decision led to (the row of the state one step later; in a fleet, that ego's row) and the
``step`` of a collision it ended in; ``time`` is the planning time.

What a step holds (float32 unless said; positions relative to the ego's centre at planning
time, so float32 keeps millimetres):

=====================  ==============  =========================================================
``ego``                (8,) float64     x, y, yaw, speed, length, width, mass, class of the ego
``agent_ids``          (N,) str         the neighbours' SUMO ids
``agents``             (N, 7)           x, y, yaw, speed, length, width (m, rad, m/s), class
``pred_mean``          (N, P, 2)        predicted centres [m] (multi-modal: the most likely mode) at the
                                        ``pred_t`` samples: every PREDICTION_SPACING s and the horizon's end
``pred_cov``           (N, P, 3)        covariance xx, xy, yy [m^2] (the same mode)
``pred_t``             (P,)             the time after planning of those samples [s] (absent in files of
                                        before: there every step, P = T)
``pred_weight``        (N, Q)           only for a multi-modal prediction (Q modes): each mode's weight,
                                        the first column that of pred_mean's mode
``pred_alt_mean``      (Q-1, N, P, 2)   only for a multi-modal prediction: the other modes' centres
``cand_xy``            (K, S, 2) f16    every scored candidate's centres: the next step, every
                                        ``stride``-th step and the horizon's end
                                        (float16: within 3 cm up to 64 m from the ego, 6 cm to 128 m)
``cand_t``             (S,)             the time after planning of those samples [s]
``selection``          (K,)             what the selection rule minimised
``j_risk``             (K,)             J_risk = cost total
``risk``               (K,)             summed ex-ante risk over every party
``validity``           (K,) int8        validity class (``plan.ethical.VALIDITY``)
``eligible``           (K,) bool        could be chosen (hard pool / chosen class)
``first_hit``          (K,) int16       first step entering a predicted envelope (T: never)
``excluded``           (K,) int8        the hard constraint that kept it from being chosen
                                        (``types.EXCLUSIONS``, 0 none; absent in older files)
``term_names``         (M,) str         the named cost terms
``term_rows``          (R,) int32       the candidates whose terms are kept: the chosen one, then
                                        the best (lowest selection) of every other validity class
``terms``              (R, M)           their values
``meta``               (6,) float64     step, time, chosen, dt, horizon steps T, stride
``view_eye``           (3,) float64     only with ``[planner] occlusion``/``phantoms``: the sensor's x, y
                                        (network frame) and range [m]
``view_visible``       (B,) uint8       the visible region, WKB (network frame, float64)
``view_hidden``        (B,) uint8       the shadows within the range, WKB
``view_seen``          (S,) str         the road users seen (``view_remembered``: remembered while hidden)
``phantoms``           (P, 7)           the phantom road users, as ``agents``
``phantom_mean``       (P, P', 2)       their predicted centres, as ``pred_mean``
``phantom_existence``  (P,)             their existence probabilities
``phantom_risk``       (P,)             the chosen candidate's expected risk with each
=====================  ==============  =========================================================

Modes (``--record-decisions``): ``all`` every planning step; ``risky`` the steps whose chosen
candidate carries risk (ex-ante risk > 0 to any party; on a busy junction some candidate always
does, so that would keep nearly every step), at most one per RISKY_SPACING seconds of simulated
time and, past RISKY_BUDGET kept steps, one per THIN_SECONDS; and every step of the
``PRE_COLLISION`` seconds before an ego collision;
``collisions`` only those seconds before each ego collision; ``off`` nothing but the last step
before each ego collision (what its snapshot figure needs). Recording never changes a decision:
it reads what the planner computed.
"""

from __future__ import annotations

import io
import urllib.parse
import zipfile
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sumo_ethics import fileio
from sumo_ethics.config import DECISION_MODES as MODES
from sumo_ethics.types import DecisionTrace

FOLDER = "decisions"
#: the run folder's collision snapshot figures (collision_<event>.png/.svg)
SNAPSHOTS = "snapshots"
#: seconds of decisions kept before every ego collision (modes collisions and risky)
PRE_COLLISION = 5.0
#: candidate positions are kept every this many seconds (at least every planning step), and the
#: predicted Gaussians likewise (PREDICTION_SPACING): what explain and replay draw (ellipses every
#: second), not every 0.1 s step; 0.2 and every step before (issue 41: 4.7-17 MB per urban run)
CANDIDATE_SPACING = 0.5
PREDICTION_SPACING = 0.5
#: mode risky keeps a risky step when RISKY_SPACING seconds of simulated time have passed since the
#: last one it kept (explain --time finds the nearest within 0.5 s), until RISKY_BUDGET are kept, then
#: one per THIN_SECONDS; the steps before a collision always. So at most 120 risky steps per simulated
#: minute, whatever the step length: on eclipse-sumo's fokr_bs_demo (0.05 s steps, up to 24 road users
#: in range) 988 steps and 15.4 MB in the first minute before, 99 and 1.5 MB with the spacing
RISKY_SPACING = 0.5
RISKY_BUDGET = 1000
THIN_SECONDS = 10.0
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def ego_folder(ego: str) -> str:
    """The folder name of fleet ego ``ego``'s decisions: its SUMO id percent-encoded (every
    character but letters, digits and ``_.-~``; so ``/``, ``:``, ``#``, spaces and ``%`` itself),
    one name per id and back (:func:`urllib.parse.unquote`); the names ``.`` and ``..`` as ``%2E``."""
    name = urllib.parse.quote(ego, safe="")
    return name.replace(".", "%2E") if name in (".", "..") else name


def step_path(out: Path, step: int, ego: str | None = None) -> Path:
    """The decision file of ``step`` in run folder ``out``: of fleet ego ``ego``, or of the one ego."""
    folder = Path(out) / FOLDER
    return (folder if ego is None else folder / ego_folder(ego)) / f"step_{step:06d}.npz"


def encode(trace: DecisionTrace, step: int, time: float, dt: float) -> dict[str, np.ndarray]:
    """The compact arrays of one decision (see the module docstring)."""
    e, a, p, c = trace.ego, trace.agents, trace.prediction, trace.candidates
    ox, oy = float(e.x[0]), float(e.y[0])
    f32 = np.float32
    T = c.x.shape[1]
    stride = max(1, int(round(CANDIDATE_SPACING / c.dt)))
    idx = np.unique(np.r_[0, np.arange(stride - 1, T, stride), T - 1])  # always the next step and the end
    tp = p.mean.shape[1]
    pstride = max(1, int(round(PREDICTION_SPACING / p.dt)))
    pidx = np.unique(np.r_[np.arange(pstride - 1, tp, pstride), tp - 1]) if tp else np.zeros(0, dtype=np.intp)
    names = sorted(trace.cost.terms)
    # the named terms of the chosen candidate and of the best (lowest selection) of each other class
    rows = [trace.chosen] + [int(np.flatnonzero(trace.validity == v)[np.argmin(trace.selection[trace.validity == v])])
                             for v in np.unique(trace.validity) if v != trace.validity[trace.chosen]]
    cov = p.cov
    modes = {}
    if p.alternatives:  # absent for a single-mode prediction: those files stay byte for byte as before
        modes = {"pred_weight": np.asarray(p.weight, dtype=f32),
                 "pred_alt_mean": np.stack([a.mean[:, pidx] - np.array([ox, oy]) for a in p.alternatives]).astype(f32)}
    return {
        **({} if trace.view is None else _encode_view(trace.view, ox, oy, pidx)),
        "meta": np.array([step, time, trace.chosen, dt, p.mean.shape[1] if len(a) else T, stride], dtype=np.float64),
        "ego": np.array([ox, oy, e.yaw[0], e.speed[0], e.length[0], e.width[0], e.mass[0], e.cls[0]], dtype=np.float64),
        "agent_ids": np.array(a.ids, dtype=str),
        "agents": np.stack([a.x - ox, a.y - oy, a.yaw, a.speed, a.length, a.width, a.cls], axis=-1).astype(f32)
        if len(a) else np.zeros((0, 7), f32),
        "pred_mean": (p.mean[:, pidx] - np.array([ox, oy])).astype(f32),
        "pred_cov": np.stack([cov[:, pidx, 0, 0], cov[:, pidx, 0, 1], cov[:, pidx, 1, 1]], axis=-1).astype(f32),
        "pred_t": ((pidx + 1) * p.dt).astype(f32),
        **modes,
        "cand_xy": np.stack([c.x[:, idx] - ox, c.y[:, idx] - oy], axis=-1).astype(np.float16),
        "cand_t": ((idx + 1) * c.dt).astype(f32),
        "selection": np.asarray(trace.selection, dtype=f32),
        "j_risk": np.asarray(trace.cost.total, dtype=f32),
        "risk": np.asarray(trace.risk, dtype=f32),
        "validity": np.asarray(trace.validity, dtype=np.int8),
        "eligible": np.asarray(trace.eligible, dtype=bool),
        "first_hit": np.minimum(trace.first_hit, np.iinfo(np.int16).max).astype(np.int16),
        **({} if trace.excluded is None else {"excluded": np.asarray(trace.excluded, dtype=np.int8)}),
        "term_names": np.array(names, dtype=str),
        "term_rows": np.array(rows, dtype=np.int32),
        "terms": np.stack([trace.cost.terms[n][rows] for n in names], axis=-1).astype(f32)
        if names else np.zeros((len(rows), 0), f32),
    }


def _encode_view(v: Any, ox: float, oy: float, pidx: np.ndarray) -> dict[str, np.ndarray]:
    """A decision's view (types.ViewTrace): see the module docstring (absent without one: those files
    stay byte for byte as before)."""
    import shapely

    f32 = np.float32
    ph = v.phantoms
    pred = v.phantom_prediction
    tp = 0 if pred is None else pred.mean.shape[1]
    keep = pidx[pidx < tp]
    return {
        "view_eye": np.array([v.eye[0], v.eye[1], v.radius], dtype=np.float64),
        "view_visible": np.frombuffer(shapely.to_wkb(v.visible), dtype=np.uint8),
        "view_hidden": np.frombuffer(shapely.to_wkb(v.hidden), dtype=np.uint8),
        "view_seen": np.array(v.seen, dtype=str),
        "view_remembered": np.array(v.remembered, dtype=str),
        "phantoms": np.stack([ph.x - ox, ph.y - oy, ph.yaw, ph.speed, ph.length, ph.width, ph.cls], axis=-1).astype(f32)
        if len(ph) else np.zeros((0, 7), f32),
        "phantom_mean": (pred.mean[:, keep] - np.array([ox, oy])).astype(f32) if pred is not None and len(ph)
        else np.zeros((0, len(keep), 2), f32),
        "phantom_existence": np.asarray(v.phantom_existence, dtype=f32),
        "phantom_risk": np.asarray(v.phantom_risk, dtype=f32),
    }


def write(path: Path, arrays: dict[str, np.ndarray]) -> int:
    """Write ``arrays`` as a compressed .npz, atomically and byte-reproducibly; returns its size [B]."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with fileio.replacing(path) as tmp, zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as z:
        for name, arr in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.ascontiguousarray(arr), allow_pickle=False)
            z.writestr(zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_TIME), buf.getvalue(),
                       compress_type=zipfile.ZIP_DEFLATED, compresslevel=1)
    return path.stat().st_size


@dataclass
class DecisionLog:
    """Keeps the decisions of one run by ``mode`` (of its fleet ego ``ego``: one log per ego);
    :meth:`add` once per planning step (after the step's collisions were detected: ``collided``
    says whether the step ended in a new ego collision)."""

    out: Path
    mode: str
    dt: float
    ego: str | None = None

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"unknown decision recording mode {self.mode!r}; known: {', '.join(MODES)}")
        keep = int(np.ceil(PRE_COLLISION / self.dt - 1e-9)) if self.mode in ("collisions", "risky") else 0
        self.keep = max(keep, 1)  # steps kept before a collision
        #: the not yet written decisions of the last PRE_COLLISION seconds: (step, arrays or trace)
        self.ring: deque[tuple[int, Any]] = deque(maxlen=self.keep)
        self.written: list[int] = []
        self.bytes = 0
        self.risky_kept = 0
        self.thinned = 0  # risky steps not kept: within RISKY_SPACING, or past the budget (mode risky)
        self._last_risky = -np.inf

    def add(self, step: int, time: float, trace: DecisionTrace | None, collided: bool) -> None:
        if trace is None:  # no planner decision this step (emergency brake, baseline controller)
            if collided:
                self._flush_ring(step)
            return
        risky = bool(trace.risk[trace.chosen] > 0.0)
        spacing = THIN_SECONDS if self.risky_kept >= RISKY_BUDGET else RISKY_SPACING
        if risky and self.mode == "risky" and time - self._last_risky < spacing - 1e-9:
            self.thinned += 1
            risky = False  # too soon after the last kept: kept only if it ends in a collision (the ring below)
        if self.mode == "all" or (self.mode == "risky" and risky):
            self._write(step, encode(trace, step, time, self.dt))
            if risky:
                self.risky_kept += 1
                self._last_risky = time
        elif self.mode == "off":  # the trace itself (no cost): encoded only if it ends in a collision
            self.ring.append((step, (trace, time)))
        else:
            self.ring.append((step, encode(trace, step, time, self.dt)))
        if collided:
            self._flush_ring(step)

    def collided(self, step: int) -> None:
        """Step ``step``, already added, ended in an ego collision found after :meth:`add` (a fleet
        ego hit by another ego whose check ran first, or reported by SUMO): keep what
        ``add(..., collided=True)`` would have kept."""
        self._flush_ring(step)

    def settled(self) -> None:
        """Every collision of the step last added is known (:meth:`add`'s ``collided``, :meth:`collided`):
        let go of what no later step can keep. With one step kept before a collision (mode off) that
        is the ring's decision, whose trace (the candidates, K x T arrays) would wait for the next add."""
        if self.keep == 1:
            self.ring.clear()

    def _flush_ring(self, now: int) -> None:
        """Write the kept decisions of the ``keep`` steps up to step ``now``."""
        while self.ring:
            step, item = self.ring.popleft()
            if step <= now - self.keep:  # older (risky mode keeps only the steps it did not write)
                continue
            if isinstance(item, tuple):
                item = encode(item[0], step, item[1], self.dt)
            self._write(step, item)

    def _write(self, step: int, arrays: dict[str, np.ndarray]) -> None:
        self.bytes += write(step_path(self.out, step, self.ego), arrays)
        self.written.append(step)


# ---- reading ------------------------------------------------------------------------------------
def recorded_steps(run: Path, ego: str | None = None) -> list[int]:
    """The steps of ``run`` with a recorded decision (of fleet ego ``ego``), in order."""
    folder = step_path(run, 0, ego).parent
    if not folder.is_dir():
        return []
    return sorted(int(p.stem.removeprefix("step_")) for p in folder.glob("step_[0-9]*.npz"))


def recorded_egos(run: Path) -> list[str]:
    """The fleet egos of ``run`` with recorded decisions (a folder holding a step file), sorted by id."""
    folder = Path(run) / FOLDER
    if not folder.is_dir():
        return []
    return sorted(urllib.parse.unquote(p.name) for p in folder.iterdir()
                  if p.is_dir() and next(p.glob("step_[0-9]*.npz"), None) is not None)


@dataclass(frozen=True)
class RecordedDecision:
    """One recorded decision, positions back in the network frame [m].

    step, time: steps.parquet row it led to, planning time [s]; chosen: index into the K
    candidates; ego: (8,) x, y, yaw, speed, length, width, mass, class; agent_ids: (N,);
    agents: (N, 7) x, y, yaw, speed, length, width, class; pred_mean: (N, P, 2); pred_cov:
    (N, P, 2, 2); pred_t: (P,) [s] after planning; cand_xy: (K, S, 2); cand_t: (S,); selection, j_risk, risk: (K,);
    validity: (K,) int8; eligible: (K,) bool; first_hit: (K,); excluded: (K,) int8 or None (files
    recorded before it); terms: name -> (K,), NaN but for
    the chosen candidate and the best one of every other validity class (the ones kept);
    pred_weight: (N, Q) mode weights and pred_alt_mean: (Q-1, N, T, 2) the other modes' centres,
    None for a single-mode prediction (pred_mean / pred_cov are then the most likely mode); view: what
    the ego's sensor saw (:class:`RecordedView`), None without ``[planner] occlusion`` or ``phantoms``.
    """

    step: int
    time: float
    dt: float
    chosen: int
    ego: np.ndarray
    agent_ids: tuple[str, ...]
    agents: np.ndarray
    pred_mean: np.ndarray
    pred_cov: np.ndarray
    pred_t: np.ndarray
    cand_xy: np.ndarray
    cand_t: np.ndarray
    selection: np.ndarray
    j_risk: np.ndarray
    risk: np.ndarray
    validity: np.ndarray
    eligible: np.ndarray
    first_hit: np.ndarray
    terms: dict[str, np.ndarray]
    pred_weight: np.ndarray | None = None
    pred_alt_mean: np.ndarray | None = None
    excluded: np.ndarray | None = None
    view: "RecordedView | None" = None

    @property
    def n_candidates(self) -> int:
        return len(self.j_risk)

    def whole_seconds(self) -> np.ndarray:
        """Indices of the prediction samples (``pred_t``) on a whole second: where ellipses are drawn."""
        return whole_seconds(self.pred_t)


@dataclass(frozen=True)
class RecordedView:
    """What the ego's sensor saw at a recorded decision, network frame: eye (2,) and radius [m];
    visible, hidden: shapely geometries; seen, remembered: road user ids; phantoms (P, 7) as
    ``RecordedDecision.agents``; phantom_mean (P, P', 2) at the decision's ``pred_t``;
    phantom_existence, phantom_risk (P,)."""

    eye: np.ndarray
    radius: float
    visible: Any
    hidden: Any
    seen: tuple[str, ...]
    remembered: tuple[str, ...]
    phantoms: np.ndarray
    phantom_mean: np.ndarray
    phantom_existence: np.ndarray
    phantom_risk: np.ndarray


def _view(d: dict[str, np.ndarray], origin: np.ndarray) -> RecordedView | None:
    if "view_eye" not in d:
        return None
    import shapely

    ph = d["phantoms"].astype(np.float64)
    ph[:, :2] += origin
    return RecordedView(eye=d["view_eye"][:2].astype(np.float64), radius=float(d["view_eye"][2]),
                        visible=shapely.from_wkb(d["view_visible"].tobytes()),
                        hidden=shapely.from_wkb(d["view_hidden"].tobytes()),
                        seen=tuple(str(x) for x in d["view_seen"]), remembered=tuple(str(x) for x in d["view_remembered"]),
                        phantoms=ph, phantom_mean=d["phantom_mean"].astype(np.float64) + origin,
                        phantom_existence=d["phantom_existence"].astype(np.float64),
                        phantom_risk=d["phantom_risk"].astype(np.float64))


def whole_seconds(t: np.ndarray) -> np.ndarray:
    """Indices of the sample times ``t`` [s] that fall on a whole second (within 1 ms)."""
    frac = np.asarray(t) % 1.0
    return np.flatnonzero(np.isclose(frac, 0.0, atol=1e-3) | np.isclose(frac, 1.0, atol=1e-3))


def load(run: Path, step: int, ego: str | None = None) -> RecordedDecision:
    """The decision recorded for ``step`` of ``run`` (of fleet ego ``ego``; FileNotFoundError if none)."""
    with np.load(step_path(run, step, ego), allow_pickle=False) as z:
        d = {k: z[k] for k in z.files}
    meta, state = d["meta"], d["ego"]
    origin = state[:2].astype(np.float64)
    agents = d["agents"].astype(np.float64)
    agents[:, :2] += origin
    c = d["pred_cov"].astype(np.float64)
    cov = np.stack([np.stack([c[..., 0], c[..., 1]], -1), np.stack([c[..., 1], c[..., 2]], -1)], -2)
    return RecordedDecision(
        step=int(meta[0]), time=float(meta[1]), dt=float(meta[3]), chosen=int(meta[2]), ego=state,
        agent_ids=tuple(str(x) for x in d["agent_ids"]), agents=agents,
        pred_mean=d["pred_mean"].astype(np.float64) + origin, pred_cov=cov,
        pred_t=d["pred_t"].astype(np.float64) if "pred_t" in d else (np.arange(d["pred_mean"].shape[1]) + 1) * meta[3],
        cand_xy=d["cand_xy"].astype(np.float64) + origin, cand_t=d["cand_t"].astype(np.float64),
        selection=d["selection"], j_risk=d["j_risk"], risk=d["risk"], validity=d["validity"],
        eligible=d["eligible"], first_hit=d["first_hit"],
        terms=_terms(d, len(d["j_risk"])),
        pred_weight=d["pred_weight"].astype(np.float64) if "pred_weight" in d else None,
        pred_alt_mean=d["pred_alt_mean"].astype(np.float64) + origin if "pred_alt_mean" in d else None,
        excluded=d.get("excluded"), view=_view(d, origin))


def _terms(d: dict[str, np.ndarray], k: int) -> dict[str, np.ndarray]:
    if "term_rows" not in d:  # files of the first version kept every candidate's terms
        return {str(n): d["terms"][:, i] for i, n in enumerate(d["term_names"])}
    out = {}
    for i, n in enumerate(d["term_names"]):
        v = np.full(k, np.nan, dtype=np.float32)
        v[d["term_rows"]] = d["terms"][:, i]
        out[str(n)] = v
    return out
