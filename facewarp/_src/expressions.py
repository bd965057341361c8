"""Facial expressions: Table 6.4 presets, activation envelopes over time, blends and sequences.

A muscle is named by its Table 6.2 name (``MUSCLES``); paired muscles take the same activation on
both sides unless a side-specific key (``"zygomatic_major_L"``) overrides it. Jaw angles are in
radians: ``jaw_u`` opens the mouth about the axis through the condyles (Sec. 6.4.3, 0..60 deg),
``jaw_v`` turns the mandible about the vertical axis (+-5 deg).

Presets give the opening as a *chin drop* ``jaw_drop_m`` [m]: the arc the chin (FDP 2.1) travels
about the condyle u-axis. A head turns it into its own angle with its condyle-to-chin lever
(:func:`jaw_lever`, the distance of the rest chin from the u-axis): ``angle = drop / lever``
(:func:`jaw_angle_for_drop`, :meth:`Expression.for_head`, :meth:`Timeline.for_head`). Until an
expression is converted for a head its ``jaw_u`` uses :data:`REFERENCE_JAW_LEVER` (0.1 m), the
lever Table 6.4 was written for: its pi/6 is a 52 mm chin drop there, near the widest human
opening, so the presets use human-sized drops instead (laugh 22 mm, surprise 12 mm, angry none).

A :class:`Timeline` holds segments (an expression with attack, hold and release times and a
weight); sampling it at a time gives the activations and jaw angles to feed the solver's Control.
Overlapping segments add (a blend) and activations are clamped to [0, 1].
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .core.errors import InputError

__all__ = [
    "MUSCLES",
    "muscle_base",
    "muscle_instances",
    "PRESETS",
    "JAW_U_MAX",
    "JAW_V_MAX",
    "REFERENCE_JAW_LEVER",
    "Expression",
    "Segment",
    "Timeline",
    "blend",
    "expression_from_activations",
    "jaw_angle_for_drop",
    "jaw_lever",
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

def muscle_base(name: str, *, what: str | None = "muscles") -> str:
    """The Table 6.2 muscle ``name`` refers to: the name itself (a bare name means both sides) or,
    for ``NAME_L`` / ``NAME_R`` (one side), ``NAME``. The one muscle-name rule of every input that
    takes muscle names (``--muscles``, ``--activations``, sequence files, rigs); see
    :func:`muscle_instances` for the names of a built head.

    Raises:
        InputError: ``name`` is no Table 6.2 muscle, alone or with a side.
    """
    key = str(name).strip()
    base = key[:-2] if key.endswith(("_L", "_R")) else key
    if base not in MUSCLES:
        raise InputError(f"{what + ': ' if what else ''}unknown muscle {key!r} (a Table 6.2 name means both sides, "
                         f"NAME_L or NAME_R one side; known: {', '.join(MUSCLES)})")
    return base


def muscle_instances(name: str, instances, *, what: str = "muscles") -> list[str]:
    """The muscle instances of a head that ``name`` means, by :func:`muscle_base`'s rule: the
    instance of that name (``"zygomatic_major_L"``, an unpaired ``"orbicularis_oris"``), else both
    sides (``"zygomatic_major"`` -> ``["zygomatic_major_L", "zygomatic_major_R"]``), in
    ``instances`` order.

    Args:
        name: A muscle name as a user wrote it.
        instances: The head's muscle instance names (M,), e.g. ``FaceSimulator.muscle_names``.

    Raises:
        InputError: ``name`` means no instance of ``instances``.
    """
    key = str(name).strip()
    hits = [n for n in instances if n == key] or [n for n in instances if n.endswith(("_L", "_R")) and n[:-2] == key]
    if not hits:
        raise InputError(f"{what}: unknown muscle {key!r} (a Table 6.2 name means both sides, NAME_L or NAME_R one "
                         f"side; known: {', '.join(sorted(set(instances)))})")
    return hits


JAW_U_MAX = math.radians(60.0)
JAW_V_MAX = math.radians(5.0)
REFERENCE_JAW_LEVER = 0.1
"""Condyle-to-chin lever [m] that converts a chin drop into an angle before a head is known."""


def jaw_lever(rig) -> float:
    """Condyle-to-chin lever [m] of a head: distance of its rest chin (FDP 2.1) from the u-axis.

    Args:
        rig: A :class:`~facewarp.FaceRig` (its ``jaw_pivot``, ``jaw_u``, FDP surface points on
            ``head_vertices``), or a lever [m] (a positive number, returned as is).

    Raises:
        InputError: a non-positive lever, or a rig without the chin FDP 2.1.
    """
    if isinstance(rig, (int, float)) and not isinstance(rig, bool):
        if not (math.isfinite(rig) and rig > 0):
            raise InputError(f"rig: a lever must be a positive length [m], got {rig!r}")
        return float(rig)
    if hasattr(rig, "fr") and not hasattr(rig, "fdp_ids"):  # a FaceSimulator
        rig = rig.fr
    for a in ("fdp_ids", "fdp_part", "fdp_face", "fdp_bary", "head_vertices", "head_faces", "jaw_pivot", "jaw_u"):
        if not hasattr(rig, a):
            raise InputError(f"rig: expected a FaceRig, a FaceSimulator or a lever [m], got {type(rig).__name__}")
    ids = [str(k) for k in rig.fdp_ids]
    if "2.1" not in ids or str(rig.fdp_part[ids.index("2.1")]) != "head":
        raise InputError("rig: the head has no chin FDP 2.1 on its skin")
    i = ids.index("2.1")
    tri = np.asarray(rig.head_vertices, np.float64)[rig.head_faces[rig.fdp_face[i]]]
    chin = np.asarray(rig.fdp_bary[i], np.float64) @ tri
    u = np.asarray(rig.jaw_u, np.float64)
    u = u / np.linalg.norm(u)
    d = chin - np.asarray(rig.jaw_pivot, np.float64)
    lever = float(np.linalg.norm(d - (d @ u) * u))
    if not lever > 1e-3:
        raise InputError(f"rig: the chin lies on the jaw axis (lever {lever:.2e} m)")
    return lever


def jaw_angle_for_drop(rig, drop_m: float) -> float:
    """Jaw opening angle [rad] that moves the chin (FDP 2.1) of ``rig`` by ``drop_m`` [m] along
    its arc about the condyle u-axis: ``drop_m / jaw_lever(rig)``, clipped to 0..60 deg.

    Args:
        rig: A FaceRig, a FaceSimulator or a lever [m] (:func:`jaw_lever`).
        drop_m: Chin drop [m], >= 0.
    """
    if not (isinstance(drop_m, (int, float)) and math.isfinite(drop_m) and drop_m >= 0):
        raise InputError(f"drop_m: expected a non-negative chin drop [m], got {drop_m!r}")
    return float(min(drop_m / jaw_lever(rig), JAW_U_MAX))


@dataclass(frozen=True)
class Expression:
    """Muscle activations in [0, 1] (name -> value; missing muscles are 0) and jaw angles [rad].

    ``jaw_drop_m`` [m], when given, is the opening as a chin drop; ``jaw_u`` is then derived from
    it (with :data:`REFERENCE_JAW_LEVER` until :meth:`for_head` uses a head's own lever).
    """

    name: str
    activations: dict = field(default_factory=dict)
    jaw_u: float = 0.0
    jaw_v: float = 0.0
    jaw_drop_m: float | None = None

    def __post_init__(self):
        if self.jaw_drop_m is not None:
            d = self.jaw_drop_m
            if not (isinstance(d, (int, float)) and math.isfinite(d) and d >= 0):
                raise InputError(f"expression {self.name!r}: jaw_drop_m must be a non-negative length [m], got {d!r}")
            if self.jaw_u == 0.0:
                object.__setattr__(self, "jaw_u", float(min(d / REFERENCE_JAW_LEVER, JAW_U_MAX)))
        for k, v in self.activations.items():
            muscle_base(k, what=f"expression {self.name!r}")
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

    def for_head(self, rig) -> Expression:
        """This expression with ``jaw_u`` computed from its chin drop by the lever of ``rig``
        (a FaceRig, a FaceSimulator or a lever [m]); unchanged without a chin drop."""
        if self.jaw_drop_m is None:
            return self
        return replace(self, jaw_u=jaw_angle_for_drop(rig, float(self.jaw_drop_m)))


def _table_6_4(name, values, jaw_drop_m):
    return Expression(name, {m: v for m, v in zip(MUSCLES, values) if v}, jaw_drop_m=jaw_drop_m)


# Table 6.4: activations of muscles 01..12. Its u-axis jaw rotations (laugh and surprise pi/6,
# angry pi/12) are chin drops of 52 and 26 mm on a 0.1 m lever, near the widest human opening;
# they are replaced by human-sized chin drops (laugh 10-25 mm, surprise 5-15 mm, angry none),
# converted per head by its lever (:meth:`Expression.for_head`). With the muscles calibrated to
# the recorded human rig (activation 1.0 = the full-weight ICT blendshape, ``muscle_defs.json``;
# activation maps to contraction through the saturating curve of ``activation_curve`` there),
# some printed activations gave shapes outside the issue-12 targets and were replaced; the old
# and new values and the reasons are in ``muscle_defs.json`` under ``preset_changes``.
PRESETS: dict[str, Expression] = {
    "neutral": Expression("neutral"),
    #                          01   02   03   04   05   06   07   08   09   10   11   12
    "smile": _table_6_4("smile", (0.6, 0.1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0.2), None),
    "laugh": _table_6_4("laugh", (1.0, 0.2, 0, 0.3, 0, 0.2, 0, 0, 0, 0, 0, 0.1), 0.022),
    "surprise": _table_6_4("surprise", (0, 0, 0, 0, 0.3, 0.3, 0, 1.0, 0.2, 0.3, 0, 0), 0.012),
    "angry": _table_6_4("angry", (0, 0, 0.3, 0.2, 0, 0.5, 1.0, 0, 0, 0, 0.4, 0), None),
    "sad": _table_6_4("sad", (0, 0, 0.5, 0, 0, 0, 0.6, 1.0, 0.1, 0, 0, 0), None),
    # Beyond Table 6.4 (named activation sets). The sphincters act by themselves: the orbicularis
    # oculi closes the lids (blink; squint half-way with the brows and cheeks), the orbicularis
    # oris narrows and purses the mouth (pucker, with the mentalis pushing the lower lip up and
    # out) or, lightly, presses the lips together (press: they touch, the lip contact holds them).
    "blink": Expression("blink", {"orbicularis_oculi": 1.0}),
    "squint": Expression("squint", {"orbicularis_oculi": 0.3, "corrugator": 0.2, "zygomatic_minor": 0.2}),
    "pucker": Expression("pucker", {"orbicularis_oris": 0.8, "mentalis": 0.3}),
    "press": Expression("press", {"orbicularis_oris": 0.4}),
    "jaw_open": Expression("jaw_open", jaw_drop_m=0.020),
    "smile_L": Expression("smile_L", {"zygomatic_major_L": 0.6, "zygomatic_minor_L": 0.1,
                                          "levator_anguli_oris_L": 0.2}),
    "smile_R": Expression("smile_R", {"zygomatic_major_R": 0.6, "zygomatic_minor_R": 0.1,
                                          "levator_anguli_oris_R": 0.2}),
}
"""The preset expressions by name: Table 6.4's smile, laugh, surprise, angry and sad, and blink,
squint, pucker, jaw_open, smile_L and smile_R (activations calibrated to the ICT rig)."""


def preset(name: str) -> Expression:
    """A preset expression by name (:data:`PRESETS`: Table 6.4's smile, laugh, surprise, angry,
    sad and the named activation sets).

    Args:
        name: The preset's name, e.g. ``"smile"``.

    Returns:
        The :class:`Expression` (activations per muscle in [0, 1], jaw angles [rad]).

    Raises:
        InputError: an unknown name (the message lists the known ones).
    """
    from .core.checks import check_name

    check_name("name", name)
    try:
        return PRESETS[name]
    except KeyError:
        raise InputError(f"expression: unknown preset {name!r} (known: {', '.join(PRESETS)})") from None


def blend(weights: dict[str, float], *, name: str | None = None) -> Expression:
    """Weighted sum of presets (name -> weight), activations clamped to [0, 1]."""
    from .core.checks import check_mapping

    check_mapping("weights", weights)
    acts: dict[str, float] = {}
    ju = jv = drop = 0.0
    for pname, w in weights.items():
        e = preset(pname)
        for k, v in e.activations.items():
            acts[k] = acts.get(k, 0.0) + w * v
        ju += w * e.jaw_u
        jv += w * e.jaw_v
        drop += w * (e.jaw_u * REFERENCE_JAW_LEVER if e.jaw_drop_m is None else e.jaw_drop_m)
    acts = {k: float(np.clip(v, 0.0, 1.0)) for k, v in acts.items()}
    return Expression(name or "+".join(f"{w:g}*{k}" for k, w in weights.items()), acts,
                      float(np.clip(ju, 0.0, JAW_U_MAX)), float(np.clip(jv, -JAW_V_MAX, JAW_V_MAX)),
                      jaw_drop_m=max(drop, 0.0) if any(preset(p).jaw_drop_m is not None for p in weights) else None)


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
    """Segments over time; :meth:`sample` gives activations and jaw angles at a time.

    Attributes:
        segments: The segments; overlapping ones add.
        lever: The condyle-to-chin lever [m] the chin drops were converted with
            (:meth:`for_head`); None until then.
    """

    segments: list[Segment]
    lever: float | None = None

    @classmethod
    def held(cls, expression: Expression, seconds: float, *, start: float = 0.05) -> Timeline:
        """``expression`` over ``seconds`` [s]: from ``start`` it ramps up over up to 0.3 s (a
        quarter of the time at most), holds, and ramps down to end 0.05 s before ``seconds``
        (the envelope ``facewarp simulate`` gives a preset or ``--activations``).

        Raises:
            InputError: ``expression`` not an :class:`Expression`, ``seconds`` not a finite number > 0.
        """
        if not isinstance(expression, Expression):
            raise InputError(f"expression: expected a facewarp Expression, got {type(expression).__name__}")
        if not (isinstance(seconds, (int, float)) and not isinstance(seconds, bool) and math.isfinite(seconds)
                and seconds > 0):
            raise InputError(f"seconds: expected a positive finite number, got {seconds!r}")
        ramp = min(0.3, seconds / 4)
        return cls([Segment(expression, start, ramp, max(seconds - 2 * ramp - 0.1, 0.0), ramp)])

    @property
    def duration(self) -> float:
        return max((s.end for s in self.segments), default=0.0)

    def for_head(self, rig) -> Timeline:
        """The timeline with every chin drop turned into the jaw angle of ``rig`` (a FaceRig, a
        FaceSimulator or a lever [m]; :meth:`Expression.for_head`), its :attr:`lever` set; this
        timeline itself when it has no chin drop or is already converted with that lever.
        :func:`~facewarp.play` converts the timeline it is given."""
        if all(s.expression.jaw_drop_m is None for s in self.segments):
            return self
        lever = jaw_lever(rig)
        if self.lever == lever:
            return self
        return Timeline([replace(s, expression=s.expression.for_head(lever)) for s in self.segments], lever)

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
    from .core.checks import check_name

    check_name("name", name)
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
    explicit muscles with optional ``jaw_deg`` or ``jaw_drop_mm`` (chin drop [mm], converted per
    head) and ``jaw_side_deg``. Unknown keys are refused; every error names the file and the
    segment.
    """
    from .core.checks import check_path

    check_path("path", path)
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
        try:
            segs.append(_load_segment(src, i, s))
        except InputError as err:  # from Expression / preset: name the file and the segment
            text = str(err)
            raise InputError(text if text.startswith(src) else f"{src}: {text}") from None
    return Timeline(segs)


SEGMENT_KEYS = ("expression", "start", "attack", "hold", "release", "weight")
"""Keys of a segment of a sequence file."""
MUSCLES_KEYS = ("muscles", "jaw_deg", "jaw_drop_mm", "jaw_side_deg")
"""Keys of an expression given by its muscles in a sequence file."""


def _unknown_keys(src: str, d: dict, known) -> None:
    extra = [k for k in d if k not in known]
    if extra:
        raise InputError(f"{src}: unknown key {extra[0]!r} (expected {', '.join(known)})")


def _load_segment(src: str, i: int, s) -> Segment:
    """Segment ``i`` of a sequence file (see :func:`load_sequence`); ``src`` names it in errors."""
    if not isinstance(s, dict) or "expression" not in s:
        raise InputError(f"{src}: expected an object with an 'expression'")
    _unknown_keys(src, s, SEGMENT_KEYS)
    e = s["expression"]
    if isinstance(e, str):
        expr = preset(e)
    elif isinstance(e, dict) and "blend" in e:
        _unknown_keys(f"{src}: expression", e, ("blend",))
        if not isinstance(e["blend"], dict) or not e["blend"]:
            raise InputError(f'{src}: blend must be an object {{"preset": weight, ...}}')
        expr = blend({str(k): _num(src, e["blend"], k, 0.0, signed=True) for k in e["blend"]})
    elif isinstance(e, dict) and "muscles" in e:
        _unknown_keys(f"{src}: expression", e, MUSCLES_KEYS)
        if not isinstance(e["muscles"], dict):
            raise InputError(f'{src}: muscles must be an object {{"muscle": activation, ...}}')
        if "jaw_deg" in e and "jaw_drop_mm" in e:
            raise InputError(f"{src}: give jaw_deg or jaw_drop_mm, not both")
        drop = _num(src, e, "jaw_drop_mm", 0.0) * 1e-3 if "jaw_drop_mm" in e else None
        expr = Expression(f"segment{i}", dict(e["muscles"]), math.radians(_num(src, e, "jaw_deg", 0.0)),
                          math.radians(_num(src, e, "jaw_side_deg", 0.0, signed=True)), jaw_drop_m=drop)
    else:
        raise InputError(f"{src}: expression must be a preset name, a blend or muscles")
    return Segment(expr, _num(src, s, "start", 0.0), _num(src, s, "attack", 0.3), _num(src, s, "hold", 1.0),
                   _num(src, s, "release", 0.3), _num(src, s, "weight", 1.0))


def expression_from_activations(spec: str, *, name: str = "activations") -> Expression:
    """A user's own expression from ``"muscle=value,..."``.

    Muscles are Table 6.2 names (both sides) or instance names (``zygomatic_major_L``) with an
    activation in [0, 1]; ``jaw_drop_mm=D`` (chin drop [mm], converted per head) and
    ``jaw_deg=A`` / ``jaw_side_deg=A`` (angles) set the jaw.

    Raises:
        InputError: an empty spec, an item without ``=``, a non-number, an unknown muscle or a
            value out of range.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise InputError("activations: expected 'muscle=value,...', got an empty string")
    acts: dict[str, float] = {}
    jaw: dict[str, float] = {}
    for item in spec.split(","):
        if not item.strip():
            continue
        key, eq, val = item.partition("=")
        key = key.strip()
        try:
            v = float(val)
        except ValueError:
            v = float("nan")
        if not eq or not key or not math.isfinite(v):
            raise InputError(f"activations: expected 'muscle=number' items, got {item.strip()!r}")
        if key in ("jaw_drop_mm", "jaw_deg", "jaw_side_deg"):
            jaw[key] = v
        else:
            acts[key] = v
    if "jaw_drop_mm" in jaw and "jaw_deg" in jaw:
        raise InputError("activations: give the jaw as jaw_drop_mm or jaw_deg, not both")
    if jaw.get("jaw_drop_mm", 0.0) < 0:
        raise InputError(f"activations: jaw_drop_mm must be >= 0, got {jaw['jaw_drop_mm']:g}")
    drop = jaw["jaw_drop_mm"] * 1e-3 if "jaw_drop_mm" in jaw else None
    return Expression(name, acts, math.radians(jaw.get("jaw_deg", 0.0)), math.radians(jaw.get("jaw_side_deg", 0.0)),
                      jaw_drop_m=drop)


def timeline_from_spec(expression: str, seconds: float) -> Timeline:
    """The timeline of ``expression`` over ``seconds`` [s].

    Args:
        expression: A preset name (:data:`PRESETS`; attack and release of up to 0.3 s, held in
            between), explicit muscles ``"muscle=value,..."`` (:func:`expression_from_activations`,
            the same envelope), ``"sequence"`` (the Fig. 6.16 sequence spread over the time) or the path
            of a sequence ``.json`` file (:func:`load_sequence`).
        seconds: Length of the animation [s], > 0.
    """
    if not isinstance(expression, (str, os.PathLike)):
        raise InputError(f"expression: expected a preset name, 'sequence', a sequence file or 'muscle=value,...', "
                         f"got {type(expression).__name__}")
    expression = os.fspath(expression)
    if not (isinstance(seconds, (int, float)) and math.isfinite(seconds) and seconds > 0):
        raise InputError(f"seconds: expected a positive finite number, got {seconds!r}")
    if expression in PRESETS:
        return Timeline.held(preset(expression), seconds)
    if expression == "sequence":
        return thesis_sequence(each=max(seconds / 5 + 0.3, 0.8))
    if "=" in expression and not expression.lower().endswith(".json"):  # muscle=value,... (a user's own)
        return Timeline.held(expression_from_activations(expression), seconds)
    p = Path(expression)
    if p.suffix.lower() == ".json" or p.exists():
        return load_sequence(p)
    raise InputError(f"expression {expression!r}: not a preset ({', '.join(PRESETS)}), 'sequence', "
                     "a sequence .json file or 'muscle=value,...'")
