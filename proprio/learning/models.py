"""Residual / standalone torque models of §4.2: MLP-7, LSTM-2, LSTM-2-FCL and a causal Transformer.

Every model maps the full feature sequence ``x [B, T, 5n]`` = vec(τ_RBD, q, q̇, q̈, r) (N·m, rad, rad/s, rad/s², rad)
to joint torques ``[B, T, n]`` N·m:

* hybrid (eq. 4.29/4.30): ``τ_HYB = τ_RBD + f_NN(τ_RBD, q, q̇, q̈[, r])``;
* standalone: ``τ = f_NN(q, q̇, q̈[, r])`` (no τ_RBD in, nothing added out).

The column selection and the normalisation (eq. 4.33/4.34) live inside the model as buffers, so a saved model is
self-contained. Deviation from the thesis, on purpose: the output is de-normalised with the mean/std of the network's
own target (the residual τ − τ_RBD for hybrids) rather than with the τ statistics — a residual is 10–100× smaller
than τ, and the τ scale would squeeze the network output into a tiny range.

A hybrid's residual starts at exactly zero: its target is scaled by its std but not shifted (``y_mean`` = 0, so a
constant offset is learned like everything else) and the last layer starts at zero (:meth:`HybridModel.zero_output`).
An untrained hybrid predicts τ_RBD exactly, and training (:func:`~proprio.learning.training.train_model`) falls back
to that backbone, whole or per joint, where the trained residual does not beat it on the validation split. Keeping
the training mean as a fixed offset learns faster (LWR 4+: 0.061 instead of 0.087 N·m² on the test file in 60
epochs) but carries the training part's offset into a test part that differs from it (TX40: held-out 18.4 vs the
backbone's 17.9 N·m²) — README, "A residual never worse than its backbone".

Sequence models are trained sequence-to-sequence (a prediction at every step of a window, each seeing only that
window's past: LSTM by recurrence, Transformer by a causal mask); the thesis' sequence-to-one prediction at the end
of a window is the last step. The streaming form (state carried from sample to sample) exists for MLP-7 (stateless)
and the LSTMs: :meth:`HybridModel.run` in torch (autograd, training), and :class:`StreamingStepper`, the same weights
as float64 numpy and numba kernels, which every inference outside training calls — one sample at a time (the
residual System, the streaming estimator) or over a whole log. The Transformer has no streaming form; its windowed
inference stays on torch.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Sequence

import numba
import numpy as np
import torch
from torch import nn

from proprio.io import atomic_path
from proprio.learning.features import DEFAULT_DEADBAND_DEG, R_MAX_DEG, feature_columns
from proprio.learning.sections import section_from_dict

__all__ = ["ARCHS", "ModelConfig", "HybridModel", "StreamingStepper", "lstm2_step", "lstm2_run", "save_model",
           "load_model", "first_line"]

ARCHS = ("mlp7", "lstm2", "lstm2_fcl", "transformer")
_LABEL = {"mlp7": "MLP-7", "lstm2": "LSTM-2", "lstm2_fcl": "LSTM-2-FCL", "transformer": "Transformer"}
_FORMAT = "proprio-hybrid-model/1"
_MLP_BLOCK = 4096                       # samples per vectorised MLP-7 block of StreamingStepper.run (≈ 23 MB at n = 7)


@dataclass
class ModelConfig:
    """Architecture and the data conventions a model needs at inference time (the ``model:`` config section)."""
    arch: str = "lstm2_fcl"
    hybrid: bool = True                 # τ_RBD as input and added to the output
    use_r: bool = True                  # rotational displacement encoding as input
    n_joints: int = 7
    window: int = 100                   # T used in training (and windowed evaluation)
    mlp_hidden: int = 100               # MLP-7: 35-100-1 per joint
    lstm_hidden: int = 35               # LSTM-2: 35 → 35 → n
    tf_d_model: int = 32                # Transformer (small)
    tf_heads: int = 4
    tf_layers: int = 2
    tf_ff: int = 64
    rate_hz: float = 75.0               # model sample rate (after decimation) [Hz]
    reversal_deadband_deg: float = DEFAULT_DEADBAND_DEG
    r_max_deg: float = R_MAX_DEG

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ModelConfig":
        cfg = section_from_dict(cls, d, "model")
        if cfg.arch not in ARCHS:
            raise ValueError(f"model: arch '{cfg.arch}' unknown; choose one of {list(ARCHS)}")
        return cfg

    @property
    def n_inputs(self) -> int:
        return len(feature_columns(self.n_joints, self.hybrid, self.use_r))

    @property
    def streamable(self) -> bool:
        return self.arch != "transformer"

    def label(self) -> str:
        """Thesis-style name: "LSTM-2-FCL 100", "MLP-7 no r", "LSTM-2 100 no r, no τ_RBD" (standalone)."""
        name = _LABEL[self.arch] + ("" if self.arch == "mlp7" else f" {self.window}")
        tags = ([] if self.use_r else ["no r"]) + ([] if self.hybrid else ["no τ_RBD"])
        return name + (" " + ", ".join(tags) if tags else "")


class _MLP7(nn.Module):
    """n parallel 35-100-1 ReLU nets, trained jointly; batched weights, one einsum per layer."""

    def __init__(self, n_in: int, hidden: int, n_out: int):
        super().__init__()
        b1, b2 = 1 / math.sqrt(n_in), 1 / math.sqrt(hidden)      # nn.Linear's default init bounds
        self.w1 = nn.Parameter(torch.empty(n_out, n_in, hidden).uniform_(-b1, b1))
        self.b1 = nn.Parameter(torch.empty(n_out, hidden).uniform_(-b1, b1))
        self.w2 = nn.Parameter(torch.empty(n_out, hidden).uniform_(-b2, b2))
        self.b2 = nn.Parameter(torch.empty(n_out).uniform_(-b2, b2))

    def forward(self, z: torch.Tensor) -> torch.Tensor:          # [..., F] -> [..., n]
        h = torch.relu(torch.einsum("...f,jfh->...jh", z, self.w1) + self.b1)
        return torch.einsum("...jh,jh->...j", h, self.w2) + self.b2


class _LSTM2(nn.Module):
    """Two stacked LSTM cells F → H → n (LSTM-2); with ``fcl`` a linear n → n layer on top (LSTM-2-FCL)."""

    def __init__(self, n_in: int, hidden: int, n_out: int, fcl: bool):
        super().__init__()
        self.cell1 = nn.LSTM(n_in, hidden, batch_first=True)
        self.cell2 = nn.LSTM(hidden, n_out, batch_first=True)
        self.fcl = nn.Linear(n_out, n_out) if fcl else None
        self.sizes = (hidden, hidden, n_out, n_out)               # h1, c1, h2, c2

    def forward(self, z: torch.Tensor, state: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """``z [B, T, F]``, flat ``state [B, 2H + 2n]`` (zeros when None) → ``(y [B, T, n], state)``."""
        if state is None:
            state = z.new_zeros(z.shape[0], sum(self.sizes))
        h1, c1, h2, c2 = (s.unsqueeze(0).contiguous() for s in torch.split(state, self.sizes, dim=-1))
        y1, (h1, c1) = self.cell1(z, (h1, c1))
        y2, (h2, c2) = self.cell2(y1, (h2, c2))
        y = self.fcl(y2) if self.fcl is not None else y2
        return y, torch.cat([h1[0], c1[0], h2[0], c2[0]], dim=-1)


class _PositionalEncoding(nn.Module):
    def __init__(self, d_model: int, max_len: int):
        super().__init__()
        pos = torch.arange(max_len).unsqueeze(1)
        div = torch.exp(torch.arange(0, d_model, 2) * (-math.log(10000.0) / d_model))
        pe = torch.zeros(max_len, d_model)
        pe[:, 0::2] = torch.sin(pos * div)
        pe[:, 1::2] = torch.cos(pos * div)
        self.register_buffer("pe", pe, persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.pe[:x.shape[1]]


class _CausalTransformer(nn.Module):
    """Encoder-only Transformer with sinusoidal positions and a causal mask (each step attends to its past)."""

    def __init__(self, n_in: int, n_out: int, cfg: ModelConfig):
        super().__init__()
        self.inp = nn.Linear(n_in, cfg.tf_d_model)
        self.pos = _PositionalEncoding(cfg.tf_d_model, cfg.window)
        layer = nn.TransformerEncoderLayer(cfg.tf_d_model, cfg.tf_heads, cfg.tf_ff, dropout=0.0, batch_first=True)
        self.encoder = nn.TransformerEncoder(layer, cfg.tf_layers, enable_nested_tensor=False)
        self.out = nn.Linear(cfg.tf_d_model, n_out)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        T = z.shape[1]
        mask = nn.Transformer.generate_square_subsequent_mask(T, device=z.device, dtype=z.dtype)
        return self.out(self.encoder(self.pos(self.inp(z)), mask=mask, is_causal=True))


class HybridModel(nn.Module):
    """A hybrid or standalone torque model; input the full features ``[B, T, 5n]``, output τ ``[B, T, n]`` N·m."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        n, f = cfg.n_joints, cfg.n_inputs
        self.register_buffer("columns", torch.as_tensor(feature_columns(n, cfg.hybrid, cfg.use_r)))
        self.register_buffer("x_mean", torch.zeros(f))
        self.register_buffer("x_std", torch.ones(f))
        self.register_buffer("y_mean", torch.zeros(n))
        self.register_buffer("y_std", torch.ones(n))
        if cfg.arch == "mlp7":
            self.net: nn.Module = _MLP7(f, cfg.mlp_hidden, n)
        elif cfg.arch in ("lstm2", "lstm2_fcl"):
            self.net = _LSTM2(f, cfg.lstm_hidden, n, fcl=cfg.arch == "lstm2_fcl")
        else:
            self.net = _CausalTransformer(f, n, cfg)
        if cfg.hybrid:
            self.zero_output()

    @property
    def per_joint_output(self) -> bool:
        """True when output j has its own last-layer row (MLP-7, LSTM-2-FCL, Transformer): zeroing it changes no
        other joint. LSTM-2's last layer is a recurrent cell whose units feed each other."""
        return self.cfg.arch != "lstm2"

    @torch.no_grad()
    def zero_output(self, joints: Sequence[int] | None = None) -> None:
        """Make the residual exactly zero for ``joints`` (all when None), so a hybrid predicts τ_RBD there: zeroes
        their target mean ``y_mean`` and those rows of the last layer; for LSTM-2 (all joints only) the cell input
        rows g of its second cell: then c₂ = h₂ = 0 at every step, while the other gates keep their weights and the
        gradient through g is not zero, so the network can still learn from there."""
        rows = list(range(self.cfg.n_joints)) if joints is None else [int(j) for j in joints]
        self.y_mean[rows] = 0.0
        if isinstance(self.net, _MLP7):
            for p in (self.net.w2, self.net.b2):
                p[rows] = 0.0
        elif isinstance(self.net, _LSTM2) and self.net.fcl is not None:
            self.net.fcl.weight[rows] = 0.0
            self.net.fcl.bias[rows] = 0.0
        elif isinstance(self.net, _LSTM2):
            if len(rows) != self.cfg.n_joints:
                raise ValueError("LSTM-2: its output units feed each other; only all joints can be zeroed")
            n = self.cfg.n_joints
            g = slice(2 * n, 3 * n)                                  # PyTorch's gate order i, f, g, o
            for name in ("weight_ih_l0", "weight_hh_l0", "bias_ih_l0", "bias_hh_l0"):
                getattr(self.net.cell2, name)[g] = 0.0
        else:
            self.net.out.weight[rows] = 0.0
            self.net.out.bias[rows] = 0.0

    # -- normalisation (eq. 4.33, 4.34), computed on the training split -------------------------------------
    def set_normalisation(self, features: np.ndarray, tau: np.ndarray) -> None:
        """Mean/std of the used input columns and of the target (τ − τ_RBD if hybrid, else τ) over the training
        samples ``features [..., 5n]``, ``tau [..., n]``. A constant column gets std 1; a hybrid's target mean stays 0
        (module docstring)."""
        n = self.cfg.n_joints
        x = features.reshape(-1, features.shape[-1])
        y = tau.reshape(-1, n) - (x[:, :n] if self.cfg.hybrid else 0.0)
        x = x[:, self.columns.cpu().numpy()]
        std = lambda a: np.where(a.std(0) > 1e-9, a.std(0), 1.0)  # noqa: E731
        y_mean = np.zeros(n) if self.cfg.hybrid else y.mean(0)
        for name, val in (("x_mean", x.mean(0)), ("x_std", std(x)), ("y_mean", y_mean), ("y_std", std(y))):
            buf = getattr(self, name)
            buf.copy_(torch.as_tensor(val, dtype=buf.dtype))

    def _normalise(self, x: torch.Tensor) -> torch.Tensor:
        return (x[..., self.columns] - self.x_mean) / self.x_std

    def _output(self, y: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        tau = y * self.y_std + self.y_mean
        return tau + x[..., :self.cfg.n_joints] if self.cfg.hybrid else tau

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """τ ``[B, T, n]`` for ``x [B, T, 5n]``; sequence models start from a zero state (one fresh window)."""
        z = self._normalise(x)
        y = self.net(z)[0] if isinstance(self.net, _LSTM2) else self.net(z)
        return self._output(y, x)

    # -- streaming ----------------------------------------------------------------------------------------------
    @property
    def state_size(self) -> int:
        """Length of the flat recurrent state (0 for MLP-7)."""
        return sum(self.net.sizes) if isinstance(self.net, _LSTM2) else 0

    def run(self, x: torch.Tensor, state: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Streaming over ``x [B, T, 5n]`` from ``state [B, state_size]`` (zeros when None) → ``(τ, final state)``.
        One call over a whole recording equals T calls with one sample each."""
        if not self.cfg.streamable:
            raise ValueError(f"{self.cfg.label()}: a Transformer has no streaming form; use windowed evaluation")
        z = self._normalise(x)
        if isinstance(self.net, _LSTM2):
            y, state = self.net(z, state)
        else:
            y, state = self.net(z), x.new_zeros(x.shape[0], 0)
        return self._output(y, x), state


def save_model(model: HybridModel, path: str | Path, extra: dict[str, Any] | None = None) -> Path:
    """Write ``{format, config, state_dict, extra}`` atomically with ``torch.save`` (weights as float32/64 tensors,
    everything else plain Python, so :func:`load_model` can use ``weights_only=True``). ``extra``: JSON-like info
    (data config, backbone, metrics)."""
    payload = {"format": _FORMAT, "config": asdict(model.cfg), "extra": extra or {},
               "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()}}
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return Path(path)


def load_model(path: str | Path, dtype: torch.dtype = torch.float32) -> tuple[HybridModel, dict[str, Any]]:
    """``(model in eval mode, extra)`` from a file written by :func:`save_model` (``weights_only=True``). An
    identified backbone (``extra["backbone"]``, an ``.npz``) not found where it was named is looked for beside the
    model file (a model shipped with its backbone, e.g. ``proprio/configs/table5_*``)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such model file")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for a corrupt / foreign file
        raise ValueError(f"{path}: not a readable model file ({exc})") from exc
    if not isinstance(payload, dict) or payload.get("format") != _FORMAT:
        raise ValueError(f"{path}: not a proprio hybrid model (format tag missing)")
    try:                    # the format tag is right; the config and the weights must fit each other too
        model = HybridModel(ModelConfig.from_dict(payload["config"]))
        model.load_state_dict(payload["state_dict"])
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise ValueError(f"{path}: a proprio hybrid model file whose config and weights do not fit together "
                         f"({first_line(exc)})") from None
    extra = dict(payload.get("extra", {}))
    spec = extra.get("backbone")
    if isinstance(spec, str) and spec.endswith(".npz") and not Path(spec).exists() \
            and (path.parent / Path(spec).name).exists():
        extra["backbone"] = str(path.parent / Path(spec).name)      # an identified backbone shipped beside the model
    return model.to(dtype).eval(), extra


def first_line(exc: BaseException, limit: int = 200) -> str:
    """The first line of an exception's message, at most ``limit`` characters (torch's state-dict report lists
    every key)."""
    text = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    return text if len(text) <= limit else text[:limit] + " …"


@numba.njit(cache=True)
def _lstm_cell(w, z, c, c_out, h_out):  # pragma: no cover (compiled)
    """One LSTM cell step (eq. 3.66–3.71): the cell state from ``c`` into ``c_out`` and h into ``h_out``. The gates
    come from ONE tanh, σ(a) = ½ + ½ tanh(a/2), so ``w = S [W_ih  W_hh  b]`` (rows i, f, o, g) is pre-scaled by
    S = ½ on the i, f, o rows and 1 on the g rows, and ``z = [x; h; 1]``."""
    k = c.shape[0]
    a = np.tanh(np.dot(w, z))                               # (BLAS: the one product of the cell)
    for i in range(k):
        gate_i, gate_f, gate_o = 0.5 * a[i] + 0.5, 0.5 * a[k + i] + 0.5, 0.5 * a[2 * k + i] + 0.5
        c_new = c[i] * gate_f + gate_i * a[3 * k + i]
        c_out[i] = c_new
        h_out[i] = math.tanh(c_new) * gate_o


@numba.njit(cache=True)
def lstm2_step(cell1, cell2, w_out, x, state, state_out, tau_out):  # pragma: no cover (compiled)
    """One step of the LSTM-2(-FCL) on the features ``x`` (the model's columns): the network's output τ_NN [n] N·m
    (a hybrid's τ_RBD not added) into ``tau_out`` and the next state ``[h₁, c₁, h₂, c₂]`` into ``state_out`` (which
    must not alias ``state``) — the streaming law of :class:`StreamingStepper`, compiled."""
    k1, k2, f = cell1.shape[0] // 4, cell2.shape[0] // 4, x.shape[0]
    z1 = np.empty(f + k1 + 1)
    z1[:f], z1[f:f + k1], z1[f + k1] = x, state[:k1], 1.0
    _lstm_cell(cell1, z1, state[k1:2 * k1], state_out[k1:2 * k1], state_out[:k1])
    z2 = np.empty(k1 + k2 + 1)
    z2[:k1], z2[k1:k1 + k2], z2[k1 + k2] = state_out[:k1], state[2 * k1:2 * k1 + k2], 1.0
    _lstm_cell(cell2, z2, state[2 * k1 + k2:], state_out[2 * k1 + k2:], state_out[2 * k1:2 * k1 + k2])
    for i in range(tau_out.shape[0]):
        s = w_out[i, k2]
        for j in range(k2):
            s += w_out[i, j] * state_out[2 * k1 + j]
        tau_out[i] = s


@numba.njit(cache=True)
def lstm2_run(cell1, cell2, w_out, x, state, tau_out):  # pragma: no cover (compiled)
    """:func:`lstm2_step` over the samples ``x [N, f]`` in order, the state carried from ``state`` (updated in place to
    the final state): τ_NN ``[N, n]`` N·m into ``tau_out`` — the batch form of the streaming law, one compiled loop."""
    nxt = np.empty_like(state)
    for k in range(x.shape[0]):
        lstm2_step(cell1, cell2, w_out, x[k], state, nxt, tau_out[k])
        state[:] = nxt


class StreamingStepper:
    """The model's inference law as plain float64 numpy and numba kernels — the one law every inference path calls:
    ``step(x [5n], state [state_size]) -> (τ [n], state)`` one sample at a time (≈10× less overhead per sample than
    a torch call; the residual Systems and the streaming estimator), ``run(x [N, 5n]) -> (τ [N, n], state)`` over a
    whole sequence (:func:`~proprio.learning.evaluation.predict_streaming`, the hybrid torque model's batch path).
    Both equal :meth:`HybridModel.run`, the torch form kept for training (autograd), to rounding (tests).

    The normalisations are folded into the weights once (eq. 4.33/4.34 are affine, so ``W((x − μ)/σ) + b`` =
    ``(W/σ) x + (b − W μ/σ)`` and the output de-normalisation scales the last layer), which leaves one matrix–vector
    product per LSTM cell (on [x; h]) and one for the output layer. An LSTM steps by the compiled kernel
    :func:`lstm2_step` (numba; compiled or loaded from its cache when the stepper is built, so the first sample is
    not the compile); :attr:`all_features`: it reads all five feature blocks vec(τ_RBD, q, q̇, q̈, r) in order (the
    residual step then runs it inside one kernel, :mod:`proprio.learning.streaming`)."""

    def __init__(self, model: HybridModel):
        if not model.cfg.streamable:
            raise ValueError(f"{model.cfg.label()}: a Transformer has no streaming form")
        sd = {k: v.detach().cpu().double().numpy() for k, v in model.state_dict().items()}
        self.n, self.hybrid = model.cfg.n_joints, model.cfg.hybrid
        self.state_size = model.state_size
        columns = sd["columns"].astype(int)
        self.columns = None if np.array_equal(columns, np.arange(5 * self.n)) else columns
        inv_std = 1.0 / sd["x_std"]
        y_mean, y_std = sd["y_mean"], sd["y_std"]

        def fold_input(w: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return w * inv_std, b - w @ (sd["x_mean"] * inv_std)

        self.arch = model.cfg.arch
        self.all_features = self.columns is None and self.arch != "mlp7"
        if self.arch == "mlp7":
            w1 = sd["net.w1"]                                                   # [n, F, H]
            self.w1 = w1 * inv_std[None, :, None]
            self.b1 = sd["net.b1"] - np.einsum("f,jfh->jh", sd["x_mean"] * inv_std, w1)
            self.w2, self.b2 = sd["net.w2"] * y_std[:, None], sd["net.b2"] * y_std + y_mean
        else:
            w_ih, b1 = fold_input(sd["net.cell1.weight_ih_l0"], sd["net.cell1.bias_ih_l0"] + sd["net.cell1.bias_hh_l0"])
            self.sizes = model.net.sizes

            def cell(w_ih: np.ndarray, w_hh: np.ndarray, b: np.ndarray) -> np.ndarray:
                k = w_hh.shape[1]
                rows = np.r_[0:2 * k, 3 * k:4 * k, 2 * k:3 * k]     # PyTorch's i, f, g, o → i, f, o, g
                scale = np.full(4 * k, 0.5)          # σ(a) = ½ + ½ tanh(a/2) on i, f, o; tanh(a) on g
                scale[3 * k:] = 1.0
                return np.ascontiguousarray(scale[:, None] * np.hstack([w_ih, w_hh, b[:, None]])[rows])

            self.cells = [cell(w_ih, sd["net.cell1.weight_hh_l0"], b1),
                          cell(sd["net.cell2.weight_ih_l0"], sd["net.cell2.weight_hh_l0"],
                               sd["net.cell2.bias_ih_l0"] + sd["net.cell2.bias_hh_l0"])]
            if "net.fcl.weight" in sd:
                w_out, b_out = sd["net.fcl.weight"] * y_std[:, None], sd["net.fcl.bias"] * y_std + y_mean
            else:
                w_out, b_out = np.diag(y_std), y_mean
            self.w_out = np.ascontiguousarray(np.hstack([w_out, b_out[:, None]]))       # [W | b] on [h₂; 1]
            f = self.cells[0].shape[1] - self.sizes[0] - 1                      # the LSTM's input size
            lstm2_step(*self.cells, self.w_out, np.zeros(f), np.zeros(self.state_size), np.empty(self.state_size),
                       np.empty(self.n))                                                         # compile / load
            lstm2_run(*self.cells, self.w_out, np.zeros((1, f)), np.zeros(self.state_size), np.empty((1, self.n)))

    def _mlp(self, z: np.ndarray) -> np.ndarray:
        """MLP-7's τ_NN ``[..., n]`` for the model's columns ``z [..., F]`` (one sample or many: the same law)."""
        h = np.maximum(np.einsum("...f,jfh->...jh", z, self.w1) + self.b1, 0.0)
        return np.einsum("...jh,jh->...j", h, self.w2) + self.b2

    def residual_step(self, x: np.ndarray, state: np.ndarray, r: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
        """τ_NN [n] N·m — the network's own output: a hybrid's residual, τ_RBD not added; a standalone model's torque
        — for the features ``x [5n]`` of one sample (or ``x [4n]`` = vec(τ_RBD, q, q̇, q̈) and ``r [n]`` apart, which
        saves a concatenation) and the next recurrent state (``state`` is not modified)."""
        if r is not None and (self.columns is not None or self.arch == "mlp7"):
            x, r = np.concatenate((x, r)), None
        z = x if self.columns is None else x[self.columns]
        if self.arch == "mlp7":
            return self._mlp(z), state
        if r is not None:
            z = np.concatenate((z, r))
        nxt, tau = np.empty_like(state), np.empty(self.n)
        lstm2_step(*self.cells, self.w_out, z, state, nxt, tau)
        return tau, nxt

    def step(self, x: np.ndarray, state: np.ndarray, r: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """τ [n] N·m (τ_HYB = τ_RBD + τ_NN for a hybrid, :meth:`residual_step` + the first feature block) and the
        next recurrent state, for one sample (arguments as :meth:`residual_step`)."""
        tau, nxt = self.residual_step(x, state, r)
        return (tau + x[:self.n] if self.hybrid else tau), nxt

    def run(self, x: np.ndarray, state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The batch form over ONE sequence ``x [N, 5n]`` with the state carried from ``state`` (zeros when None):
        ``(τ [N, n] N·m, final state)``, equal to :meth:`step` sample by sample and to :meth:`HybridModel.run` to
        rounding (tests). An LSTM runs :func:`lstm2_step` over the samples in one compiled call (:func:`lstm2_run`),
        MLP-7 its law vectorised over the samples."""
        x = np.asarray(x, dtype=float)
        if x.ndim != 2 or x.shape[1] != 5 * self.n:
            raise ValueError(f"StreamingStepper.run: features must be [N, {5 * self.n}], got {list(x.shape)}")
        z = x if self.columns is None else x[:, self.columns]
        final = np.zeros(self.state_size) if state is None else np.array(state, dtype=float)
        if self.arch == "mlp7":        # vectorised in blocks: the hidden layer is [block, n, H]
            tau = np.vstack([self._mlp(z[i:i + _MLP_BLOCK]) for i in range(0, max(z.shape[0], 1), _MLP_BLOCK)])
        else:
            tau = np.empty((x.shape[0], self.n))
            lstm2_run(*self.cells, self.w_out, np.ascontiguousarray(z), final, tau)
        return (tau + x[:, :self.n] if self.hybrid else tau), final
