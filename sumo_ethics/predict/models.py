"""CS-LSTM, the paper's attention variant and the map-aware one, the bivariate Gaussian NLL, weight files.

All models share one interface::

    model(tgt_hist, tgt_group, nbr_hist, nbr_group, nbr_batch, nbr_cell, nbr_valid=None,
          map_pts=None, map_valid=None, map_scalar=None)
        -> (B, FUT_STEPS, 5) = (mu_x, mu_y, sigma_x, sigma_y, rho)

(the map inputs are read by kind "map" only; see ``features.map_features``: map_pts are
normalised like the histories, by the target's position scale).

Inputs are in the target's frame and NORMALISED: positions divided by
``model.scale(tgt_group)`` (per target group, see ``features.POS_SCALE``); outputs are
in the same normalised units (multiply mu and sigma by the scale for metres).
Neighbours come packed: row p of ``nbr_*`` belongs to target ``nbr_batch[p]`` and sits in
social-grid cell ``nbr_cell[p]`` (lon * 3 + lat); ``nbr_valid[p] = False`` removes it
entirely (a padded neighbour changes nothing).

Sizes follow Deo & Trivedi / METHOD.md section 4 (docs/prediction.md): Linear(2->32) input embedding (plus a
32-d embedding of the agent class group, added), shared LSTM encoder 64, dynamics
embedding 32, 13 x 3 social grid, Conv 3x3 (64) -> Conv 3x1 (16) -> MaxPool(2,1) = 80,
decoder LSTM ``dec`` (128; 64 for the map kinds, :func:`default_options`), a linear output of
5 per future step and mode. No manoeuvre classes.
Residual decoding (residual=True, the default, for ``residual_groups``: vehicles and cyclists):
mu = constant-velocity rollout of the target's last observed displacement + the decoder's
output, so an untrained decoder already predicts constant velocity and training learns the
corrections. Pedestrians decode absolute positions (their stop-and-go made the residual form
worse: docs/prediction.md, "Options of the default").
sigma = softplus(.) + sigma_min (normalised units; 0.01 = 10 cm for vehicles, 2 cm for
pedestrians), rho = 0.95 tanh(.): SUMO's exactly-standing agents would otherwise drive
sigma to zero and make the NLL explode on the first one that starts moving.

Attention (kind="attention"): X = the target's encoder state, H_i = the neighbours'
encoder states. The paper's ``A_i = cos(X,H_i) / sum_j cos(X,H_j)`` is undefined when the
cosines sum to ~0 and gives negative weights; we use the guarded form
``A = softmax_i(cos(X, H_i) / tau)`` over valid neighbours, tau a learned temperature
(clamped to >= 0.01, initialised at 0.1). ``W_H = sum_i A_i H_i`` (0 without neighbours),
projected 64 -> 80 without bias and added to the pooled grid: ``E = cs_pool + P W_H``;
``[E, dyn]`` goes to the decoder, as in CS-LSTM.

Map (kind="map", the planner's default): the attention model plus a lane context. Each of the MAP_LANES polylines
(MAP_POINTS x 2 points, flattened, with a one-hot of its row kind: ahead / left / right) is
encoded by a 2-layer MLP (-> 64); the query is a linear map of [target encoding, map
scalars]; scaled dot-product attention over the valid polylines (none valid: zero) gives a
64-d context, concatenated with a 32-d embedding of the scalars (traffic light ahead, its
distance and state, speed limit): ``[E, dyn, lane context, scalars]`` goes to the decoder.
Map CS-LSTM (kind="map_cslstm"): the same lane context on CS-LSTM without the attention,
the counterpart of "map" in the attention ablation.

Modes (``modes`` = M > 1, the shipped "map" and "map_cslstm" have M = 3): the output layer gives M
Gaussians per step and a linear head on the decoder's input gives M mode probabilities
(log-softmax). ``model(...)`` returns the most likely mode, ``model(..., all_modes=True)``
((B, M, FUT_STEPS, 5), (B, M) log weights); every mode is residual to constant velocity.
Trained with the winner-takes-all MSE of the closest mode (+ cross-entropy of the weights)
as warm-up, then the mixture NLL of whole trajectories (:func:`mixture_nll`). A standing car
can then be "stays" and "pulls away" at once instead of one Gaussian averaging the two.
Options (``default_options``; the shipped map and map_cslstm have the last two): ``cv_mode``, the last
mode's mean is the constant-velocity rollout itself (a standing agent stays), only its spread and
weight learned (for the groups decoded in absolute positions, pedestrians, it is "stands
still"); ``single_mode_groups``, class groups (pedestrians) that get mode 0 with weight 1 and
the others weight 0; ``stay_mode_groups``, class groups that get mode 0 and a last mode that
stays exactly where the agent is now (mean 0, spread ``sigma_min``, no correlation), both
weights learned, the others weight 0 (one Gaussian averages a standing pedestrian's "stays" and
"walks off"; with a learned spread the stay mode grew wide enough to cover the walkers and mode
0 collapsed onto the standing ones); ``stay_speed`` [m/s], the stay mode only for those slower
than it over the last 0.2 s of history, the faster ones get mode 0 alone (weight 1);
``dec``, the decoder's size (64 instead of 128); ``dec_steps``, the decoder's steps (default
``fut_steps``, one per output step; with fewer, each decoder step emits ``fut_steps // dec_steps``
consecutive output steps through its own rows of the output layer, e.g. 5 decoder steps of
0.8 s instead of 20; its cost: docs/prediction.md, "The shipped weight files"). An earlier default
(models/superseded/map_cslstm_v3.pt) had ``cv_mode`` too; the selection rule of docs/predictor_seeds.md
chose the file without it.

Neighbour encoding (``nbr_frame``). "target" (cslstm, attention, the first map model map_v1): each
neighbour's history is encoded in its target's frame, once per (target, neighbour) pair, as
CS-LSTM does (up to M (M - 1) encodings for M agents). "agent" (the shipped map and map_cslstm): every agent's
history is encoded once in its own frame (origin now, +x its heading, normalised by its own
class scale) and placed into a target's grid with its pose there, ``act(H + W_pose [x, y,
cos dyaw, sin dyaw])`` (x, y by the target's scale). Training still feeds per-pair rows and
converts them (``agent_inputs``, needs ``nbr_yaw``); the run-time ``scene_forward`` encodes
the M agents once and gives the same result (tests/predict/test_predictor_fast.py).

The cslstm/attention parameters are built exactly as before (same names, same order), so
their shipped files and seeded initialisations are unchanged. Weight files of the map kinds
carry ``map_version``, the map features they were trained with (features.MAP_VERSIONS: 1
without pedestrian map context, 2 with it, 3 with the time the light's state holds as an 8th
scalar, 4 with the blinkers as 9th and 10th scalars and the pedestrian's lane after a walking area;
``TrajectoryLSTM.map_version``), and are refused with any other.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as Fn
from torch import nn

from sumo_ethics import fileio
from sumo_ethics.predict import PredictorError
from sumo_ethics.predict import features as F

KINDS = ("cslstm", "attention", "map", "map_cslstm")
#: kinds that read the map features (features.map_features) besides the histories
MAP_KINDS = ("map", "map_cslstm")
#: kinds with the cosine attention over the neighbours (the others pool the social grid only)
ATTENTION_KINDS = ("attention", "map")
#: how neighbour histories are encoded: "target" = in each target's frame (once per target and
#: neighbour pair, as CS-LSTM), "agent" = once per agent in its own frame, placed by its pose
NBR_FRAMES = ("target", "agent")


def default_nbr_frame(kind: str) -> str:
    """The neighbour encoding a new model of ``kind`` gets: that of its shipped file ("agent" for
    the map-aware kinds, "target" for the others, kept as they were for the ablation; the first
    map file, models/superseded/map_v1.pt, had "target")."""
    return "agent" if kind in MAP_KINDS else "target"


def default_modes(kind: str) -> int:
    """The number of trajectory modes a new model of ``kind`` gets: that of its shipped file (3 for
    the map-aware kinds, whose single-Gaussian versions averaged "stays" and "pulls away"; 1 for
    the others, kept as they were for the ablation)."""
    return 3 if kind in MAP_KINDS else 1


def default_options(kind: str, modes: int) -> dict[str, Any]:
    """Decoder size, constant-velocity mode and one-mode class groups of a new model of ``kind``
    with ``modes`` modes: those of its shipped file (the map-aware kinds: a 64-state decoder, no
    constant-velocity mode, pedestrians with one mode; the others as they were, for the
    ablation). The mode options need modes > 1."""
    residual = (F.GROUP_VEHICLE, F.GROUP_CYCLIST)
    if kind not in MAP_KINDS:
        return {"dec": 128, "cv_mode": False, "single_mode_groups": (), "stay_mode_groups": (),
                "residual_groups": residual}
    multi = modes > 1
    return {"dec": 64, "cv_mode": False, "single_mode_groups": (F.GROUP_PEDESTRIAN,) if multi else (),
            "stay_mode_groups": (), "residual_groups": residual}


def lstm_recurrence(pre: torch.Tensor, w_hh: torch.Tensor, steps: int) -> torch.Tensor:
    """(B, 4 n) input projection (with both biases), (n, 4 n) recurrent weights transposed ->
    (B, steps, n) hidden states of an LSTM fed the same input every step from zero states (gate
    rows as nn.LSTM's: input, forget, cell, output). Inference only: every operation writes into
    buffers allocated once (the same arithmetic as allocating per step; the timing:
    docs/predictor_latency.md, "The decoder's recurrence into preallocated buffers")."""
    n, b = w_hh.shape[0], pre.shape[0]
    out = pre.new_empty(b, steps, n)
    gates, sg = pre.new_empty(b, 4 * n), pre.new_empty(b, 4 * n)
    cell_in, tmp = pre.new_empty(b, n), pre.new_empty(b, n)
    c, h = pre.new_zeros(b, n), pre.new_zeros(b, n)
    in_gate, forget_gate, out_gate, cell_rows = sg[:, :n], sg[:, n:2 * n], sg[:, 3 * n:], gates[:, 2 * n:3 * n]
    for k in range(steps):
        torch.addmm(pre, h, w_hh, out=gates)
        torch.sigmoid(gates, out=sg)  # one call for the three sigmoid gates (the cell rows unused)
        torch.tanh(cell_rows, out=cell_in)
        torch.mul(forget_gate, c, out=c)  # c = f * c + i * tanh(g)
        torch.mul(in_gate, cell_in, out=tmp)
        c.add_(tmp)
        torch.tanh(c, out=tmp)
        h = out[:, k]
        torch.mul(out_gate, tmp, out=h)  # h = o * tanh(c), written straight into the output
    return out


FILE_FORMAT = "sumo-ethics-predictor"
FILE_FORMAT_VERSION = 1


class TrajectoryLSTM(nn.Module):
    """CS-LSTM (kind="cslstm"), + cosine attention ("attention"), + lanes ("map_cslstm", "map")."""

    # the buffers (register_buffer in __init__), typed here: nn.Module's __getattr__ gives Tensor | Module
    pos_scale: torch.Tensor
    residual_mask: torch.Tensor
    single_mode_mask: torch.Tensor
    one_mode_log_w: torch.Tensor
    stay_mode_mask: torch.Tensor
    stay_barred: torch.Tensor
    stay_params: torch.Tensor

    def __init__(
        self,
        kind: str = "attention",
        hist_steps: int = F.HIST_STEPS,
        fut_steps: int = F.FUT_STEPS,
        in_emb: int = 32,
        enc: int = 64,
        dyn: int = 32,
        dec: int = 128,
        conv1: int = 64,
        conv2: int = 16,
        n_groups: int = F.N_GROUPS,
        pos_scale: tuple[float, ...] = tuple(F.POS_SCALE),
        sigma_min: float = 0.01,
        residual: bool = True,
        residual_groups: tuple[int, ...] = (F.GROUP_VEHICLE, F.GROUP_CYCLIST),
        map_size: int = 64,
        nbr_frame: str = "target",
        modes: int = 1,
        cv_mode: bool = False,
        single_mode_groups: tuple[int, ...] = (),
        stay_mode_groups: tuple[int, ...] = (),
        map_version: int = F.MAP_VERSION,
        dec_steps: int | None = None,
        stay_speed: float | None = None,
    ) -> None:
        super().__init__()
        if kind not in KINDS:
            raise ValueError(f"unknown model kind {kind!r}, expected one of {KINDS}")
        if nbr_frame not in NBR_FRAMES:
            raise ValueError(f"unknown nbr_frame {nbr_frame!r}, expected one of {NBR_FRAMES}")
        if not (isinstance(modes, int) and 1 <= modes <= 8):
            raise ValueError(f"modes must be an integer from 1 to 8, got {modes!r}")
        if (cv_mode or single_mode_groups or stay_mode_groups) and modes < 2:
            raise ValueError("cv_mode, single_mode_groups and stay_mode_groups need modes >= 2")
        dec_steps = fut_steps if dec_steps is None else dec_steps
        if not (isinstance(dec_steps, int) and 1 <= dec_steps <= fut_steps and fut_steps % dec_steps == 0):
            raise ValueError(f"dec_steps must divide the {fut_steps} output steps, got {dec_steps!r}")
        if stay_speed is not None and not (stay_mode_groups and float(stay_speed) > 0):
            raise ValueError(f"stay_speed needs stay_mode_groups and a positive speed, got {stay_speed!r}")
        if set(single_mode_groups) & set(stay_mode_groups):
            raise ValueError("a class group cannot be in both single_mode_groups and stay_mode_groups")
        if cv_mode and not residual:
            raise ValueError("cv_mode needs residual decoding (its mean is the constant-velocity rollout)")
        self.kind = kind
        #: map features the model reads (features.map_features' version: the dataset's it is
        #: trained on, read back from its weights file); it sets the number of map scalars
        self.map_version = int(map_version)
        self.n_scalars = F.map_scalars(self.map_version)
        self.nbr_frame = nbr_frame
        self.modes = modes
        self.cv_mode = bool(cv_mode)
        self.single_mode_groups = tuple(int(g) for g in single_mode_groups)
        single = torch.zeros(n_groups, dtype=torch.bool)
        single[list(self.single_mode_groups)] = True
        self.register_buffer("single_mode_mask", single, persistent=False)
        one_mode = torch.full((modes,), -math.inf)  # log weights: mode 0 sure, the others impossible
        one_mode[0] = 0.0
        self.register_buffer("one_mode_log_w", one_mode, persistent=False)
        self.stay_mode_groups = tuple(int(g) for g in stay_mode_groups)
        stay = torch.zeros(n_groups, dtype=torch.bool)
        stay[list(self.stay_mode_groups)] = True
        self.register_buffer("stay_mode_mask", stay, persistent=False)
        barred = torch.ones(modes, dtype=torch.bool)  # modes a stay group may not have: all but the first and last
        barred[[0, -1]] = False
        self.register_buffer("stay_barred", barred, persistent=False)
        stay_params = torch.tensor([0.0, 0.0, float(sigma_min), float(sigma_min), 0.0])  # mean 0, sigma_min, rho 0
        self.register_buffer("stay_params", stay_params, persistent=False)
        #: [m/s] a stay group's target at least this fast over the last 0.2 s has no stay mode (None: all have it)
        self.stay_speed = None if stay_speed is None else float(stay_speed)
        self.sigma_min = float(sigma_min)
        self.residual = bool(residual)
        self.residual_groups = tuple(int(g) for g in residual_groups) if residual else ()
        mask = torch.zeros(n_groups)
        mask[list(self.residual_groups)] = 1.0
        self.register_buffer("residual_mask", mask, persistent=False)
        self.hist_steps, self.fut_steps = hist_steps, fut_steps
        #: decoder steps; each emits fut_steps // dec_steps consecutive output steps
        self.dec_steps = dec_steps
        self.enc_size = enc
        self.input_emb = nn.Linear(2, in_emb)
        self.class_emb = nn.Embedding(n_groups, in_emb)
        self.encoder = nn.LSTM(in_emb, enc, batch_first=True)
        self.dyn_emb = nn.Linear(enc, dyn)
        self.soc_conv = nn.Conv2d(enc, conv1, 3)
        self.conv_3x1 = nn.Conv2d(conv1, conv2, (3, 1))
        self.soc_maxpool = nn.MaxPool2d((2, 1), padding=(1, 0))
        self.soc_size = ((F.GRID_LON - 4) + 1) // 2 * conv2
        if kind in ATTENTION_KINDS:
            self.att_proj = nn.Linear(enc, self.soc_size, bias=False)
            self.log_tau = nn.Parameter(torch.tensor(math.log(0.1)))
        self.map_size = 0
        if kind in MAP_KINDS:
            # lane polylines: flattened points + kind one-hot -> 64; query from the target's
            # encoding and its signal/speed-limit scalars; scaled dot-product attention
            self.poly_enc = nn.Sequential(nn.Linear(F.MAP_POINTS * 2 + 3, map_size), nn.LeakyReLU(0.1),
                                          nn.Linear(map_size, map_size))
            self.map_query = nn.Linear(enc + self.n_scalars, map_size)
            self.scalar_emb = nn.Linear(self.n_scalars, 32)
            self.map_size = map_size + 32
        self.decoder = nn.LSTM(self.soc_size + dyn + self.map_size, dec, batch_first=True)
        chunk = fut_steps // dec_steps  # output steps per decoder step (1: the original layout)
        self.output = nn.Linear(dec, 5 * modes * chunk)
        if self.residual:  # start exactly at constant velocity (mode 0; the other modes start
            with torch.no_grad():  # near it, their random output weights break the symmetry)
                mu0 = (torch.arange(chunk)[:, None] * 5 * modes + torch.arange(2)).flatten()  # mode 0's means
                self.output.weight[mu0] = 0.0
                self.output.bias[mu0] = 0.0
        if modes > 1:  # mode probabilities from the decoder's input
            self.mode_head = nn.Linear(self.soc_size + dyn + self.map_size, modes)
        self.act = nn.LeakyReLU(0.1)
        self.register_buffer("pos_scale", torch.tensor(pos_scale, dtype=torch.float32))
        if nbr_frame == "agent":  # neighbour pose in the target's frame (x, y normalised, cos, sin of yaw)
            self.pose_emb = nn.Linear(4, enc)

    @property
    def dec_size(self) -> int:
        """States of the decoder LSTM."""
        return self.decoder.hidden_size

    def scale(self, group: torch.Tensor) -> torch.Tensor:
        """(B,) class groups -> (B,) position scale [m]."""
        return self.pos_scale[group]

    def encode(self, seq: torch.Tensor, group: torch.Tensor) -> torch.Tensor:
        """(S, H, 2), (S,) -> (S, enc) final encoder hidden state."""
        emb = self.act(self.input_emb(seq) + self.class_emb(group)[:, None, :])
        _, (h, _) = self.encoder(emb)
        return h[0]

    def forward(
        self,
        tgt_hist: torch.Tensor,
        tgt_group: torch.Tensor,
        nbr_hist: torch.Tensor,
        nbr_group: torch.Tensor,
        nbr_batch: torch.Tensor,
        nbr_cell: torch.Tensor,
        nbr_valid: torch.Tensor | None = None,
        map_pts: torch.Tensor | None = None,
        map_valid: torch.Tensor | None = None,
        map_scalar: torch.Tensor | None = None,
        nbr_yaw: torch.Tensor | None = None,
        all_modes: bool = False,
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        b = tgt_hist.shape[0]
        if self.nbr_frame == "agent":
            if nbr_yaw is None:
                raise ValueError("a model with nbr_frame='agent' needs nbr_yaw (samples built before it: "
                                 "dataset.rebuild_samples)")
            own, pose = self.agent_inputs(tgt_group, nbr_hist, nbr_group, nbr_batch, nbr_yaw)
            hidden = self.encode(torch.cat([tgt_hist, own]), torch.cat([tgt_group, nbr_group]))
            tgt_enc, nbr_enc = hidden[:b], self.place(hidden[b:], pose)
        else:
            hidden = self.encode(torch.cat([tgt_hist, nbr_hist]), torch.cat([tgt_group, nbr_group]))
            tgt_enc, nbr_enc = hidden[:b], hidden[b:]
        return self.head(tgt_hist, tgt_group, tgt_enc, nbr_enc, nbr_batch, nbr_cell, nbr_valid,
                         map_pts, map_valid, map_scalar, all_modes)

    def scene_forward(
        self,
        agent_hist: torch.Tensor,
        agent_group: torch.Tensor,
        targets: torch.Tensor,
        nbr_agent: torch.Tensor,
        nbr_batch: torch.Tensor,
        nbr_cell: torch.Tensor,
        nbr_pose: torch.Tensor,
        map_pts: torch.Tensor | None = None,
        map_valid: torch.Tensor | None = None,
        map_scalar: torch.Tensor | None = None,
        all_modes: bool = False,
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Run-time path of ``nbr_frame="agent"`` models: every agent encoded once.

        agent_hist (M, H, 2): each agent's history in its own frame, normalised by its own
        group's scale; agent_group (M,); targets (B,) agent rows predicted; nbr_agent (P,)
        agent row of each neighbour, nbr_batch (P,) its target row (into targets), nbr_cell
        (P,); nbr_pose (P, 4): (x, y) of the neighbour in its target's frame / the target's
        scale, cos and sin of its yaw there. -> as :meth:`forward` (and equal to it)."""
        enc = self.encode(agent_hist, agent_group)
        nbr_enc = self.place(enc[nbr_agent], nbr_pose)
        return self.head(agent_hist[targets], agent_group[targets], enc[targets], nbr_enc, nbr_batch, nbr_cell,
                         None, map_pts, map_valid, map_scalar, all_modes)

    def agent_inputs(self, tgt_group: torch.Tensor, nbr_hist: torch.Tensor, nbr_group: torch.Tensor,
                     nbr_batch: torch.Tensor, nbr_yaw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Target-frame neighbour rows -> (P, H, 2) histories in their own frames (normalised by
        their own scale) and (P, 4) poses (x, y normalised by the target's scale, cos, sin yaw)."""
        nh = nbr_hist * self.pos_scale[tgt_group][nbr_batch][:, None, None]  # metres, target frame
        c, s = torch.cos(nbr_yaw)[:, None], torch.sin(nbr_yaw)[:, None]
        d = nh - nh[:, -1:, :]
        own = torch.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], -1)
        own = own / self.pos_scale[nbr_group][:, None, None]
        pose = torch.cat([nbr_hist[:, -1], c, s], -1)
        return own, pose

    def place(self, enc: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
        """(P, enc) own-frame encodings + (P, 4) poses -> (P, enc) neighbour features."""
        return self.act(enc + self.pose_emb(pose))

    def head(self, tgt_hist: torch.Tensor, tgt_group: torch.Tensor, tgt_enc: torch.Tensor, nbr_enc: torch.Tensor,
             nbr_batch: torch.Tensor, nbr_cell: torch.Tensor, nbr_valid: torch.Tensor | None,
             map_pts: torch.Tensor | None, map_valid: torch.Tensor | None, map_scalar: torch.Tensor | None,
             all_modes: bool = False) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Social pooling (+ attention, + lane context) and decoding -> (B, FUT_STEPS, 5), the most
        likely mode; with ``all_modes``: ((B, M, FUT_STEPS, 5) every mode, (B, M) log weights)."""
        b = tgt_enc.shape[0]
        if nbr_valid is not None:
            keep = nbr_valid.to(torch.bool)
            nbr_enc, nbr_batch, nbr_cell = nbr_enc[keep], nbr_batch[keep], nbr_cell[keep]
        dyn = self.act(self.dyn_emb(tgt_enc))
        grid = tgt_enc.new_zeros(b * F.N_CELLS, self.enc_size)
        grid = grid.index_add(0, nbr_batch * F.N_CELLS + nbr_cell, nbr_enc)
        if self.nbr_frame == "agent" and not torch.is_grad_enabled():
            soc = self.social_fast(grid.view(b, F.N_CELLS * self.enc_size))
        else:
            grid = grid.view(b, F.GRID_LON, F.GRID_LAT, self.enc_size).permute(0, 3, 1, 2)
            soc = self.act(self.soc_conv(grid))
            soc = self.act(self.conv_3x1(soc))
            soc = self.soc_maxpool(soc).reshape(b, self.soc_size)
        if self.kind in ATTENTION_KINDS:
            soc = soc + self.att_proj(self.attend(tgt_enc, nbr_enc, nbr_batch))
        parts = [soc, dyn]
        if self.kind in MAP_KINDS:
            parts.append(self.map_context(tgt_enc, map_pts, map_valid, map_scalar))
        enc = torch.cat(parts, dim=-1)
        out = self.output(self.decode(enc))
        if self.dec_steps != self.fut_steps:  # (B, dec_steps, chunk x 5 M) -> (B, FUT_STEPS, 5 M)
            out = out.reshape(b, self.fut_steps, 5 * self.modes)
        if self.modes > 1:
            out = out.view(b, self.fut_steps, self.modes, 5).transpose(1, 2)  # (B, M, T, 5)
        mu = out[..., :2]
        if self.cv_mode:  # the last mode's mean is the constant-velocity rollout itself
            mu = torch.cat([mu[:, :-1], torch.zeros_like(mu[:, -1:])], 1)
        if self.residual:
            steps = torch.arange(1, self.fut_steps + 1, dtype=mu.dtype, device=mu.device)
            v_last = tgt_hist[:, -1] - tgt_hist[:, -2]  # displacement over the last model step
            v_last = v_last * self.residual_mask[tgt_group][:, None]
            cv = steps[None, :, None] * v_last[:, None, :]
            mu = mu + (cv[:, None] if self.modes > 1 else cv)
        sigma = Fn.softplus(out[..., 2:4]) + self.sigma_min
        rho = 0.95 * torch.tanh(out[..., 4:5])
        params = torch.cat([mu, sigma, rho], dim=-1)
        if self.stay_mode_groups:  # their last mode stays where it is, spread sigma_min, whatever the decoding
            stays = self.stay_mode_mask[tgt_group][:, None, None]
            params = torch.cat([params[:, :-1], torch.where(stays, self.stay_params, params[:, -1])[:, None]], 1)
        if self.modes == 1:
            return (params[:, None], params.new_zeros(b, 1)) if all_modes else params
        logits = self.mode_head(enc)
        if self.stay_mode_groups:  # these groups get the first and the stay mode (the others weight 0)
            logits = logits.masked_fill(self.stay_mode_mask[tgt_group][:, None] & self.stay_barred, -math.inf)
        if self.stay_speed is not None:  # ... and only while they stand: a moving one gets mode 0 alone
            step = torch.linalg.vector_norm(tgt_hist[:, -1] - tgt_hist[:, -2], dim=-1) * self.pos_scale[tgt_group]
            moving = self.stay_mode_mask[tgt_group] & (step >= self.stay_speed * F.MODEL_DT)
            logits = torch.cat([logits[:, :-1], logits[:, -1:].masked_fill(moving[:, None], -math.inf)], -1)
        log_w = torch.log_softmax(logits, -1)
        if self.single_mode_groups:  # these groups get mode 0 with weight 1 (the others weight 0)
            log_w = torch.where(self.single_mode_mask[tgt_group][:, None], self.one_mode_log_w, log_w)
        if all_modes:
            return params, log_w
        return params[torch.arange(b), log_w.argmax(-1)]

    def social_fast(self, grid: torch.Tensor) -> torch.Tensor:
        """(B, N_CELLS * enc) social grids, cell-major (lon, lat, channel) -> (B, soc_size): the two
        convolutions and the pooling as matrix products over strided windows of the grid, without
        autograd (about 2x faster than Conv2d for a few dozen targets; equal to it within float
        rounding, see tests/predict/test_predictor_fast.py)."""
        b, e = grid.shape[0], self.enc_size
        row = F.GRID_LAT * e  # one lon row of the grid: 3 cells x enc channels
        w1 = self.soc_conv.weight.permute(0, 2, 3, 1).reshape(self.soc_conv.out_channels, -1)  # (o, kh kw c)
        win = grid.unfold(1, 3 * row, row).reshape(-1, 3 * row)  # (B * 11, 3 rows)
        c1, c2 = self.soc_conv.out_channels, self.conv_3x1.out_channels
        rows1, rows2 = F.GRID_LON - 2, F.GRID_LON - 4  # output rows of the 3x3 and the 3x1 convolution
        bias1, bias2 = self.soc_conv.bias, self.conv_3x1.bias
        if bias1 is None or bias2 is None:  # both are built with one (nn.Conv2d's default)
            raise RuntimeError("the social convolutions have no bias")
        soc = self.act(torch.addmm(bias1, win, w1.t())).reshape(b, rows1 * c1)  # (B, 11 x 64)
        w2 = self.conv_3x1.weight.permute(0, 2, 3, 1).reshape(c2, -1)
        win = soc.unfold(1, 3 * c1, c1).reshape(-1, 3 * c1)  # (B * 9, 3 rows)
        soc = self.act(torch.addmm(bias2, win, w2.t())).reshape(b, rows2, c2)
        # MaxPool2d((2, 1), padding=(1, 0)) over the 9 rows: row 0 alone, then the pairs (1, 2), (3, 4), ...
        pooled = torch.cat([soc[:, :1], torch.maximum(soc[:, 1::2], soc[:, 2::2])], 1)  # (B, 5, 16)
        return pooled.transpose(1, 2).reshape(b, self.soc_size)

    def decode(self, enc: torch.Tensor) -> torch.Tensor:
        """(B, E) -> (B, dec_steps, dec) decoder states; the same input every step.

        Without autograd, ``nbr_frame="agent"`` models take the input projection once and run
        the recurrence by hand (:func:`lstm_recurrence`, equal to nn.LSTM within float rounding, see
        tests/predict/test_predictor_fast.py; its speed: docs/predictor_latency.md).
        Older models keep nn.LSTM, so their shipped outputs stay bit for bit."""
        b = enc.shape[0]
        if self.nbr_frame != "agent" or torch.is_grad_enabled():
            h_dec, _ = self.decoder(enc[:, None, :].expand(b, self.dec_steps, enc.shape[-1]))
            return h_dec
        d = self.decoder  # its parameters by name, as nn.LSTM declares no attribute for them
        pre = torch.addmm(d.get_parameter("bias_ih_l0") + d.get_parameter("bias_hh_l0"), enc,
                          d.get_parameter("weight_ih_l0").t())
        return lstm_recurrence(pre, d.get_parameter("weight_hh_l0").t(), self.dec_steps)

    def map_context(self, tgt_enc: torch.Tensor, pts: torch.Tensor | None, valid: torch.Tensor | None,
                    scalar: torch.Tensor | None) -> torch.Tensor:
        """(B, map_size): attention of the target over its lane polylines + its scalars.

        pts (B, MAP_LANES, MAP_POINTS, 2) normalised target-frame points; valid (B, MAP_LANES);
        scalar (B, n_scalars). Missing inputs (or no valid polyline) give a zero lane context."""
        b = tgt_enc.shape[0]
        if pts is None:
            pts = tgt_enc.new_zeros(b, F.MAP_LANES, F.MAP_POINTS, 2)
            valid = torch.zeros(b, F.MAP_LANES, dtype=torch.bool)
        if scalar is None:
            scalar = tgt_enc.new_zeros(b, self.n_scalars)
        if valid is None:
            raise ValueError("map_context: lane points without their valid mask")
        valid = valid.to(torch.bool)
        kind = torch.zeros(F.MAP_LANES, 3, dtype=pts.dtype)
        kind[: F.MAP_AHEAD, F.MAP_KIND_AHEAD] = 1.0
        kind[F.MAP_AHEAD, F.MAP_KIND_LEFT] = 1.0
        kind[F.MAP_AHEAD + 1, F.MAP_KIND_RIGHT] = 1.0
        x = torch.cat([pts.reshape(b, F.MAP_LANES, -1), kind.expand(b, -1, -1)], -1)
        key = self.poly_enc(x)  # (B, L, M)
        q = self.map_query(torch.cat([tgt_enc, scalar], -1))  # (B, M)
        logits = (key * q[:, None, :]).sum(-1) / math.sqrt(key.shape[-1])
        logits = logits.masked_fill(~valid, -1e9)
        a = torch.softmax(logits, -1) * valid.to(logits.dtype)
        ctx = (a[..., None] * key).sum(1)
        return torch.cat([ctx, self.act(self.scalar_emb(scalar))], -1)

    def attend(self, x: torch.Tensor, h: torch.Tensor, batch: torch.Tensor) -> torch.Tensor:
        """W_H per target: softmax over its neighbours of cos(X, H_i)/tau, times H_i; 0 if none."""
        b = x.shape[0]
        if h.shape[0] == 0:
            return x.new_zeros(b, h.shape[-1])
        tau = self.log_tau.exp().clamp_min(0.01)
        logits = Fn.cosine_similarity(x[batch], h, dim=-1, eps=1e-6) / tau
        top = x.new_full((b,), -1e9).scatter_reduce(0, batch, logits, reduce="amax", include_self=True)
        e = torch.exp(logits - top[batch])
        denom = x.new_zeros(b).index_add(0, batch, e)
        a = e / denom[batch].clamp_min(1e-12)
        return x.new_zeros(b, h.shape[-1]).index_add(0, batch, a[:, None] * h)


def bivariate_nll(params: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean negative log-likelihood of ``target`` (..., 2) under N(mu, Sigma) from ``params``.

    params (..., 5) = (mu_x, mu_y, sigma_x, sigma_y, rho), Sigma = [[sx^2, rho sx sy],
    [rho sx sy, sy^2]]. NLL = log(2 pi) + log sx + log sy + 0.5 log(1 - rho^2)
    + (dx^2 + dy^2 - 2 rho dx dy) / (2 (1 - rho^2)), with dx = (x - mu_x) / sx etc.
    ``mask`` (...) bool/float selects the terms averaged (all by default).
    """
    nll = bivariate_nll_terms(params, target)
    if mask is None:
        return nll.mean()
    mask = mask.to(nll.dtype)
    return (nll * mask).sum() / mask.sum().clamp_min(1.0)


def bivariate_nll_terms(params: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per-point NLL (...) of :func:`bivariate_nll`, unreduced."""
    mux, muy, sx, sy, rho = params.unbind(-1)
    dx = (target[..., 0] - mux) / sx
    dy = (target[..., 1] - muy) / sy
    one_m = 1.0 - rho * rho
    z = dx * dx + dy * dy - 2.0 * rho * dx * dy
    return 0.5 * z / one_m + torch.log(sx) + torch.log(sy) + 0.5 * torch.log(one_m) + math.log(2.0 * math.pi)


def rank_modes(params: torch.Tensor, log_w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``model(..., all_modes=True)``'s output with each target's modes by falling weight (the
    most likely first, ties in model order): params (B, M, T, 5), log_w (B, M)."""
    order = torch.sort(log_w, dim=-1, descending=True, stable=True).indices
    return params.gather(1, order[:, :, None, None].expand_as(params)), log_w.gather(1, order)


def mixture_nll(params: torch.Tensor, log_w: torch.Tensor, target: torch.Tensor,
                mask: torch.Tensor | None = None) -> torch.Tensor:
    """NLL of whole future trajectories under a mixture of M Gaussian trajectory modes, per point.

    params (B, M, T, 5), log_w (B, M) log mode probabilities, target (B, T, 2), mask (B, T):
    ``-sum_b log sum_m w_bm prod_t N(y_bt | mode m) / (number of masked-in points)``. With
    M = 1 this is :func:`bivariate_nll`'s mean exactly (the mode's log weight is 0)."""
    terms = bivariate_nll_terms(params, target[:, None])  # (B, M, T)
    m = torch.ones(terms.shape[0], terms.shape[2], dtype=terms.dtype) if mask is None else mask.to(terms.dtype)
    traj = (terms * m[:, None, :]).sum(-1)  # (B, M)
    return -torch.logsumexp(log_w - traj, -1).sum() / m.sum().clamp_min(1.0)


def winner_mse(params: torch.Tensor, log_w: torch.Tensor, target: torch.Tensor,
               mask: torch.Tensor | None = None) -> torch.Tensor:
    """Warm-up loss of a multi-modal model: the mean squared distance of the closest mode only
    (winner takes all, so the modes spread out) + the cross-entropy of the mode weights towards
    that mode. params (B, M, T, 5), log_w (B, M), target (B, T, 2), mask (B, T)."""
    d = ((params[..., :2] - target[:, None]) ** 2).sum(-1)  # (B, M, T)
    m = torch.ones(d.shape[0], d.shape[2], dtype=d.dtype) if mask is None else mask.to(d.dtype)
    per_mode = (d * m[:, None, :]).sum(-1) / m.sum(-1, keepdim=True).clamp_min(1.0)  # (B, M)
    best = per_mode.masked_fill(torch.isinf(log_w), math.inf).argmin(-1)  # among the modes a target may have
    return per_mode.gather(1, best[:, None]).mean() + Fn.nll_loss(log_w, best)


def masked_mse(params: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean squared distance of the predicted means (warm-up loss)."""
    d = ((params[..., :2] - target) ** 2).sum(-1)
    if mask is None:
        return d.mean()
    mask = mask.to(d.dtype)
    return (d * mask).sum() / mask.sum().clamp_min(1.0)


def model_config(model: TrajectoryLSTM) -> dict[str, Any]:
    return {
        "kind": model.kind,
        "hist_steps": model.hist_steps,
        "fut_steps": model.fut_steps,
        "pos_scale": [float(v) for v in model.pos_scale.tolist()],
        "sigma_min": model.sigma_min,
        "residual": model.residual,
        "residual_groups": list(model.residual_groups),
        **({"map_size": model.map_size - 32} if model.kind in MAP_KINDS else {}),
        **({"nbr_frame": model.nbr_frame} if model.nbr_frame != "target" else {}),
        **({"modes": model.modes} if model.modes > 1 else {}),
        **({"dec": model.dec_size} if model.dec_size != 128 else {}),
        **({"cv_mode": True} if model.cv_mode else {}),
        **({"single_mode_groups": list(model.single_mode_groups)} if model.single_mode_groups else {}),
        **({"stay_mode_groups": list(model.stay_mode_groups)} if model.stay_mode_groups else {}),
        **({"dec_steps": model.dec_steps} if model.dec_steps != model.fut_steps else {}),
        **({"stay_speed": model.stay_speed} if model.stay_speed is not None else {}),
    }


def save_model(model: TrajectoryLSTM, path: Path, info: dict[str, Any] | None = None) -> Path:
    """Write weights with a header: kind, feature layout version, history/horizon/dt, scales."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    blob = {
        "format": FILE_FORMAT,
        "format_version": FILE_FORMAT_VERSION,
        "kind": model.kind,
        "feature_version": F.FEATURE_VERSION,
        "dt": F.MODEL_DT,
        "hist_steps": model.hist_steps,
        "fut_steps": model.fut_steps,
        "grid": [F.GRID_LON, F.GRID_LAT],
        "grid_cell": F.GRID_CELL.tolist(),
        "pos_scale": [float(v) for v in model.pos_scale.tolist()],
        "map_version": model.map_version if model.kind in MAP_KINDS else None,
        "config": model_config(model),
        "info": info or {},
        "state_dict": {k: v.detach().cpu().clone() for k, v in model.state_dict().items()},
    }
    with fileio.replacing(path, tmp_name=path.name + ".part") as part:  # whole or not at all, even if killed
        torch.save(blob, part)
    return path


def load_model(path: Path, kind: str | None = None) -> tuple[TrajectoryLSTM, dict[str, Any]]:
    """Read a weights file; any problem -> PredictorError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise PredictorError(f"predictor weights file not found: {path}")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is the same error to the user
        raise PredictorError(f"predictor weights file is corrupt or unreadable: {path} ({type(exc).__name__})") from None
    if not isinstance(blob, dict) or blob.get("format") != FILE_FORMAT:
        raise PredictorError(f"not a sumo-ethics predictor weights file: {path}")
    found = blob.get("kind")
    if kind is not None and found != kind:
        raise PredictorError(f"predictor weights file {path} holds a {found!r} model, expected {kind!r} "
                             f"(choose its kind: --predictor {found}, or predictor = \"{found}\" in [planner])")
    checks = {
        "feature_version": F.FEATURE_VERSION,
        "hist_steps": F.HIST_STEPS,
        "fut_steps": F.FUT_STEPS,
        "grid": [F.GRID_LON, F.GRID_LAT],
    }
    for key, want in checks.items():
        if blob.get(key) != want:
            raise PredictorError(f"predictor weights file {path} has {key}={blob.get(key)!r}, this code needs {want!r}")
    if blob.get("kind") not in KINDS:
        raise PredictorError(f"predictor weights file {path} holds an unknown model kind {blob.get('kind')!r}; "
                             f"this code knows {', '.join(KINDS)}")
    if blob.get("kind") in MAP_KINDS and blob.get("map_version") not in F.MAP_VERSIONS:
        raise PredictorError(f"predictor weights file {path} has map_version={blob.get('map_version')!r}, "
                             f"this code reads {' or '.join(map(str, F.MAP_VERSIONS))}")
    if abs(float(blob.get("dt", -1)) - F.MODEL_DT) > 1e-9 or blob.get("grid_cell") != F.GRID_CELL.tolist():
        raise PredictorError(f"predictor weights file {path} was trained for another time step or grid")
    try:
        cfg = blob["config"]
        model = TrajectoryLSTM(kind=cfg["kind"], pos_scale=tuple(cfg["pos_scale"]), sigma_min=cfg.get("sigma_min", 1e-3),
                               residual=cfg.get("residual", False),
                               residual_groups=tuple(cfg.get("residual_groups", (0, 1, 2))),
                               map_size=cfg.get("map_size", 64), nbr_frame=cfg.get("nbr_frame", "target"),
                               modes=cfg.get("modes", 1), dec=cfg.get("dec", 128), cv_mode=cfg.get("cv_mode", False),
                               single_mode_groups=tuple(cfg.get("single_mode_groups", ())),
                               stay_mode_groups=tuple(cfg.get("stay_mode_groups", ())),
                               map_version=int(blob.get("map_version") or F.MAP_VERSION),
                               dec_steps=cfg.get("dec_steps"), stay_speed=cfg.get("stay_speed"))
        model.load_state_dict(blob["state_dict"])
    except Exception as exc:  # noqa: BLE001
        raise PredictorError(f"predictor weights file {path} does not match the model: {exc}") from None
    model.eval()
    return model, blob


def batch_to_tensors(batch: dict[str, Any], pos_scale: Any = F.POS_SCALE, with_map: bool = False,
                     map_version: int = F.MAP_VERSION) -> dict[str, torch.Tensor]:
    """numpy sample batch (see dataset.subset) -> model input tensors, normalised (with the
    map inputs if ``with_map``; a batch without map arrays then gets an empty map). For a
    ``map_version`` 1 model the pedestrians' map inputs are emptied, as that version built them,
    and before version 4 their row after a walking area; each version gets its own scalars
    (features.map_scalars); before version 5 row 0 comes from ``map_row0_v4`` where the batch
    has it (a walking-area pedestrian's earlier row 0, features.map_features)."""
    g = torch.as_tensor(batch["tgt_group"], dtype=torch.long)
    nb = torch.as_tensor(batch["nbr_batch"], dtype=torch.long)
    scale = torch.as_tensor(pos_scale, dtype=torch.float32)[g]
    out = {
        "tgt_hist": torch.as_tensor(batch["tgt_hist"], dtype=torch.float32) / scale[:, None, None],
        "tgt_group": g,
        "nbr_hist": torch.as_tensor(batch["nbr_hist"], dtype=torch.float32) / scale[nb][:, None, None],
        "nbr_group": torch.as_tensor(batch["nbr_group"], dtype=torch.long),
        "nbr_batch": nb,
        "nbr_cell": torch.as_tensor(batch["nbr_cell"], dtype=torch.long),
    }
    if with_map and "map_pts" in batch:
        out["map_pts"] = torch.as_tensor(batch["map_pts"], dtype=torch.float32) / scale[:, None, None, None]
        if map_version < 5 and "map_row0_v4" in batch:  # a version-5 dataset: row 0 as the model's version built it
            out["map_pts"][:, 0] = torch.as_tensor(batch["map_row0_v4"], dtype=torch.float32) / scale[:, None, None]
        out["map_valid"] = torch.as_tensor(batch["map_valid"], dtype=torch.bool)
        out["map_scalar"] = torch.as_tensor(batch["map_scalar"], dtype=torch.float32)[:, :F.map_scalars(map_version)]
        ped = g == F.GROUP_PEDESTRIAN
        if map_version < 2:
            out["map_pts"] = out["map_pts"].masked_fill(ped[:, None, None, None], 0.0)
            out["map_valid"] = out["map_valid"] & ~ped[:, None]
            out["map_scalar"] = out["map_scalar"].masked_fill(ped[:, None], 0.0)
        elif map_version < 4:  # no pedestrian lane after a walking area (features.MAP_ROW_AFTER)
            row = torch.zeros(out["map_valid"].shape[1], dtype=torch.bool)
            row[F.MAP_ROW_AFTER] = True
            gone = ped[:, None] & row[None, :]
            out["map_pts"] = out["map_pts"].masked_fill(gone[:, :, None, None], 0.0)
            out["map_valid"] = out["map_valid"] & ~gone
    if "nbr_yaw" in batch:
        out["nbr_yaw"] = torch.as_tensor(batch["nbr_yaw"], dtype=torch.float32)
    return out
