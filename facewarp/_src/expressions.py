"""Facial expressions: Table 6.4 presets, activation envelopes over time, blends and sequences.

A muscle is named by its Table 6.2 name (``MUSCLES``); paired muscles take the same activation on
both sides unless a side-specific key (``"zygomatic_major_L"``) overrides it. Jaw angles are in
radians: ``jaw_u`` opens the mouth about the axis through the condyles (Sec. 6.4.3, 0..60 deg),
``jaw_v`` turns the mandible about the vertical axis (+-5 deg).

A :class:`Timeline` holds segments (an expression with attack, hold and release times and a
weight); sampling it at a time gives the activations and jaw angles to feed the solver's Control.
Overlapping segments add (a blend) and activations are clamped to [0, 1].
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .core.errors import InputError

__all__ = [
    "MUSCLES",
    "PRESETS",
    "JAW_U_MAX",
    "JAW_V_MAX",
    "Expression",
    "Segment",
    "Timeline",
    "blend",
    "load_sequence",
    "preset",
    "thesis_sequence",
    "timeline_for",
    "timeline_from_spec",
]

MUSCLES: tuple[str, ...] = (
    "zygomatic_major",  # 01
    "zygomatic_minor",  # 02
    "depressor_anguli_oris",  # 03
    "risorius",  # 04
    "mentalis",  # 05
    "quadratus_labii_superioris",  # 06
    "corrugator",  # 07
    "frontalis_inner",  # 08
    "frontalis_major",  # 09
    "frontalis_outer",  # 10
    "nasalis",  # 11
    "levator_anguli_oris",  # 12
    "orbicularis_oris",  # 13
    "orbicularis_oculi",  # 14
)
"""Table 6.2 muscles in the thesis's numbering (index + 1 = muscle no.)."""

JAW_U_MAX = math.radians(60.0)
JAW_V_MAX = math.radians(5.0)


@dataclass(frozen=True)
class Expression:
    """Muscle activations in [0, 1] (name -> value; missing muscles are 0) and jaw angles [rad]."""

    name: str
    activations: dict = field(default_factory=dict)
    jaw_u: float = 0.0
    jaw_v: float = 0.0

    def __post_init__(self):
        for k, v in self.activations.items():
            base = k[:-2] if k.endswith(("_L", "_R")) else k
            if base not in MUSCLES:
                raise InputError(f"expression {self.name!r}: unknown muscle {k!r} (known: {', '.join(MUSCLES)})")
            if not (isinstance(v, (int, float)) and 0.0 <= float(v) <= 1.0):
                raise InputError(f"expression {self.name!r}: activation of {k} must be in [0, 1], got {v!r}")
        if not 0.0 <= self.jaw_u <= JAW_U_MAX + 1e-9:
            raise InputError(f"expression {self.name!r}: jaw_u must be 0..60 deg, got {math.degrees(self.jaw_u):.1f} deg")
        if abs(self.jaw_v) > JAW_V_MAX + 1e-9:
            raise InputError(f"expression {self.name!r}: jaw_v must be within +-5 deg, got {math.degrees(self.jaw_v):.1f} deg")

    def activation(self, muscle: str, side: str | None = None) -> float:
        """Activation of ``muscle`` (a Table 6.2 name) on ``side`` ("L", "R" or None)."""
        if side is not None and f"{muscle}_{side}" in self.activations:
            return float(self.activations[f"{muscle}_{side}"])
        return float(self.activations.get(muscle, 0.0))


def _table_6_4(name, values, jaw_u):
    return Expression(name, {m: v for m, v in zip(MUSCLES, values) if v}, jaw_u)


