"""``sumo-ethics replay``: the ego's run as an animation, one frame per recorded planning step.

Each frame is an ego-centred view (``half`` metres each way, axes in metres of the network
frame): the road from the SUMO network (read and drawn once; the view pans), every road user
as its true box coloured by class with its predicted mean path and 1-sigma ellipse every
second, all candidates faint by validity class, the chosen trajectory in black, the ego's trail,
and a title with the time, the ego's speed and the choice (validity class, J_risk). The frames
are every ``every``-th recorded step plus the recorded step of every ego collision, which is
marked in red (who was hit, the harm booked). In a fleet run it is one ego's (``ego``): its
decisions, its collisions, its name in the titles.

Frames are rendered one at a time and handed to a writer: ``.mp4`` through ffmpeg (when it is
missing a ``.gif`` is written next to the requested name, with a message saying so), ``.gif``
through :class:`GifStream`, which writes each frame to the file as it comes (matplotlib's
PillowWriter keeps every frame in memory until the end), so memory stays flat however long the
run. The file is written under a temporary name and renamed when complete.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sumo_ethics import fileio
from sumo_ethics.geometry import OrientedBoxes, ellipses
from sumo_ethics.errors import ConfigError
from sumo_ethics.record import decisions as rec

SUFFIXES = (".mp4", ".gif")
#: default frame rate cap for a GIF [frames/s] (file size; real time at dt = 0.1 s)
GIF_FPS_CAP = 10.0
#: default frame rate cap for an MP4 [frames/s]
MP4_FPS_CAP = 30.0
#: figure size [in] and resolution [dpi]: 800 x 600 pixels
FIGSIZE = (8.0, 6.0)
DPI = 100


@dataclass(frozen=True)
class ReplayResult:
    """What :func:`replay` wrote: the file (a .gif when an .mp4 was asked for without ffmpeg),
    the frames, the writer used ("ffmpeg" or "gif"), the frame rate and playback speed (1.0 =
    real time), the recorded and total steps of the run, the notes to show the user (MP4
    fallback, partial recording) and a line describing the playback."""

    path: Path
    n_frames: int
    writer: str
    fps: float = 0.0
    speed: float = 1.0
    recorded: int = 0
    total_steps: int = 0
    notes: tuple[str, ...] = field(default_factory=tuple)
    playback: str = ""


class GifStream:
    """A matplotlib movie writer (``saving`` / ``grab_frame``) that appends each frame to a GIF
    file at once: adaptive 256-colour palette per frame (no dithering), only the rectangle that
    changed since the previous frame, every frame kept (none merged) and looped forever."""

    def __init__(self, fps: float, dynamic: Any = None) -> None:
        self.duration_ms = 1000.0 / fps
        #: the one axes that changes between frames: the rest of the figure is drawn once
        self.dynamic = dynamic
        self._background: Any = None
        self.frames = 0
        self._fp: Any = None
        self._prev: Any = None
        self._shown_cs = 0.0  # centiseconds written so far (GIF delays are whole centiseconds)

    def saving(self, fig: Any, path: Path, dpi: float) -> Any:
        from contextlib import contextmanager

        @contextmanager
        def ctx():
            self.fig, self.dpi = fig, dpi
            fig.set_dpi(dpi)
            with open(path, "wb") as self._fp:
                yield self
                self._fp.write(b";")  # trailer
            self._fp = None

        return ctx()

    def _delay_cs(self) -> int:
        """This frame's delay in centiseconds, rounded so the total stays on the requested rate."""
        target = (self.frames + 1) * self.duration_ms / 10.0
        delay = max(2, round(target - self._shown_cs))  # viewers slow delays < 2 cs down to 10
        self._shown_cs += delay
        return delay

    def _draw(self) -> None:
        canvas = self.fig.canvas
        if self.dynamic is None:
            canvas.draw()
            return
        if self._background is None:
            self.dynamic.set_visible(False)
            canvas.draw()
            self._background = canvas.copy_from_bbox(self.fig.bbox)
            self.dynamic.set_visible(True)
        canvas.restore_region(self._background)
        self.fig.draw_artist(self.dynamic)

    def grab_frame(self) -> None:
        from PIL import GifImagePlugin, Image, ImageChops

        self._draw()
        rgb = Image.frombuffer("RGBA", self.fig.canvas.get_width_height(physical=True),
                               self.fig.canvas.buffer_rgba(), "raw", "RGBA", 0, 1).convert("RGB")
        delay = self._delay_cs() * 10
        if self._prev is None:
            im = rgb.quantize(256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
            header, _ = GifImagePlugin.getheader(im, info={"loop": 0, "duration": delay})
            for chunk in header:
                self._fp.write(chunk)
            chunks = GifImagePlugin.getdata(im, (0, 0), duration=delay)
        else:
            bbox = ImageChops.difference(rgb, self._prev).getbbox() or (0, 0, 1, 1)  # never merge frames
            part = rgb.crop(bbox).quantize(256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
            chunks = GifImagePlugin.getdata(part, bbox[:2], duration=delay, include_color_table=True)
        for chunk in chunks:
            self._fp.write(chunk)
        self._prev = rgb
        self.frames += 1


# ---- the frames -----------------------------------------------------------------------------------
def _scene(ax: Any, d: rec.RecordedDecision, class_colours: dict[str, str], ego_colour: str) -> None:
    """Every road user's true box by class, its predicted mean path and its 1-sigma (filled) and
    2-sigma (dashed) ellipses each second, and the ego: a few collections, drawn fast."""
    from matplotlib.collections import LineCollection, PolyCollection

    from sumo_ethics.types import RoadUserClass

    a = d.agents
    colours = [class_colours[RoadUserClass(int(c)).label] for c in a[:, 6]]
    if len(a):
        ax.add_collection(PolyCollection(OrientedBoxes(a[:, 0], a[:, 1], a[:, 2], a[:, 4], a[:, 5]).corners(),  # type: ignore[arg-type]  # stub: a Sequence; set_verts takes an (N, M, 2) array (its fast path)
                                         facecolors=colours, edgecolors="black", linewidths=0.6, zorder=5))
        small = np.isin(a[:, 6], (int(RoadUserClass.PEDESTRIAN), int(RoadUserClass.BICYCLE)))
        if small.any():  # pedestrians and cyclists ringed, as in explain: a 0.5 m box is a dot at 80 m
            ax.scatter(a[small, 0], a[small, 1], s=90, facecolors="none",
                       edgecolors=[c for c, k in zip(colours, small) if k], linewidths=1.4, zorder=5.1)
    n = min(len(a), d.pred_mean.shape[0])
    if n and d.pred_mean.shape[1]:
        paths = np.concatenate([a[:n, None, :2], d.pred_mean[:n]], axis=1)
        ax.add_collection(LineCollection(list(paths), colors=colours[:n], linewidths=1.2, zorder=4))
        ts = d.whole_seconds()
        if len(ts):
            m = d.pred_mean[:n, ts].reshape(-1, 2)
            cov = d.pred_cov[:n, ts].reshape(-1, 2, 2)
            ec = [c for c in colours[:n] for _ in ts]
            ax.add_collection(PolyCollection(list(ellipses(m, cov, 1.0)), facecolors=ec, edgecolors="none",
                                             alpha=0.22, zorder=3))
            ax.add_collection(LineCollection(list(ellipses(m, cov, 2.0)), colors=ec, linewidths=0.6, alpha=0.5,
                                             linestyles="--", zorder=3))
    e = d.ego
    ax.add_collection(PolyCollection(OrientedBoxes(e[0:1], e[1:2], e[2:3], e[4:5], e[5:6]).corners(),  # type: ignore[arg-type]  # stub: a Sequence; set_verts takes an (N, M, 2) array (its fast path)
                                     facecolors=ego_colour, edgecolors="white", linewidths=1.0, zorder=6))


def _scan(run: Path, steps: list[int], ego: str | None = None) -> tuple[np.ndarray, np.ndarray, set[int], set[int], float]:
    """One cheap pass over the recorded steps (only the small arrays): the ego's centres (S, 2)
    [m], the planning times (S,) [s], the road-user classes and validity classes seen, the step
    length [s]."""
    xy, times = np.zeros((len(steps), 2)), np.zeros(len(steps))
    classes: set[int] = set()
    validity: set[int] = set()
    dt = 0.1
    from sumo_ethics.analysis.recorded import readable

    for i, s in enumerate(steps):
        with readable(run, s, ego), np.load(rec.step_path(run, s, ego), allow_pickle=False) as z:
            xy[i] = z["ego"][:2]
            classes.update(int(c) for c in np.unique(z["agents"][:, 6]))
            validity.update(int(v) for v in np.unique(z["validity"]))
            times[i], dt = float(z["meta"][1]), float(z["meta"][3])
    return xy, times, classes, validity, dt


def _total_steps(run: Path, ego: str | None = None) -> int:
    """The steps.parquet rows of the run (of fleet ego ``ego``)."""
    from sumo_ethics.record.reader import read_table

    try:
        t = read_table(run, "steps")
    except ConfigError:
        return 0
    if ego is None or "ego_id" not in t.column_names:
        return t.num_rows
    return sum(k == ego for k in t.column("ego_id").to_pylist())


def _collisions(run: Path, ego: str | None = None) -> dict[int, str]:
    """The run's booked ego collisions (those of fleet ego ``ego``): step -> a line naming the
    other party and the harm booked."""
    from sumo_ethics.analysis.recorded import other_party, party_label
    from sumo_ethics.collision import is_booked
    from sumo_ethics.record.reader import read_table

    try:
        rows = read_table(run, "collisions").to_pylist()
    except ConfigError:
        return {}
    marks: dict[int, list[str]] = {}
    for r in rows:
        if not is_booked(r):
            continue
        if ego is None:
            line = (f"COLLISION at t = {r['time']:.1f} s: ego and {party_label(r, 'b')}\n"
                    f"harm P(MAIS 3+): ego {r['harm_ego']:.3f}, third party {r['harm_third_party']:.3f}")
        elif ego in (r["id_a"], r["id_b"]):
            q = other_party(r, ego)
            p = "a" if q == "b" else "b"
            line = (f"COLLISION at t = {r['time']:.1f} s: ego '{ego}' and {party_label(r, q)}\n"
                    f"harm P(MAIS 3+): '{ego}' {r[f'harm_{p}']:.3f}, '{r[f'id_{q}']}' {r[f'harm_{q}']:.3f}")
        else:
            continue
        marks.setdefault(int(r["step"]), []).append(line)
    return {k: "\n".join(v) for k, v in marks.items()}




def _progress(enabled: bool, total: int) -> Any:
    if not enabled:
        return None
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    prog = Progress(TextColumn("[bold]replay"), BarColumn(), MofNCompleteColumn(), TextColumn("frames"),
                    TimeRemainingColumn(), transient=True)
    if not prog.console.is_terminal:
        return None
    task = prog.add_task("frames", total=total)
    prog.start()
    return prog, task


def check_out(out: Path) -> None:
    """ConfigError unless ``out`` ends in .mp4 or .gif."""
    if Path(out).suffix.lower() not in SUFFIXES:
        raise ConfigError(f"--out {out}: a replay is written as .mp4 or .gif, not "
                          f"{Path(out).suffix or 'a name without suffix'}")


def _check(out: Path, every: int, fps: float | None, half: float) -> None:
    check_out(out)
    if every < 1:
        raise ConfigError(f"--every {every}: must be a whole number of at least 1")
    if fps is not None and not (0 < fps <= 50):  # a GIF's delays are whole centiseconds, at least 2
        raise ConfigError(f"--fps {fps:g}: must be above 0 and at most 50 frames per second")
    if not half > 0:
        raise ConfigError(f"half-width {half:g} m of the view must be positive")


def replay(run: Path, out: Path, every: int = 1, fps: float | None = None, half: float = 40.0,
           progress: bool = True, ego: str | None = None) -> ReplayResult:
    """Animate the recorded decisions of ``run`` (every ``every``-th, and the step of every ego
    collision) to ``out`` (.mp4 or .gif); of ``ego``, required in a fleet run with per-ego decisions
    (:func:`sumo_ethics.analysis.recorded.decisions_of`).

    ``fps`` defaults to real time, 1 / (dt x every), capped at 10 for a GIF and 30 for an MP4.
    ConfigError for a bad suffix or value and for a run without recorded decisions (naming the
    flag). Without ffmpeg an .mp4 request writes the .gif of the same name instead (see the notes)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import animation
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    from sumo_ethics.analysis.drawing import CLASS_COLOURS, EGO_COLOUR, VALIDITY_COLOURS, VALIDITY_LABELS, fmt, draw_road
    from sumo_ethics.analysis.recorded import decisions_of, load_checked, record_mode, recorded, road_of
    from sumo_ethics.types import RoadUserClass

    run, out = Path(run), Path(out)
    _check(out, every, fps, half)
    ego = decisions_of(run, ego)
    all_steps = recorded(run, ego)
    crashes = _collisions(run, ego)
    steps = sorted(set(all_steps[::every]) | (set(crashes) & set(all_steps)))  # every collision is shown
    notes: list[str] = []

    total = _total_steps(run, ego)
    if total and len(all_steps) < total:
        if record_mode(run) == "all":
            notes.append(f"{len(all_steps)} of {total} steps have a decision (the others had no planner "
                         f"decision, e.g. emergency braking)")
        else:
            notes.append(f"{len(all_steps)} of {total} steps recorded; run with --record-decisions all "
                         f"for every step")

    writer_name = "gif"
    if out.suffix.lower() == ".mp4":
        if animation.writers.is_available("ffmpeg"):
            writer_name = "ffmpeg"
        else:
            gif = out.with_suffix(".gif")
            notes.append(f"ffmpeg not found: wrote {gif} instead of {out} (install ffmpeg for MP4)"
                         + (f"; it replaced the {gif.name} that was there" if gif.exists() else ""))
            out = gif

    ego_xy, times, classes, validity, dt = _scan(run, steps, ego)
    real = 1.0 / (dt * every)
    if fps is None:
        fps = min(real, GIF_FPS_CAP if writer_name == "gif" else MP4_FPS_CAP)
    speed = fps / real
    gaps = len(steps) > 1 and bool(np.any(np.diff(steps) > every))
    playback = (f"{len(steps)} frame{'s' if len(steps) != 1 else ''} at {fps:.3g} frames/s, "
                f"{len(steps) / fps:.1f} s of playback for t = {times[0]:.1f} to {times[-1]:.1f} s of the run ("
                + (f"{_speed(speed)} between recorded steps; the steps not recorded are skipped)" if gaps
                   else f"{_speed(speed)})"))

    # the figure: road drawn once (the part the ego's views can reach), the view pans
    fig = plt.figure(figsize=FIGSIZE, dpi=DPI)
    ax = fig.add_axes((0.09, 0.09, 0.6, 0.8))
    road = road_of(run)
    if road is not None:
        lo, hi = ego_xy.min(axis=0) - half, ego_xy.max(axis=0) + half
        draw_road(ax, road.window(lo[0], lo[1], hi[0], hi[1]))
    else:
        notes.append(f"the road is not drawn: the SUMO network of {run / 'config.json'}'s scenario was not found")
    ax.set_aspect("equal", adjustable="box")
    ax.set_facecolor("#f7f7f2")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    trail, = ax.plot([], [], color=EGO_COLOUR, lw=1.0, ls=":", zorder=1.5)
    handles = [Patch(fc=EGO_COLOUR, label="ego"), Line2D([], [], color=EGO_COLOUR, lw=1, ls=":", label="ego's trail")]
    handles += [Patch(fc=CLASS_COLOURS[RoadUserClass(c).label], ec="black", lw=0.6, label=RoadUserClass(c).label)
                for c in sorted(classes)]
    handles += [Line2D([], [], color="0.4", lw=1.2, label="predicted mean path"),
                Patch(fc="0.5", alpha=0.3, ec="0.4", ls="--", label="predicted 1 sigma\n(2 sigma dashed), each s"),
                Line2D([], [], color="black", lw=2.5, label="chosen trajectory")]
    handles += [Line2D([], [], color=VALIDITY_COLOURS[v], lw=1.5, alpha=0.6, label=f"candidate: {VALIDITY_LABELS[v]}")
                for v in sorted(validity)]
    fig.legend(handles=handles, loc="center left", bbox_to_anchor=(0.71, 0.5), fontsize=8, frameon=False)
    who = "" if ego is None else f" · ego '{ego}'"
    fig.text(0.99, 0.01, f"{run.name}{who} · {len(steps)} frames · playback {_speed(speed)}", ha="right",
             va="bottom", fontsize=7.5, color="0.35")
    static = set(ax.get_children())

    from matplotlib.collections import LineCollection

    out.parent.mkdir(parents=True, exist_ok=True)
    # codec h264 gets -pix_fmt yuv420p from matplotlib: plays in browsers and QuickTime (yuv444p would not)
    writer = GifStream(fps, dynamic=ax) if writer_name == "gif" else animation.FFMpegWriter(fps=fps, codec="h264")  # type: ignore[arg-type]  # stub: int; ffmpeg takes any rate
    bar = _progress(progress, len(steps))
    try:
        # the temporary name keeps the suffix: the writer picks the format by it
        with fileio.replacing(out, f".{out.stem}.part{out.suffix}") as tmp, writer.saving(fig, tmp, DPI):
            for i, s in enumerate(steps):
                d = load_checked(run, s, ego)
                ex, ey = float(d.ego[0]), float(d.ego[1])
                _scene(ax, d, CLASS_COLOURS, EGO_COLOUR)
                if d.n_candidates:
                    start = np.broadcast_to(d.ego[:2], (d.n_candidates, 1, 2))
                    paths = np.concatenate([start, d.cand_xy], axis=1)
                    colours = [VALIDITY_COLOURS[int(v)] for v in d.validity]
                    ax.add_collection(LineCollection(list(paths), colors=colours, linewidths=0.5, alpha=0.25,
                                                     zorder=2))
                    p = paths[d.chosen]
                    ax.plot(p[:, 0], p[:, 1], color="white", lw=4.0, zorder=5.5, solid_capstyle="round")
                    ax.plot(p[:, 0], p[:, 1], color="black", lw=2.0, zorder=5.6, solid_capstyle="round")
                    choice = (f"chose candidate {d.chosen} of {d.n_candidates}: "
                              f"{VALIDITY_LABELS[int(d.validity[d.chosen])]}, J_risk {fmt(float(d.j_risk[d.chosen]))}")
                else:
                    choice = "no candidates"
                if s in crashes:
                    ax.text(0.5, 0.98, crashes[s], transform=ax.transAxes, ha="center", va="top", fontsize=8,
                            color="white", weight="bold", zorder=10,
                            bbox={"boxstyle": "round", "fc": "#d62728", "ec": "none"})
                trail.set_data(ego_xy[: i + 1, 0], ego_xy[: i + 1, 1])
                ax.set_xlim(ex - half, ex + half)
                ax.set_ylim(ey - half, ey + half)
                ax.set_title(f"t = {d.time:.1f} s (step {d.step}) · ego{'' if ego is None else f' {ego!r}'} {d.ego[3]:.1f} m/s "
                             f"({d.ego[3] * 3.6:.0f} km/h)\n{choice}", fontsize=9.5)
                writer.grab_frame()
                for artist in ax.get_children():
                    if artist not in static:
                        artist.remove()
                if bar is not None:
                    bar[0].advance(bar[1])
    finally:
        if bar is not None:
            bar[0].stop()
        plt.close(fig)
    return ReplayResult(out, len(steps), writer_name, float(fps), float(speed), len(all_steps), total, tuple(notes),
                        playback)


def _speed(speed: float) -> str:
    if math.isclose(speed, 1.0, rel_tol=1e-3):
        return "real time"
    return f"{speed:.3g}x real time"
