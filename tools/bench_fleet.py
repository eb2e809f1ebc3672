"""What a fleet costs: wall time per simulated second with 1, 5, 10, 25 (and 100) egos on the same
scenario, the ethical planner with its prediction shared among the egos, and at one size also
with one prediction per ego (the sharing switched off), and memory over the run.

Each fleet run inserts N egos of ours on urban_grid (routes drawn with the seed). Their
departures are spread over the first half of the run (``--end``), so the figure reported is
taken over the second half, where every ego that could be inserted drives: the wall time of
those steps per simulated second, per ego-step, and the per-ego-step medians of the planner's
parts from timings.parquet. The resident memory of the process is sampled every second; its
growth over the second half is reported (flat memory: a few MB).

    python tools/bench_fleet.py [--sizes 1,5,10,25] [--end 40] [--unshared 10] [--baseline 100]
                                [--replan-every 1,3] [--threads 1|2|auto]
    python tools/bench_fleet.py --memory 600   # memory while egos come and go (penetration 1, baseline),
                                               # its growth with time separated from the traffic it holds
                                               # (now, and the most so far); --save CSV keeps the samples
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 1e6


def growth_fit(rss: np.ndarray, covariates: list[np.ndarray], t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ordinary least squares RSS [MB] ~ 1 + covariates + t / 100 [s]: (coefficients, their standard
    errors, residuals); the last coefficient is the growth per 100 s the covariates do not explain."""
    x = np.column_stack([np.ones(len(t)), *covariates, np.asarray(t) / 100.0])
    coef, *_ = np.linalg.lstsq(x, rss, rcond=None)
    resid = rss - x @ coef
    cov = np.linalg.inv(x.T @ x) * (resid @ resid) / max(len(t) - x.shape[1], 1)
    return coef, np.sqrt(np.diag(cov)), resid


def rss_sampler() -> tuple[list[tuple[float, float]], threading.Event, threading.Thread]:
    """A started thread appending (time, RSS MB) every second to the list until the event is set."""
    samples: list[tuple[float, float]] = []
    stop = threading.Event()

    def sample() -> None:
        while not stop.is_set():
            samples.append((time.perf_counter(), rss_mb()))
            stop.wait(1.0)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    return samples, stop, th


def one(n: int, end: float, shared: bool, planner: str, out: Path, seed: int, replan_every: int = 1) -> dict:
    import pandas as pd

    from sumo_ethics.config import FleetSpec, RunConfig
    from sumo_ethics.runner.fleet import make_fleet_controllers, run_fleet
    from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig
    from sumo_ethics.plan.baseline import RouteFollower

    cfg = RunConfig(scenario=ROOT / "scenarios" / "urban_grid" / "urban_grid.sumocfg", out=out, seed=seed, end=end,
                    progress=False, fleet=FleetSpec(egos=n, shares=((planner, 1.0),)),
                    planner=PlannerConfig(replan_every=replan_every))
    if planner == "baseline":
        def make(name, vid):
            return RouteFollower()
    elif shared:
        make = make_fleet_controllers(cfg)
    else:
        def make(name, vid):  # one predictor per ego: each predicts its own neighbours
            return EthicalPlanner(PlannerConfig(replan_every=replan_every))
    samples, stop, th = rss_sampler()
    t0 = time.perf_counter()
    s = run_fleet(cfg, make)
    stop.set()
    th.join()
    steps = pd.read_parquet(out / "steps.parquet", columns=["ego_id", "step", "time"])
    tim = pd.read_parquet(out / "timings.parquet")
    late_steps = steps.loc[steps["time"] > end / 2, "step"]
    lt = tim[tim["step"].isin(late_steps)]
    per_step = lt.groupby("step")
    # wall_s: the run's clock when each ego's row was written; over the second half of the run
    wall = float(lt["wall_s"].max() - lt["wall_s"].min())
    sim = float(steps.loc[steps["time"] > end / 2, "time"].agg(lambda t: t.max() - t.min()))
    late_rss = [r for t, r in samples if t - t0 > (time.perf_counter() - t0) / 2]
    # the wall time of each step's planning, all egos together (they may plan on several threads at
    # once, so their own controller_ms overlap): the fleet runner's fleet_plan_ms, once per step
    plan_wall = float(per_step["fleet_plan_ms"].first().median()) if "fleet_plan_ms" in lt else float("nan")
    return {"n": n, "planner": planner, "shared": shared, "egos_driving": float(per_step.size().median()),
            "plan_wall_ms": plan_wall,
            "controller_ms": float(lt["controller_ms"].median()),
            "predict_ms": float(lt["predict_ms"].median()) if "predict_ms" in lt else 0.0,
            "ego_step_ms": float(per_step["controller_ms"].sum().median()),
            "wall_per_sim_s": wall / sim if sim > 0 else float("nan"), "run_wall": time.perf_counter() - t0,
            "rss_growth_mb": late_rss[-1] - min(late_rss) if len(late_rss) > 2 else float("nan"),
            "rss_mb": samples[-1][1] if samples else float("nan"), "egos": s.data["fleet"]["egos"]}


