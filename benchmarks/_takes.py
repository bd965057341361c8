"""Recordings that look real, made here: what Live Link Face, MediaPipe's Face Landmarker and a
mocap lab write, with their oddities (our own generator; the layouts from the apps' public docs).

* :func:`arkit_curves`: smooth random ARKit curves, a few shapes at a time, EyeLookIn peaking to 1.05.
* :func:`write_livelink`: a Live Link Face CSV: ``Timecode, BlendShapeCount`` (or ``BlendshapeCount``),
  the 52 ARKit columns in Live Link's order (capitalised, or other cases), ``HeadYaw, HeadPitch,
  HeadRoll``, the six eye angles; a 30 fps take on a 60 fps timecode that drops frames (steps of 2 to
  8 timecode frames), timecodes with the sub-frame fraction.
* :func:`write_mediapipe`: MediaPipe Face Landmarker output: 52 categories, ``_neutral`` then the 51
  ARKit names in MediaPipe's (alphabetical) order, no ``tongueOut``; layouts ``tasks`` (Python
  Tasks API dump), ``js`` (JavaScript), ``people`` (``{"people": [[{"name", "score"}]]}``),
  ``flat`` (one flat list of categories per frame), ``lists`` (per-frame lists, no timestamps);
  scores as numbers or strings; timestamps in whole milliseconds, float ms or microseconds.
* :func:`marker_take`: a marker take of an actor (another head than the one driven): the actor's
  simulated FDPs, rigid head motion (a slow nod and turn, the actor standing), in centimetres with
  y up, noise and dropouts (NaN), about 41 markers.

Only the public API is used.
"""

from __future__ import annotations

import csv
import json

import numpy as np

MARKERS_41 = ("2.1", "2.10", "2.11", "2.12", "2.13", "2.14",  # chin and jaw
              "8.1", "8.2", "8.3", "8.4", "8.5", "8.6", "8.7", "8.8",  # outer lips
              "4.1", "4.2", "4.3", "4.4", "4.5", "4.6",  # brows
              "3.7", "3.8", "3.11", "3.12", "3.9", "3.10",  # eye corners and lower lids
              "5.1", "5.2", "5.3", "5.4",  # cheeks
              "9.1", "9.2", "9.3",  # nose
              "11.1", "11.2", "11.3", "9.6", "9.7", "9.12", "10.9", "10.10")  # stable: forehead, nose bridge, ears
"""A 41-marker facial set as a lab places it (FDP ids; markers on skin, none on the eyes or inner lips)."""


def arkit_curves(seconds: float, fps: float, rng, *, active: int = 10, knot_s: float = 0.4,
                 over: float = 0.05) -> np.ndarray:
    """(T, 52) smooth random weights in ARKIT_NAMES order: ``active`` shapes, each a monotone cubic
    through random knots (0 at the start); eyeLookIn* peak to ``1 + over`` as real takes do."""
    import facewarp as fw
    from scipy.interpolate import PchipInterpolator

    T = int(round(seconds * fps)) + 1
    t = np.arange(T) / fps
    knots = np.arange(0.0, t[-1] + knot_s, knot_s)
    W = np.zeros((T, 52))
    names = list(fw.ARKIT_NAMES)
    pick = rng.choice([i for i, n in enumerate(names) if n != "tongueOut"], size=active, replace=False)
    for i in pick:
        v = rng.uniform(0.0, rng.uniform(0.4, 1.0), len(knots))
        v[0] = 0.0
        W[:, i] = np.clip(PchipInterpolator(knots, v)(t), 0.0, 1.0)
    bump = (1.0 + over) * np.exp(-((t - t[-1] * 0.6) / 0.1) ** 2)  # a look to the nose, past 1 at its peak
    for n in ("eyeLookInLeft", "eyeLookInRight"):
        i = names.index(n)
        W[:, i] = np.maximum(W[:, i], bump)
    return W


def livelink_columns(case: str = "title", count_header: str = "BlendShapeCount") -> list:
    import facewarp as fw

    def spell(n):
        return {"title": n[0].upper() + n[1:], "camel": n, "lower": n.lower(), "upper": n.upper()}[case]

    return ["Timecode", count_header, *(spell(n) for n in fw.ARKIT_NAMES), "HeadYaw", "HeadPitch", "HeadRoll",
            "LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll", "RightEyeYaw", "RightEyePitch", "RightEyeRoll"]


def dropped_frames(T: int, rng, *, drop: float = 0.15, max_step: int = 4) -> np.ndarray:
    """The frames a take kept: steps of 1 (mostly) to ``max_step`` data frames."""
    keep = [0]
    while True:
        step = 1 if rng.uniform() > drop else int(rng.integers(2, max_step + 1))
        if keep[-1] + step >= T:
            break
        keep.append(keep[-1] + step)
    if keep[-1] != T - 1:
        keep.append(T - 1)
    return np.array(keep)


