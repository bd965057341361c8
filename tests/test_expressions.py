"""Expressions: Table 6.4 presets, envelopes, blends, sequences and their errors."""

from __future__ import annotations

import json

import pytest

import facewarp
from facewarp import MUSCLES, PRESETS, InputError, Timeline, preset, thesis_sequence
from facewarp.expressions import Segment, blend, load_sequence


def test_table_6_4_exact():
    assert len(MUSCLES) == 14 and MUSCLES[0] == "zygomatic_major" and MUSCLES[12] == "orbicularis_oris"
    # Table 6.4 as calibrated in issue 12 (old values recorded in muscle_defs.json)
    assert PRESETS["smile"].activations == {"zygomatic_major": 0.6, "zygomatic_minor": 0.1, "levator_anguli_oris": 0.2}
    assert PRESETS["laugh"].jaw_drop_m == pytest.approx(0.022) and PRESETS["angry"].jaw_u == 0.0
    assert PRESETS["laugh"].jaw_u == pytest.approx(0.022 / facewarp.expressions.REFERENCE_JAW_LEVER)
    assert PRESETS["sad"].activation("corrugator") == 0.6 and PRESETS["sad"].activation("frontalis_inner") == 1.0
    assert PRESETS["surprise"].activation("mentalis") == 0.3
    assert PRESETS["surprise"].activation("frontalis_major") == 0.2
    assert PRESETS["sad"].activation("depressor_anguli_oris") == 0.5  # Table 6.4's value (two-way anchors)
    assert PRESETS["laugh"].activation("zygomatic_major") == 1.0 and PRESETS["laugh"].activation("risorius") == 0.3
    for name in ("blink", "squint", "pucker", "press", "jaw_open", "smile_L", "smile_R"):
        assert name in PRESETS


def test_chin_drop_converts_per_head():
    # a 50 mm lever turns a 10 mm chin drop into 0.2 rad; longer levers need smaller angles
    assert facewarp.expressions.jaw_angle_for_drop(0.05, 0.01) == pytest.approx(0.2)
    e = PRESETS["surprise"].for_head(0.12)
    assert e.jaw_u == pytest.approx(0.012 / 0.12) and e.jaw_drop_m == PRESETS["surprise"].jaw_drop_m
    tl = Timeline([Segment(PRESETS["laugh"], 0.0, 0.1, 1.0, 0.1)]).for_head(0.11)
    assert tl.sample(0.5).jaw_u == pytest.approx(0.022 / 0.11)
    assert PRESETS["smile"].for_head(0.11) is PRESETS["smile"]  # no chin drop: unchanged
    with pytest.raises(InputError, match="lever"):
        facewarp.expressions.jaw_lever(-1.0)
    with pytest.raises(InputError, match="drop_m"):
        facewarp.expressions.jaw_angle_for_drop(0.1, -0.01)


def test_expression_from_activations():
    e = facewarp.expressions.expression_from_activations("zygomatic_major_L=0.8, corrugator=0.2,jaw_drop_mm=12")
    assert e.activation("zygomatic_major", "L") == 0.8 and e.activation("zygomatic_major", "R") == 0.0
    assert e.activation("corrugator") == 0.2 and e.jaw_drop_m == pytest.approx(0.012)
    tl = facewarp.expressions.timeline_from_spec("frontalis_inner=0.5", 1.0)
    assert tl.sample(0.5).activation("frontalis_inner") == pytest.approx(0.5)
    for bad, msg in (("", "empty"), ("zygomatic_major", "muscle=number"), ("zygomatic_major=x", "muscle=number"),
                     ("nose=0.5", "unknown muscle"), ("corrugator=1.5", r"\[0, 1\]"),
                     ("jaw_drop_mm=-3", "jaw_drop_mm")):
        with pytest.raises(InputError, match=msg):
            facewarp.expressions.expression_from_activations(bad)


def test_envelope_and_blend():
    seg = Segment(preset("smile"), start=1.0, attack=0.5, hold=1.0, release=0.5)
    assert seg.envelope(0.9) == 0 and seg.envelope(1.25) == pytest.approx(0.5) and seg.envelope(2.0) == 1
    assert seg.envelope(3.0) == 0 and seg.end == 3.0
    tl = Timeline([seg, Segment(preset("smile"), start=1.0, attack=0.5, hold=1.0, release=0.5)])
    assert tl.sample(2.0).activation("zygomatic_major") == pytest.approx(1.0)  # 0.6 + 0.6, clamped
    b = blend({"smile": 0.5, "surprise": 0.5})
    assert b.activation("zygomatic_major") == pytest.approx(0.3) and b.jaw_drop_m == pytest.approx(0.006)


def test_thesis_sequence_order():
    tl = thesis_sequence()
    names = [s.expression.name for s in tl.segments]
    assert names == ["smile", "laugh", "surprise", "angry", "sad"]
    mid = [(s.start + s.attack + 0.5 * s.hold) for s in tl.segments]
    assert tl.sample(mid[0]).activation("zygomatic_major") == pytest.approx(0.6)
    assert tl.sample(mid[4]).activation("corrugator") == pytest.approx(0.6)


def test_load_sequence(tmp_path):
    p = tmp_path / "seq.json"
    p.write_text(json.dumps({"segments": [{"expression": "smile"}, {"expression": {"muscles": {"corrugator_L": 0.5},
                                                                                  "jaw_deg": 10}, "start": 2}]}))
    tl = load_sequence(p)
    assert len(tl.segments) == 2 and tl.segments[1].expression.activation("corrugator", "L") == 0.5
    assert tl.segments[1].expression.activation("corrugator", "R") == 0.0
    for bad, needle in [({"segments": [{"expression": "grin"}]}, "grin"),
                        ({"segments": [{"expression": {"muscles": {"biceps": 1}}}]}, "biceps"),
                        ({"segments": [{"expression": {"muscles": {"nasalis": 2}}}]}, "nasalis"),
                        ({"segments": [{"expression": "smile", "hold": -1}]}, "hold"),
                        ({"segments": []}, "segments")]:
        p.write_text(json.dumps(bad))
        with pytest.raises(InputError, match=needle):
            load_sequence(p)
    p.write_text("{")
    with pytest.raises(InputError, match="JSON"):
        load_sequence(p)
