"""Time the ethics hot path: collision probability + risk + cost for one planning step.

    OPENBLAS_NUM_THREADS=1 python tools/bench_risk.py [--k 1000] [--n 20] [--t 40] [--runs 50]
        [--scene highway|crowded] [--top-pad-mb 64]

Synthetic but planner-like scene: the ego at 15 m/s on a 4-lane road, K candidates (lateral
end offsets x end speeds over T steps of 0.1 s), N agents predicted at constant velocity with a
covariance growing along and across their heading. "highway": cars spread over -40..90 m plus
two cyclists and two pedestrians at the kerb; "crowded": every agent within 25 m of the ego.
Prints the median and minimum wall time [ms] of each stage over ``--runs`` runs after warm-up.

``--top-pad-mb`` sets glibc's M_TOP_PAD (mallopt) first: numpy's temporaries are freed and
re-allocated every call, and with the default padding glibc trims the heap each time and the
next call page-faults all of it in again (~3000 faults, ~2-3 ms per step here). 0 leaves
the allocator alone. The runner can do the same once at start-up (or set MALLOC_TOP_PAD_).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core; must precede the numpy import

import argparse  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from sumo_ethics.ethics.cost import CostConfig, score  # noqa: E402
from sumo_ethics.ethics.probability import ProbabilityConfig, collision_probability, sparse_collision_probability  # noqa: E402
from sumo_ethics.ethics.risk import assess_risk  # noqa: E402
from sumo_ethics.types import AgentStates, Candidates, Prediction, RoadUserClass  # noqa: E402

DT = 0.1
EGO_L, EGO_W, EGO_M = 4.508, 1.610, 1475.0
LANES = np.array([-5.25, -1.75, 1.75, 5.25])  # ego in lane 1.75


def make_candidates(K: int, T: int, v0: float = 15.0) -> Candidates:
    n_lat = max(1, int(round(math.sqrt(K * 40 / 25))))
    n_lat = min(n_lat, K)
    n_v = -(-K // n_lat)
    d_end = np.linspace(-7.0, 7.0, n_lat)
    v_end = np.linspace(0.0, 25.0, n_v)
    dd, vv = (a.ravel()[:K] for a in np.meshgrid(d_end, v_end, indexing="ij"))
    t = (np.arange(T) + 1) * DT
    tau = t / t[-1]
    acc = (vv - v0) / t[-1]
    s = v0 * t + 0.5 * acc[:, None] * t**2
    speed_s = v0 + acc[:, None] * t
    blend = 10 * tau**3 - 15 * tau**4 + 6 * tau**5  # quintic 0 -> 1
    dblend = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / t[-1]
    y0 = 1.75
    y = y0 + dd[:, None] * blend
    vy = dd[:, None] * dblend
    yaw = np.arctan2(vy, speed_s)
    z = np.zeros((K, T))
    return Candidates(
        dt=DT, x=s, y=y, yaw=yaw, speed=np.hypot(speed_s, vy), accel=acc[:, None] + z, curvature=z,
        s=s, d=y - y0, horizon=np.full(K, T * DT), valid=np.ones((K, T), bool),
    )


def make_agents(N: int, T: int, scene: str, rng: np.random.Generator) -> tuple[AgentStates, Prediction]:
    n_vru = min(4, N // 5) if scene == "highway" else 0
    n_car = N - n_vru
    if scene == "highway":
        x = rng.uniform(-40.0, 90.0, n_car)
    else:
        x = rng.uniform(-15.0, 25.0, n_car)
    y = rng.choice(LANES, n_car) + rng.normal(0, 0.2, n_car)
    yaw = rng.normal(0, 0.02, n_car)
    speed = rng.uniform(8.0, 20.0, n_car)
    cls = np.full(n_car, int(RoadUserClass.CAR))
    length, width = np.full(n_car, 4.5), np.full(n_car, 1.8)
    if n_vru:
        vx = rng.uniform(0.0, 60.0, n_vru)
        vy = np.where(np.arange(n_vru) % 2 == 0, 7.5, -7.5)
        vyaw = np.where(np.arange(n_vru) < n_vru // 2, 0.0, -np.sign(vy) * math.pi / 2)  # cyclists along, peds crossing
        vspeed = np.where(np.arange(n_vru) < n_vru // 2, 5.0, 1.4)
        vcls = np.where(np.arange(n_vru) < n_vru // 2, int(RoadUserClass.BICYCLE), int(RoadUserClass.PEDESTRIAN))
        x, y, yaw, speed = (np.r_[a, b] for a, b in ((x, vx), (y, vy), (yaw, vyaw), (speed, vspeed)))
        cls = np.r_[cls, vcls]
        length = np.r_[length, np.where(vcls == int(RoadUserClass.BICYCLE), 1.8, 0.5)]
        width = np.r_[width, np.where(vcls == int(RoadUserClass.BICYCLE), 0.6, 0.5)]
    ids = tuple(f"a{i}" for i in range(N))
    mass = np.where(cls == int(RoadUserClass.CAR), 1500.0, np.where(cls == int(RoadUserClass.BICYCLE), 90.0, 75.0))
    agents = AgentStates(ids=ids, x=x, y=y, yaw=yaw, speed=speed, accel=np.zeros(N), length=length, width=width,
                         mass=mass, cls=cls.astype(np.int8))
    t = (np.arange(T) + 1) * DT
    h = np.stack([np.cos(yaw), np.sin(yaw)], -1)  # (N, 2)
    nrm = np.stack([-h[:, 1], h[:, 0]], -1)
    mean = np.stack([x, y], -1)[:, None] + (speed[:, None] * t)[..., None] * h[:, None]
    s_al, s_ac = 0.2 + 0.5 * t, 0.1 + 0.1 * t  # std along / across heading [m]
    cov = (s_al**2)[None, :, None, None] * np.einsum("ni,nj->nij", h, h)[:, None] + (s_ac**2)[
        None, :, None, None
    ] * np.einsum("ni,nj->nij", nrm, nrm)[:, None]
    pred = Prediction(ids=ids, dt=DT, mean=mean, cov=cov, yaw=np.broadcast_to(yaw[:, None], (N, T)).copy())
    return agents, pred


def tune_malloc(top_pad_mb: int) -> bool:
    """glibc mallopt(M_TOP_PAD, top_pad_mb MiB); False where unavailable (not glibc)."""
    if top_pad_mb <= 0:
        return False
    try:
        import ctypes
        import ctypes.util

        libc = ctypes.CDLL(ctypes.util.find_library("c"))
        return bool(libc.mallopt(-2, top_pad_mb << 20))  # M_TOP_PAD = -2
    except (OSError, AttributeError):
        return False


def timed_ms(fn, runs: int, warmup: int = 3) -> tuple[float, float]:
    """(median, min) wall time [ms]."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times), 1e3 * min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--k", type=int, default=1000)
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--t", type=int, default=40)
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--scene", choices=("highway", "crowded"), default="highway")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--top-pad-mb", type=int, default=64, help="glibc M_TOP_PAD [MiB]; 0: leave malloc alone")
    args = ap.parse_args()
    tuned = tune_malloc(args.top_pad_mb)

    rng = np.random.default_rng(args.seed)
    cand = make_candidates(args.k, args.t)
    agents, pred = make_agents(args.n, args.t, args.scene, rng)
    pcfg, ccfg = ProbabilityConfig(), CostConfig()
    sizes = (agents.length, agents.width, EGO_L, EGO_W)

    def step():
        risk = assess_risk(cand, pred, agents, EGO_M, RoadUserClass.CAR, EGO_L, EGO_W, prob_cfg=pcfg)
        return score(cand, risk, ccfg, desired_speed=15.0)

    sp = sparse_collision_probability(cand, pred, *sizes, pcfg)
    risk = assess_risk(cand, pred, agents, EGO_M, RoadUserClass.CAR, EGO_L, EGO_W, prob_cfg=pcfg)
    K, N, T = risk.shape
    print(f"scene {args.scene}: K={K} N={N} T={T} ({K * N * T:,} entries), threads={os.environ['OPENBLAS_NUM_THREADS']}, "
          f"M_TOP_PAD={'%d MiB' % args.top_pad_mb if tuned else 'default'}")
    print(f"  entries with P > 0: {sp.p.size:,} ({100 * sp.p.size / max(K * N * T, 1):.2f} %), "
          f"candidates with any risk: {int((risk.ego_risk.max(axis=1) > 0).sum()) if N else 0}")
    rows = [
        ("collision probability, sparse", lambda: sparse_collision_probability(cand, pred, *sizes, pcfg)),
        ("collision probability, dense (K,N,T)", lambda: collision_probability(cand, pred, *sizes, pcfg)),
        ("assess_risk (P + harm + risk)",
         lambda: assess_risk(cand, pred, agents, EGO_M, RoadUserClass.CAR, EGO_L, EGO_W, prob_cfg=pcfg)),
        ("score", lambda: score(cand, risk, ccfg, desired_speed=15.0)),
        ("assess_risk + score (one step)", step),
    ]
    print(f"  {'stage':38s} {'median':>8s} {'min':>8s}   (ms, {args.runs} runs)")
    for name, fn in rows:
        med, best = timed_ms(fn, args.runs)
        print(f"  {name:38s} {med:8.2f} {best:8.2f}")

if __name__ == "__main__":
    main()