# Table 6.4: activations of muscles 01..12 and the u-axis jaw rotation, exactly as printed.
PRESETS: dict[str, Expression] = {
    "neutral": Expression("neutral"),
    "smile": _table_6_4("smile", (0.3, 0.1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0.2), 0.0),
    "laugh": _table_6_4("laugh", (0.7, 0.2, 0, 0.5, 0, 0.2, 0, 0, 0, 0, 0, 0.1), math.pi / 6),
    "surprise": _table_6_4("surprise", (0, 0, 0, 0, 0.3, 0.3, 0, 0, 0.2, 0, 0, 0), math.pi / 6),
    "angry": _table_6_4("angry", (0, 0, 0.3, 0.2, 0, 0.5, 0.4, 0, 0, 0.3, 0.4, 0), math.pi / 12),
    "sad": _table_6_4("sad", (0, 0, 0.5, 0, 0, 0, 0.6, 0.4, 0.1, 0, 0, 0), 0.0),
}


def preset(name: str) -> Expression:
    try:
        return PRESETS[name]
    except KeyError:
        raise InputError(f"expression: unknown preset {name!r} (known: {', '.join(PRESETS)})") from None


def blend(weights: dict[str, float], *, name: str | None = None) -> Expression:
    """Weighted sum of presets (name -> weight), activations clamped to [0, 1]."""
    acts: dict[str, float] = {}
    ju = jv = 0.0
    for pname, w in weights.items():
        e = preset(pname)
        for k, v in e.activations.items():
            acts[k] = acts.get(k, 0.0) + w * v
        ju += w * e.jaw_u
        jv += w * e.jaw_v
    acts = {k: float(np.clip(v, 0.0, 1.0)) for k, v in acts.items()}
    return Expression(name or "+".join(f"{w:g}*{k}" for k, w in weights.items()), acts,
                      float(np.clip(ju, 0.0, JAW_U_MAX)), float(np.clip(jv, -JAW_V_MAX, JAW_V_MAX)))


def _smoothstep(x):
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass(frozen=True)
class Segment:
    """One expression over time: ramps up over ``attack``, holds, ramps down over ``release`` [s]."""

    expression: Expression
    start: float = 0.0
    attack: float = 0.3
    hold: float = 1.0
    release: float = 0.3
    weight: float = 1.0

    @property
    def end(self) -> float:
        return self.start + self.attack + self.hold + self.release

    def envelope(self, t: float) -> float:
        """Weight of the segment at time ``t`` [s] (smoothstep ramps), in [0, weight]."""
        s = t - self.start
        if s <= 0.0 or s >= self.attack + self.hold + self.release:
            return 0.0
        if s < self.attack:
            return self.weight * _smoothstep(s / self.attack)
        if s <= self.attack + self.hold:
            return self.weight
        return self.weight * (1.0 - _smoothstep((s - self.attack - self.hold) / max(self.release, 1e-9)))


@dataclass
class Timeline:
    """Segments over time; :meth:`sample` gives activations and jaw angles at a time."""

    segments: list[Segment]

    @property
    def duration(self) -> float:
        return max((s.end for s in self.segments), default=0.0)

    def sample(self, t: float) -> Expression:
        acts: dict[str, float] = {}
        ju = jv = 0.0
        for seg in self.segments:
            w = seg.envelope(t)
            if w == 0.0:
                continue
            for k, v in seg.expression.activations.items():
                acts[k] = acts.get(k, 0.0) + w * v
            ju += w * seg.expression.jaw_u
            jv += w * seg.expression.jaw_v
        acts = {k: float(min(max(v, 0.0), 1.0)) for k, v in acts.items()}
        return Expression(f"t={t:.3f}", acts, float(min(max(ju, 0.0), JAW_U_MAX)),
                          float(min(max(jv, -JAW_V_MAX), JAW_V_MAX)))


def timeline_for(name: str, *, attack: float = 0.3, hold: float = 1.0, release: float = 0.3, start: float = 0.2) -> Timeline:
    """A single preset with the given envelope."""
    return Timeline([Segment(preset(name), start, attack, hold, release)])