def memory(seconds: float, seed: int, every: float = 5.0, save: str = "") -> None:
    """Memory over a long run whose egos come and go: penetration 1, baseline planners (cheap), so
    every eligible vehicle of urban_grid is an ego from its departure to its arrival.

    Every ``every`` simulated seconds the first ego to act samples the resident memory and counts
    the controllers still alive (a WeakSet, after a garbage collection). Afterwards the egos
    driving and the road users in SUMO at each sample come from steps.parquet and trips.parquet,
    and an ordinary least-squares fit RSS ~ 1 + egos + road users + t over the samples after the
    build-up (the first 20 %) separates what the traffic holds from growth with time: flat memory
    is a time slope whose CI holds 0 MB per 100 s, or a few tenths. While the traffic still builds
    up, that slope also holds the allocators' high water (memory freed is kept for reuse): a second
    fit against the most egos and road users so far tells the two apart."""
    import gc
    import weakref

    import pandas as pd

    from sumo_ethics.config import FleetSpec, RunConfig
    from sumo_ethics.runner.fleet import run_fleet
    from sumo_ethics.plan.baseline import RouteFollower

    live: weakref.WeakSet = weakref.WeakSet()
    samples: list[tuple[float, float, int]] = []  # (sim time [s], RSS [MB], controllers alive)

    class Sampled(RouteFollower):
        def act(self, scene):  # type: ignore[no-untyped-def]
            if not samples or scene.time >= samples[-1][0] + every:
                gc.collect()
                samples.append((scene.time, rss_mb(), len(live)))
            return super().act(scene)

    def make(name: str, vid: str) -> RouteFollower:
        c = Sampled()
        live.add(c)
        return c

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "m"
        cfg = RunConfig(scenario=ROOT / "scenarios" / "urban_grid" / "urban_grid.sumocfg", out=out,
                        seed=seed, end=seconds, progress=False, fleet=FleetSpec(penetration=1.0,
                                                                                 shares=(("baseline", 1.0),)))
        t0 = time.perf_counter()
        s = run_fleet(cfg, make)
        wall = time.perf_counter() - t0
        steps = pd.read_parquet(out / "steps.parquet", columns=["ego_id", "time", "n_neighbours"])
        trips = pd.read_parquet(out / "trips.parquet")
    d = pd.DataFrame(samples, columns=["t", "rss", "alive"])
    driving = steps.groupby("time").ego_id.nunique()
    d["egos"] = [int(driving.get(round(t, 6), driving.iloc[np.abs(driving.index - t).argmin()])) for t in d.t]
    # what the egos see: the sum over the egos of their road users in range (each ego's scene, history
    # and conflict trails hold its neighbours: egos x density, more than linear in the traffic)
    seen = steps.groupby("time").n_neighbours.sum()
    d["neighbours"] = [int(seen.iloc[np.abs(seen.index - t).argmin()]) for t in d.t]
    arr = trips["arrival"].where(trips["arrival"] >= 0, np.inf).to_numpy(float)
    d["road_users"] = [int(((trips["depart"].to_numpy(float) <= t) & (arr > t)).sum()) for t in d.t]
    late = d[d.t >= 0.2 * seconds]
    coef, se, resid = growth_fit(late.rss.to_numpy(), [late.egos.to_numpy(), late.road_users.to_numpy()],
                                 late.t.to_numpy())
    f = s.data["fleet"]
    print(f"memory, penetration 1 (baseline), {seconds:g} s of urban_grid ({wall:.0f} s wall): {f['egos']} egos "
          f"({f['by_status']}); {len(d)} samples every {every:g} s")
    print("RSS at 10/25/50/75/100 % of the run: "
          + " / ".join(f"{d.rss.iloc[min(int(q * (len(d) - 1)), len(d) - 1)]:.0f}" for q in (0.1, 0.25, 0.5, 0.75, 1.0))
          + " MB; egos driving at those samples: "
          + " / ".join(str(d.egos.iloc[min(int(q * (len(d) - 1)), len(d) - 1)]) for q in (0.1, 0.25, 0.5, 0.75, 1.0)))
    print(f"controllers alive minus egos driving, over the samples: max {int((d.alive - d.egos).max())}, "
          f"median {float((d.alive - d.egos).median()):.0f} (an ended ego's planner must be freed)")
    print(f"fit over t >= {0.2 * seconds:g} s ({len(late)} samples): RSS = {coef[0]:.1f} MB + {coef[1]:.3f} MB per ego "
          f"driving + {coef[2]:.3f} MB per road user in SUMO + {coef[3]:.2f} MB per 100 s "
          f"[95 % CI {coef[3] - 1.96 * se[3]:.2f}, {coef[3] + 1.96 * se[3]:.2f}]; residual sd {resid.std():.2f} MB")
    coef, se, resid = growth_fit(late.rss.to_numpy(), [late.egos.to_numpy(), late.road_users.to_numpy(),
                                                       late.neighbours.to_numpy()], late.t.to_numpy())
    print(f"with what the egos see (the sum of their neighbours, {late.neighbours.min()}-{late.neighbours.max()}): "
          f"RSS = {coef[0]:.1f} MB + {coef[1]:.3f} MB per ego driving + {coef[2]:.3f} MB per road user + "
          f"{1e3 * coef[3]:.1f} kB per ego-neighbour + {coef[4]:.2f} MB per 100 s "
          f"[95 % CI {coef[4] - 1.96 * se[4]:.2f}, {coef[4] + 1.96 * se[4]:.2f}]; residual sd {resid.std():.2f} MB")
    # the allocators keep what they once held (freed memory is reused, seldom returned): the resident
    # memory follows the most traffic held so far, so growth with time is what that high water leaves
    d["max_egos"], d["max_road_users"] = d.egos.cummax(), d.road_users.cummax()
    late = d[d.t >= 0.2 * seconds]
    coef, se, resid = growth_fit(late.rss.to_numpy(), [late.max_egos.to_numpy(), late.max_road_users.to_numpy()],
                                 late.t.to_numpy())
    print(f"against the high water (the most egos driving and road users so far): RSS = {coef[0]:.1f} MB + "
          f"{coef[1]:.3f} MB per ego + {coef[2]:.3f} MB per road user + {coef[3]:.2f} MB per 100 s "
          f"[95 % CI {coef[3] - 1.96 * se[3]:.2f}, {coef[3] + 1.96 * se[3]:.2f}]; residual sd {resid.std():.2f} MB")
    if save:
        d.to_csv(save, index=False)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1,5,10,25")
    ap.add_argument("--end", type=float, default=40.0)
    ap.add_argument("--unshared", type=int, default=10, help="also run this size with one prediction per ego (0: no)")
    ap.add_argument("--baseline", type=int, default=100, help="also run this many baseline egos (0: no)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--memory", type=float, default=0.0, help="only the memory run, this many simulated seconds")
    ap.add_argument("--save", default="", help="with --memory: the samples (t, rss, egos, ...) to this CSV")
    ap.add_argument("--replan-every", default="1", help="the planners' replan_every; several (1,3) run each size "
                    "with each, compared with one ego at the first")
    ap.add_argument("--threads", default="1", help="threads of the risk kernels (a number or auto)")
    a = ap.parse_args()
    from sumo_ethics import cores

    cores.set_threads(a.threads if a.threads == "auto" else int(a.threads))
    if a.memory:
        memory(a.memory, a.seed, save=a.save)
        return
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        every = [int(v) for v in a.replan_every.split(",")]
        jobs = [(int(n), True, "ethical", e) for e in every for n in a.sizes.split(",")]
        if a.unshared:
            jobs.append((a.unshared, False, "ethical", every[0]))
        if a.baseline:
            jobs.append((a.baseline, True, "baseline", 1))
        for k, (n, shared, planner, e) in enumerate(jobs):
            r = one(n, a.end, shared, planner, Path(tmp) / f"r{k}", a.seed, e)
            r["replan_every"] = e
            rows.append(r)
            print(f"{r['n']:>4} egos {r['planner']:>8} {'shared' if r['shared'] else 'own':>6} replan_every {e}: "
                  f"driving {r['egos_driving']:5.1f}, "
                  f"planner {r['controller_ms']:6.1f} ms/ego-step (predict {r['predict_ms']:5.1f}), "
                  f"{r['ego_step_ms']:7.1f} ms of planning per step summed over the egos, {r['plan_wall_ms']:7.1f} ms "
                  f"of wall time, {r['wall_per_sim_s']:6.1f} s wall per simulated s, "
                  f"RSS {r['rss_mb']:.0f} MB (+{r['rss_growth_mb']:.1f} MB over the second half)", flush=True)
    one_ego = next((r for r in rows if r["n"] == 1 and r["planner"] == "ethical"), None)
    if one_ego:
        for r in rows:
            if r["planner"] == "ethical":
                print(f"{r['n']} egos ({'shared' if r['shared'] else 'own'} prediction, replan_every "
                      f"{r['replan_every']}): planning per step {r['plan_wall_ms'] / one_ego['plan_wall_ms']:.1f}x "
                      f"one ego's in wall time ({r['ego_step_ms'] / one_ego['ego_step_ms']:.1f}x summed over the "
                      f"egos; one ego at replan_every {one_ego['replan_every']}), wall per simulated second "
                      f"{r['wall_per_sim_s'] / one_ego['wall_per_sim_s']:.1f}x")


if __name__ == "__main__":
    main()