def write_livelink(path, W, fps: float, rng, *, timecode_rate: int = 60, drop: bool = True,
                   count_header: str = "BlendShapeCount", case: str = "title", head=None, eyes=None,
                   start_tc=(17, 32, 41, 15)) -> np.ndarray:
    """Write ``W`` (T, 52) as a Live Link Face CSV; returns the data frames kept (T',) (all, or
    with frames dropped: timecode steps of 2-8 at 60 for a 30 fps take)."""
    T = len(W)
    keep = dropped_frames(T, rng) if drop else np.arange(T)
    head = np.zeros((T, 3)) if head is None else head
    eyes = np.zeros((T, 6)) if eyes is None else eyes
    h, m, s, f = start_tc
    t_start = h * 3600 + m * 60 + s + f / timecode_rate
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(livelink_columns(case, count_header))
        for k in keep:
            t = t_start + k / fps
            whole = int(np.floor(t + 1e-9))
            frac = (t - whole) * timecode_rate
            ff = int(np.floor(frac + 1e-6))
            sub = int(round((frac - ff) * 1000)) % 1000
            tc = f"{whole // 3600:02d}:{whole // 60 % 60:02d}:{whole % 60:02d}:{ff:02d}.{sub:03d}"
            w.writerow([tc, 61, *(f"{v:.6f}" for v in W[k]), *(f"{v:.6f}" for v in head[k]),
                        *(f"{v:.6f}" for v in eyes[k])])
    return keep


def mediapipe_names() -> list:
    """MediaPipe Face Landmarker's 52 categories in its order: ``_neutral``, then the ARKit names
    without tongueOut, alphabetical."""
    import facewarp as fw

    return ["_neutral", *sorted(n for n in fw.ARKIT_NAMES if n != "tongueOut")]


def write_mediapipe(path, W, fps: float, rng, *, layout: str = "tasks", stamps: str = "ms", strings: bool = False,
                    drop: bool = False, no_face: int = 0) -> np.ndarray:
    """Write ``W`` (T, 52) as MediaPipe output in ``layout``; ``stamps``: ``"ms"`` whole milliseconds
    (0, 33, 67, ...), ``"ms_float"``, ``"us"`` (microseconds under ``timestamp_ms``, as graph
    timestamps are); ``no_face`` frames in the middle have no face. Returns the data frames kept."""
    import facewarp as fw

    T = len(W)
    keep = dropped_frames(T, rng) if drop else np.arange(T)
    names = mediapipe_names()
    col = {n: list(fw.ARKIT_NAMES).index(n) for n in names[1:]}
    frames = []
    gone = set(range(T // 2, T // 2 + no_face))
    for k in keep:
        t = k / fps
        ts = {"ms": int(round(t * 1000)), "ms_float": t * 1000.0, "us": int(round(t * 1e6))}[stamps]
        scores = [float(rng.uniform(0, 1e-4))] + [float(W[k, col[n]]) for n in names[1:]]
        val = [f"{s:.7f}" if strings else s for s in scores]
        if k in gone:
            cats = []
        elif layout in ("tasks", "flat", "lists"):
            cats = [{"index": i, "score": v, "category_name": n, "display_name": ""}
                    for i, (n, v) in enumerate(zip(names, val))]
        elif layout == "js":
            cats = [{"index": i, "score": v, "categoryName": n, "displayName": ""}
                    for i, (n, v) in enumerate(zip(names, val))]
        else:
            cats = [{"name": n, "score": v} for n, v in zip(names, val)]
        if layout == "tasks":
            frames.append({"timestamp_ms": ts, "face_blendshapes": [cats] if cats else []})
        elif layout == "js":
            frames.append({"timestampMs": ts, "faceBlendshapes": [{"categories": cats, "headIndex": -1,
                                                                  "headName": ""}] if cats else []})
        elif layout == "people":
            frames.append({"timestamp_ms": ts, "people": [cats] if cats else []})
        elif layout == "flat":
            frames.append({"timestamp_ms": ts, "blendshapes": cats})
        elif layout == "lists":
            frames.append(cats)
        else:
            raise ValueError(layout)
    data = {"frames": frames} if layout == "js" else frames
    with open(path, "w") as fh:
        json.dump(data, fh)
    return keep


def random_controls(rng, frames: int, fps: float, muscles: int, *, active: float = 0.4, knot_s: float = 0.5,
                    jaw_open_deg: float = 20.0, jaw_side_deg: float = 3.0):
    """Smooth random activations (frames, M) in [0, 1] and jaw (frames, 2) [rad], 0 at frame 0
    (:func:`benchmarks._streams.smooth_performance` with peaks up to 0.9 and this jaw's ranges)."""
    from benchmarks._streams import smooth_performance

    return smooth_performance(rng, frames, fps, muscles, active_fraction=active, knot_s=knot_s,
                              jaw_open_max_deg=jaw_open_deg, jaw_side_max_deg=jaw_side_deg, peak_max=0.9)


def simulate_points(rig, A, J, fps: float, names, *, device: str = "cpu") -> np.ndarray:
    """The named points (FDP ids) of ``rig`` driven by controls A (T, M), J (T, 2): (T, K, 3) [m]
    in the head's frame; frame 0 is the rest (the take's neutral)."""
    import facewarp as fw

    sim = fw.FaceSimulator(rig, fps=fps, device=device)
    ids = [str(i) for i in rig.fdp_ids]
    cols = [ids.index(n) for n in names]
    out = [sim.fdp_points()[cols]]
    for a, j in zip(A[1:], J[1:]):
        sim.set_activations(a)
        sim.set_jaw(*j)
        sim.step()
        out.append(sim.fdp_points()[cols])
    return np.array(out, dtype=np.float64)


def head_motion(T: int, fps: float, rng, *, yaw_deg: float = 12.0, pitch_deg: float = 8.0, roll_deg: float = 4.0,
                sway_m: float = 0.02):
    """Smooth rigid head motion: rotations (T, 3, 3) and translations (T, 3) [m] about the head's
    origin, starting at identity (a slow turn, nod and tilt, a sway of the body)."""
    t = np.arange(T) / fps
    ph = rng.uniform(0, 2 * np.pi, 6)
    ang = np.radians([yaw_deg, pitch_deg, roll_deg])[None] * np.sin(2 * np.pi * np.array([0.3, 0.45, 0.2])[None]
                                                                    * t[:, None] + ph[None, :3])
    ang -= ang[:1]
    R = np.empty((T, 3, 3))
    for k, (y, p, r) in enumerate(ang):
        cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
        R[k] = (np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]]) @ np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
                @ np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]]))
    tr = sway_m * np.sin(2 * np.pi * np.array([0.15, 0.1, 0.12])[None] * t[:, None] + ph[None, 3:])
    return R, tr - tr[:1]


