"""What a data-quality check reports: :class:`Finding` (severity, code, message, numbers), the
:class:`DataQuality` of one log, the :class:`QualityThresholds` of the checks, and their text / Markdown forms."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

__all__ = ["SEVERITIES", "Finding", "DataQuality", "QualityThresholds", "format_findings", "findings_markdown"]

SEVERITIES = ("info", "warning", "problem")
_RANK = {s: i for i, s in enumerate(SEVERITIES)}
_SYMBOL = {"t": "t", "q": "q", "tau": "τ", "qd": "q̇", "qdd": "q̈"}


@dataclass(frozen=True)
class QualityThresholds:
    """The thresholds of :func:`assess` (module docstring). Times in s, fractions of 1, ratios dimensionless."""
    jitter_factor: float = 1.5            # a step > this × median step is "long"
    jitter_warn_fraction: float = 0.01    # warn when more steps than this fraction are long
    gap_problem_fraction: float = 0.10    # a problem when gaps miss more than this fraction of the duration
    clip_margin: float = 0.01             # |τ| within this fraction of the effort limit counts as at the limit
    clip_min_run: int = 3                 # samples in a row at the limit
    flat_min_run: int = 10                # bit-identical samples in a row at a joint's extreme
    quant_tolerance: float = 0.01         # |Δx/δ − round(Δx/δ)| allowed, fraction of δ
    quant_fit_fraction: float = 0.98      # share of non-zero differences that must be multiples of δ
    quant_max_ratio: float = 1000.0       # report only when median |Δx| ≤ this × δ
    quant_warn_zero_fraction: float = 0.2
    filtered_floor_ratio: float = 1e-5    # white floor σ / signal RMS below this: filtered upstream
    filtered_falloff: float = 10.0        # median P in [0.15, 0.25) fs over [0.4, 0.5] fs above this: filtered
    min_spectrum_samples: int = 256
    max_lag_s: float = 0.05               # lags searched within ± this [s]
    edge_fraction: float = 0.05           # share of samples dropped at each end before the lag estimate
    lag_warn_s: float = 1e-3
    gain_warn: float = 0.05
    qdd_noise_ratio: float = 3.0


@dataclass(frozen=True)
class Finding:
    """One finding: ``severity`` (``info`` / ``warning`` / ``problem``), a short ``code``, a one-line ``message``
    naming the ``channel`` (``t``, ``q``, ``tau``, ``qd``, ``qdd``) and ``joints``, and the numbers behind it
    (``values``, SI units, keys say which)."""
    severity: str
    code: str
    message: str
    channel: str
    joints: tuple[str, ...] = ()
    values: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.severity not in _RANK:
            raise ValueError(f"finding severity must be one of {SEVERITIES}, got {self.severity!r}")

    def to_dict(self) -> dict[str, Any]:
        return {"severity": self.severity, "code": self.code, "message": self.message, "channel": self.channel,
                "joints": list(self.joints), "values": _jsonable(self.values)}


@dataclass
class DataQuality:
    """The findings on one Recording (most severe first), the conditioning line and the Recording's ``source``."""
    findings: list[Finding]
    conditioning: str
    source: str = ""

    def at_least(self, severity: str) -> list[Finding]:
        """The findings of ``severity`` or worse."""
        return [f for f in self.findings if _RANK[f.severity] >= _RANK[severity]]

    @property
    def worst(self) -> str | None:
        """The most severe severity found, or None without findings."""
        return max((f.severity for f in self.findings), key=_RANK.__getitem__, default=None)

    def codes(self) -> set[str]:
        return {f.code for f in self.findings}

    def to_dict(self) -> dict[str, Any]:
        return {"source": self.source, "conditioning": self.conditioning,
                "findings": [f.to_dict() for f in self.findings]}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1, allow_nan=False)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


def format_findings(dq: DataQuality, min_severity: str = "info", title: str | None = None,
                    conditioning: bool = True) -> str:
    """Fixed-width text: an optional title line, one line per finding of ``min_severity`` or worse
    (``SEVERITY  code  message``) and the conditioning line."""
    lines = [title] if title else []
    shown = dq.at_least(min_severity)
    for f in shown:
        lines.append(f"  {f.severity.upper():<8} {f.code:<14} {f.message}")
    if not shown:
        lines.append("  no findings" + ("" if min_severity == "info" else f" of severity {min_severity} or worse"))
    if conditioning:
        lines.append(f"  {dq.conditioning}")
    return "\n".join(lines)


def findings_markdown(items: Sequence[tuple[str, DataQuality]], min_severity: str = "info") -> str:
    """A markdown table of the findings of several Recordings (``(name, DataQuality)`` pairs), then one paragraph
    per Recording with its conditioning line — for the top of the diagnosis report."""
    rows = ["| recording | severity | finding | what |", "|---|---|---|---|"]
    for name, dq in items:
        shown = dq.at_least(min_severity)
        if not shown:
            rows.append(f"| {name} | — | — | no findings |")
        for f in shown:
            rows.append(f"| {name} | {f.severity} | {f.code} | {f.message.replace('|', '/')} |")
    paras = [f"{name}{f' ({dq.source})' if dq.source else ''} — {dq.conditioning}" for name, dq in items]
    return "\n".join(rows) + "\n\n" + "\n\n".join(paras)
