"""Expressions: Table 6.4 presets, envelopes, blends, sequences and their errors."""

from __future__ import annotations

import json
import math

import pytest

from facewarp import MUSCLES, PRESETS, InputError, Segment, Timeline, blend, load_sequence, preset, thesis_sequence


def test_table_6_4_exact():
    assert len(MUSCLES) == 14 and MUSCLES[0] == "zygomatic_major" and MUSCLES[12] == "orbicularis_oris"
    assert PRESETS["smile"].activations == {"zygomatic_major": 0.3, "zygomatic_minor": 0.1, "levator_anguli_oris": 0.2}
    assert PRESETS["laugh"].jaw_u == pytest.approx(math.pi / 6)
    assert PRESETS["angry"].jaw_u == pytest.approx(math.pi / 12)
    assert PRESETS["sad"].activation("corrugator") == 0.6 and PRESETS["sad"].activation("frontalis_inner") == 0.4
    assert PRESETS["surprise"].activation("mentalis") == 0.3


def test_envelope_and_blend():
    seg = Segment(preset("smile"), start=1.0, attack=0.5, hold=1.0, release=0.5)
    assert seg.envelope(0.9) == 0 and seg.envelope(1.25) == pytest.approx(0.5) and seg.envelope(2.0) == 1
    assert seg.envelope(3.0) == 0 and seg.end == 3.0
    tl = Timeline([seg, Segment(preset("smile"), start=1.0, attack=0.5, hold=1.0, release=0.5)])
    assert tl.sample(2.0).activation("zygomatic_major") == pytest.approx(0.6)
    b = blend({"smile": 0.5, "surprise": 0.5})
    assert b.activation("zygomatic_major") == pytest.approx(0.15) and b.jaw_u == pytest.approx(math.pi / 12)


def test_thesis_sequence_order():
    tl = thesis_sequence()
    names = [s.expression.name for s in tl.segments]
    assert names == ["smile", "laugh", "surprise", "angry", "sad"]
    mid = [(s.start + s.attack + 0.5 * s.hold) for s in tl.segments]
    assert tl.sample(mid[0]).activation("zygomatic_major") == pytest.approx(0.3)
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