def thesis_sequence(*, each: float = 1.6, overlap: float = 0.3) -> Timeline:
    """Fig. 6.16: smile -> laugh -> surprise -> angry -> sad, each ramping into the next."""
    segs = []
    t = 0.2
    for name in ("smile", "laugh", "surprise", "angry", "sad"):
        segs.append(Segment(preset(name), t, overlap, each - 2 * overlap, overlap))
        t += each - overlap
    return Timeline(segs)


def _num(src, d, key, default, *, signed=False):
    v = d.get(key, default)
    if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or (v < 0 and not signed):
        raise InputError(f"{src}: {key} must be a {'finite' if signed else 'non-negative'} number, got {v!r}")
    return float(v)


def load_sequence(path: str | os.PathLike) -> Timeline:
    """Read a sequence file.

    Format (JSON)::

        {"segments": [
            {"expression": "smile", "start": 0.0, "attack": 0.3, "hold": 1.0, "release": 0.3, "weight": 1.0},
            {"expression": {"muscles": {"zygomatic_major": 0.5, "corrugator_L": 0.2}, "jaw_deg": 10},
             "start": 1.5}
        ]}

    ``expression`` is a preset name, a blend ``{"blend": {"smile": 0.5, "surprise": 0.5}}`` or
    explicit muscles with optional ``jaw_deg`` / ``jaw_side_deg``.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such sequence file")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(data, dict) or not isinstance(data.get("segments"), list) or not data["segments"]:
        raise InputError(f'{path}: expected {{"segments": [...]}} with at least one segment')
    segs = []
    for i, s in enumerate(data["segments"]):
        src = f"{path}: segment {i}"
        if not isinstance(s, dict) or "expression" not in s:
            raise InputError(f"{src}: expected an object with an 'expression'")
        e = s["expression"]
        if isinstance(e, str):
            expr = preset(e)
        elif isinstance(e, dict) and "blend" in e:
            if not isinstance(e["blend"], dict) or not e["blend"]:
                raise InputError(f'{src}: blend must be an object {{"preset": weight, ...}}')
            expr = blend({str(k): _num(src, e["blend"], k, 0.0, signed=True) for k in e["blend"]})
        elif isinstance(e, dict) and "muscles" in e:
            if not isinstance(e["muscles"], dict):
                raise InputError(f'{src}: muscles must be an object {{"muscle": activation, ...}}')
            expr = Expression(f"segment{i}", dict(e["muscles"]), math.radians(_num(src, e, "jaw_deg", 0.0)),
                              math.radians(_num(src, e, "jaw_side_deg", 0.0, signed=True)))
        else:
            raise InputError(f"{src}: expression must be a preset name, a blend or muscles")
        segs.append(Segment(expr, _num(src, s, "start", 0.0), _num(src, s, "attack", 0.3), _num(src, s, "hold", 1.0),
                            _num(src, s, "release", 0.3), _num(src, s, "weight", 1.0)))
    return Timeline(segs)


def timeline_from_spec(expression: str, seconds: float) -> Timeline:
    """The timeline of ``expression`` over ``seconds`` [s].

    Args:
        expression: A preset name (:data:`PRESETS`; attack and release of up to 0.3 s, held in
            between), ``"sequence"`` (the Fig. 6.16 sequence spread over the time) or the path
            of a sequence ``.json`` file (:func:`load_sequence`).
        seconds: Length of the animation [s], > 0.
    """
    if not (isinstance(seconds, (int, float)) and math.isfinite(seconds) and seconds > 0):
        raise InputError(f"seconds: expected a positive finite number, got {seconds!r}")
    if expression in PRESETS:
        ramp = min(0.3, seconds / 4)
        return timeline_for(expression, attack=ramp, hold=max(seconds - 2 * ramp - 0.1, 0.0), release=ramp, start=0.05)
    if expression == "sequence":
        return thesis_sequence(each=max(seconds / 5 + 0.3, 0.8))
    p = Path(expression)
    if p.suffix.lower() == ".json" or p.exists():
        return load_sequence(p)
    raise InputError(f"expression {expression!r}: not a preset ({', '.join(PRESETS)}), 'sequence', or a sequence .json file")