def marker_take(local, fps: float, rng, *, names, motion: bool = True, noise_m: float = 0.2e-3,
                dropout: float = 0.02, place_m=(0.1, 1.62, -0.3), units: str = "cm"):
    """An actor's take as a lab writes it: points ``local`` (T, K, 3) [m] in the actor's head
    frame moved by rigid head motion and placed in the room (y up, the face at ``place_m``), with
    per-axis noise ``noise_m`` and each marker lost in a fraction ``dropout`` of frames (runs of a
    few frames). Returns ``(track in metres, motion (R, t))``; :func:`save_take` writes it."""
    import facewarp as fw

    T, K = local.shape[:2]
    R, t = head_motion(T, fps, rng) if motion else (np.tile(np.eye(3), (T, 1, 1)), np.zeros((T, 3)))
    P = np.einsum("tij,tkj->tki", R, local) + t[:, None] + np.asarray(place_m)[None, None]
    P = P + rng.normal(0.0, noise_m, P.shape)
    stable = set(fw.takes.STABLE_POINTS)
    for k in range(K):
        if names[k] in stable:
            continue  # a lab keeps its reference markers visible; dropouts hit the moving face
        for _ in range(rng.poisson(dropout * T / 4)):
            a = int(rng.integers(1, T))  # the neutral frame 0 keeps every marker
            P[a:a + int(rng.integers(1, 8)), k] = np.nan
    return fw.MarkerTrack(fps, list(names), P, source="generated take"), (R, t)


def save_take_csv(track, path, *, units: str = "cm", labels=None) -> None:
    """A mocap CSV as exported: ``time`` then ``LABEL_x, LABEL_y, LABEL_z`` in ``units``, empty cells for
    missing markers; ``labels`` (name -> label) renames the markers (then a map file is needed)."""
    scale = {"mm": 1e3, "cm": 1e2, "m": 1.0}[units]
    labels = labels or {}
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        head = ["time"]
        for n in track.names:
            lab = labels.get(n, n)
            head += [f"{lab}_x", f"{lab}_y", f"{lab}_z"]
        w.writerow(head)
        for k in range(track.frames):
            row = [f"{k / track.fps:.4f}"]
            for p in track.positions[k]:
                row += ["" if not np.isfinite(v) else f"{v * scale:.4f}" for v in p]
            w.writerow(row)
