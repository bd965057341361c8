"""Mocap retargeting: a marker take of another face (an actor) drives this head.

A take of an actor is not this head: absolute marker positions land centimetres from any point of
it. What carries over is the motion. The take's *neutral* (its first frame, or the mean of a span,
:func:`~facewarp.load_markers` ``neutral=``) and the head's rest points define the mapping:

1. Rigid head motion out, against the actor's own neutral: per frame a rigid fit of the take's
   stable points (:data:`~facewarp.takes.STABLE_POINTS`) to the same points of the neutral
   (:func:`~facewarp.takes.remove_head_motion` with the neutral as rest, no scale). What is left is the
   expression in the actor's neutral frame; the fitted poses are the actor's head motion.
2. Displacements from the neutral, ``d_i(t) = p_i(t) - n_i`` per marker ``i``.
3. Carried to the head: ``target_i(t) = q_i + L_r d_i(t)`` with ``q_i`` the head's rest point and
   ``L_r`` the linear map of the marker's region ``r`` (:data:`REGIONS`):

   - ``"affine"``: the actor's neutral markers are aligned to the head's points by one
     similarity (Umeyama, Eq. 4.3.3: rotation ``R0``, scale ``s0``), then each region's markers by
     an affine map fitted in least squares, ``A_r = argmin sum_i |A (x_i - x_c) - (q_i - q_c)|^2
     + lambda |A - A_face|^2`` (``lambda`` = :data:`AFFINE_PRIOR` times the region's spread, so a
     region stays near ``A_face``, the whole face's affine map, fitted the same way towards the
     identity with :data:`FACE_PRIOR`); ``L_r = A_r s0 R0``. Follows an actor whose face is
     stretched as a whole; a face that differs in shape (a wider jaw, a deeper chin) does not
     move the more for it, which the large :data:`AFFINE_PRIOR` keeps in check.
   - ``"fapu"`` (default): MPEG-4 face animation parameter units (thesis §4.1, ``docs/MPEG4_FDP.md``):
     ``L_r = diag(f_x, f_y, f_z) R0`` with each factor the head's unit over the actor's: across
     the face (x) MW (mouth width, 8.3-8.4) for the mouth and jaw, ES (eye separation) elsewhere;
     up (y) MNS (mouth-nose, 9.15-2.2) for the mouth and jaw, IRISD (upper to lower lid, 3.1-3.3)
     for the lids, ENS (eye-nose, eyes to 9.15) elsewhere; depth (z) MNS for the mouth and jaw,
     ENS elsewhere. A unit whose points the take lacks falls back to ``s0`` (said in the notes).

Markers are named by FDP id or ``v<index>`` (a vertex: the region of the head's nearest FDP).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.checks import check_choice, describe
from ..core.errors import InputError
from ..geometry.similarity import fit_similarity, point_spread
from .rigid import STABLE_POINTS, HeadMotion, remove_head_motion
from .tracks import MarkerTrack

__all__ = ["AFFINE_PRIOR", "FACE_PRIOR", "METHODS", "REGIONS", "RetargetMap", "region_of", "retarget_map", "retarget_markers",
           "retarget_track"]

METHODS = ("fapu", "affine")
"""How displacements are carried from the actor to the head (module doc)."""

REGIONS = {
    "forehead": ("11.",), "brows": ("4.",), "eyes": ("3.",), "nose": ("9.",), "cheeks": ("5.",),
    "mouth": ("8.", "2.2", "2.3", "2.4", "2.5", "2.6", "2.7", "2.8", "2.9"),
    "jaw": ("2.1", "2.10", "2.11", "2.12", "2.13", "2.14"), "ears": ("10.",), "other": (),
}
"""The regions of the face that get a map of their own, by FDP id prefix (MPEG-4 groups; the
inner lip points 2.2-2.9 with the mouth, the chin and jaw line with the jaw)."""

AFFINE_PRIOR = 3.0
"""Weight of a region's affine map's pull towards the whole face's, as a fraction of the region's
spread (the trace of its centred neutral points' scatter). Large: an actor's face differs from the
head in shape more than its motion differs (an ICT identity driving the default head: the whole
face's map alone is 1.25 mm RMS from the head's own motion at worst, free regional maps 2.5 mm)."""

FACE_PRIOR = 0.01
"""The same weight for the whole face's affine map towards the similarity: small, so that a face
wider or shorter than the head as a whole is followed."""

_MOUTH = ("mouth", "jaw")


def region_of(name: str) -> str:
    """The region (:data:`REGIONS`) of an FDP id; ``"other"`` for anything else."""
    for r, prefixes in REGIONS.items():
        for p in prefixes:
            if (p.endswith(".") and name.startswith(p)) or name == p:
                return r
    return "other"


@dataclass
class RetargetMap:
    """How a take's displacements are carried to a head (module doc).

    Attributes:
        method: ``"affine"`` or ``"fapu"``.
        names: The K point names.
        regions: (K,) the region of each point.
        linear: (K, 3, 3) float64, ``L`` per point (its region's): head displacement = ``L @`` actor displacement.
        rotation: (3, 3) float64, ``R0``, the actor's neutral frame to the head's.
        scale: ``s0``, the head's size over the actor's (the global similarity's).
        neutral_residual_mm: RMS [mm] of the global similarity over the points (how different the faces are).
        units: For ``"fapu"``: each unit's actor and head value [m] and the factor used.
        notes: What fell back or was left out.
    """

    method: str
    names: list
    regions: list
    linear: np.ndarray
    rotation: np.ndarray
    scale: float
    neutral_residual_mm: float
    units: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        per_region = {}
        for r, L in zip(self.regions, self.linear):
            per_region.setdefault(r, np.round(L, 5).tolist())
        return {"method": self.method, "scale": round(float(self.scale), 6),
                "rotation": np.round(self.rotation, 6).tolist(),
                "neutral_residual_mm": round(float(self.neutral_residual_mm), 3),
                "regions": per_region, "units": self.units, "notes": list(self.notes)}


def _fdp_region(name: str, head_rest: dict) -> str:
    if not name.startswith("v"):
        return region_of(name)
    p = head_rest[name]
    fdps = [(n, q) for n, q in head_rest.items() if not n.startswith("v")]
    if not fdps:
        return "other"
    return region_of(min(fdps, key=lambda nq: float(np.sum((nq[1] - p) ** 2)))[0])


def _unit(points: dict, which: str):
    """An MPEG-4 FAP unit [m] from named points (FDP id -> (3,)), or None when they are missing."""
    def mid(*ids):
        if all(i in points for i in ids):
            return np.mean([points[i] for i in ids], axis=0)
        return None

    eye_l = points.get("3.5") if "3.5" in points else mid("3.7", "3.11")
    eye_r = points.get("3.6") if "3.6" in points else mid("3.8", "3.12")
    if which == "ES":
        return None if eye_l is None or eye_r is None else abs(float(eye_l[0] - eye_r[0]))
    if which == "ENS":
        if eye_l is None or eye_r is None or "9.15" not in points:
            return None
        return abs(float((eye_l[1] + eye_r[1]) / 2 - points["9.15"][1]))
    if which == "MNS":
        low = points.get("2.2", points.get("8.1"))
        return None if low is None or "9.15" not in points else abs(float(points["9.15"][1] - low[1]))
    if which == "MW":
        return None if "8.3" not in points or "8.4" not in points else abs(float(points["8.3"][0] - points["8.4"][0]))
    if which == "IRISD":
        v = [abs(float(points[a][1] - points[b][1])) for a, b in (("3.1", "3.3"), ("3.2", "3.4"))
             if a in points and b in points]
        return float(np.mean(v)) if v else None
    raise ValueError(which)


def retarget_map(neutral, names, head_rest: dict, *, method: str = "fapu") -> RetargetMap:
    """The map of a take's displacements onto a head (module doc).

    Args:
        neutral: (K, 3) float64 [m], the actor's neutral markers (NaN: not seen in the neutral).
        names: The K point names (FDP ids, ``v<index>``).
        head_rest: Point name -> (3,) [m], the head at rest (its own frame), holding every name.
        method: ``"fapu"`` (default) or ``"affine"``.

    Raises:
        InputError: fewer than four points seen in the neutral, or spread over less than a plane.
    """
    method = check_choice("method", method, METHODS)
    names = [str(n) for n in names]
    N = np.asarray(neutral, dtype=np.float64).reshape(len(names), 3)
    missing = [n for n in names if n not in head_rest]
    if missing:
        raise InputError(f"head: no point {missing[0]!r} ({len(missing)} of the take's points missing on the head)")
    Q = np.array([np.asarray(head_rest[n], dtype=np.float64).reshape(3) for n in names])
    seen = np.isfinite(N).all(axis=1)
    if seen.sum() < 4 or point_spread(N[seen])[2] < 1e-3:
        raise InputError(f"neutral: retargeting needs four or more points seen in the actor's neutral and spread "
                         f"beyond a plane, got {int(seen.sum())}")
    S = fit_similarity(N[seen], Q[seen], with_scale=True)
    R0, s0 = S.rotation, float(S.scale)
    aligned = S.apply(np.where(seen[:, None], N, 0.0))
    resid = float(np.sqrt(np.mean(np.sum((aligned[seen] - Q[seen]) ** 2, axis=1))) * 1e3)
    regions = [_fdp_region(n, head_rest) for n in names]
    linear = np.zeros((len(names), 3, 3))
    notes, units = [], {}
    if method == "affine":
        def fit(idx, prior, weight):
            X = aligned[idx] - aligned[idx].mean(0)
            Y = Q[idx] - Q[idx].mean(0)
            lam = weight * float(np.trace(X.T @ X)) + 1e-12
            return (Y.T @ X + lam * prior) @ np.linalg.inv(X.T @ X + lam * np.eye(3))

        A_all = fit(np.flatnonzero(seen), np.eye(3), FACE_PRIOR)  # the whole face's stretch
        for r in sorted(set(regions)):
            idx = np.array([i for i, g in enumerate(regions) if g == r and seen[i]], dtype=np.int64)
            if len(idx) >= 2:
                A = fit(idx, A_all, AFFINE_PRIOR)
            else:
                A = A_all
                notes.append(f"region {r}: {len(idx)} point(s) in the neutral, the whole face's map used")
            for i, g in enumerate(regions):
                if g == r:
                    linear[i] = A @ (s0 * R0)
    else:
        actor = {n: (R0 @ N[i]) for i, n in enumerate(names) if seen[i]}  # head axes, actor size
        head = {n: Q[i] for i, n in enumerate(names)}
        for n, q in head_rest.items():
            head.setdefault(n, np.asarray(q, dtype=np.float64))
        for u in ("ES", "ENS", "MNS", "MW", "IRISD"):
            a, h = _unit(actor, u), _unit(head, u)
            if a is None or h is None or a < 1e-4:
                units[u] = {"actor_mm": None if a is None else round(a * 1e3, 3),
                            "head_mm": None if h is None else round(h * 1e3, 3), "factor": s0}
                notes.append(f"FAP unit {u}: its points are not all in the take's neutral; the global scale "
                             f"{s0:.3f} used")
            else:
                units[u] = {"actor_mm": round(a * 1e3, 3), "head_mm": round(h * 1e3, 3), "factor": h / a}
        f = {u: float(v["factor"]) for u, v in units.items()}
        lids = {"3.1", "3.2", "3.3", "3.4"}
        for i, (n, r) in enumerate(zip(names, regions)):
            if r in _MOUTH:
                D = (f["MW"], f["MNS"], f["MNS"])
            elif n in lids:
                D = (f["ES"], f["IRISD"], f["ENS"])
            else:
                D = (f["ES"], f["ENS"], f["ENS"])
            linear[i] = np.diag(D) @ R0
    return RetargetMap(method=method, names=names, regions=regions, linear=linear, rotation=R0, scale=s0,
                       neutral_residual_mm=resid, units=units, notes=notes)


def retarget_track(track: MarkerTrack, head_rest: dict, *, method: str = "fapu", rigid: bool = True,
                   points=None) -> tuple[MarkerTrack, HeadMotion | None, RetargetMap]:
    """An actor's take as target points on this head (module doc).

    Args:
        track: The take (:class:`~facewarp.MarkerTrack`, metres, any frame); its
            :attr:`~facewarp.MarkerTrack.neutral` (default its first frame) is the actor at rest.
        head_rest: Point name -> (3,) [m], the head at rest, holding every name of the take.
        method: ``"fapu"`` (default) or ``"affine"``.
        rigid: Remove the actor's head motion first (needs three stable points; without them the
            take is taken as still, and the notes say so).
        points: The stable point names (default :data:`~facewarp.takes.STABLE_POINTS`).

    Returns:
        ``(targets, motion, map)``: the targets in the head's frame (a MarkerTrack of the take's
        names, fps and source, NaN where a marker is missing; ``notes`` say what was done), the
        actor's head motion relative to its neutral (None when not removed) and the
        :class:`RetargetMap`.
    """
    if not isinstance(track, MarkerTrack):
        raise InputError(f"track: expected a MarkerTrack, got {describe(track)}")
    if not hasattr(head_rest, "items"):
        raise InputError(f"head_rest: expected a mapping from point names to positions, got {describe(head_rest)}")
    neutral = track.neutral_points()
    notes = list(track.notes)
    motion = None
    local = track
    stable = tuple(STABLE_POINTS if points is None else points)
    if rigid:
        rest = {n: neutral[i] for i, n in enumerate(track.names) if np.isfinite(neutral[i]).all()}
        have = [p for p in stable if p in rest]
        if len(have) >= 3:
            local, motion = remove_head_motion(track, rest, points=stable, scale=False)
        else:
            notes.append(f"head motion not removed: the take's neutral has {len(have)} of the stable points "
                         f"{', '.join(stable)} (the actor is taken as still)")
    m = retarget_map(neutral, track.names, head_rest, method=method)
    Q = np.array([np.asarray(head_rest[n], dtype=np.float64).reshape(3) for n in track.names])
    D = local.positions - neutral[None]  # (T, K, 3) actor displacements [m]
    targets = Q[None] + np.einsum("kij,tkj->tki", m.linear, D)
    lost = ~np.isfinite(neutral).all(axis=1)
    if lost.any():
        notes.append(f"points never seen in the neutral, left out: {', '.join(np.asarray(track.names)[lost])}")
    notes += m.notes
    notes.append(f"retargeted ({m.method}): the actor's neutral is {m.neutral_residual_mm:.1f} mm RMS from the "
                 f"head after a similarity of scale {m.scale:.3f}")
    out = MarkerTrack(track.fps, list(track.names), targets, source=track.source, notes=notes,
                      info=dict(track.info, retarget=m.method))
    return out, motion, m


def retarget_markers(track: MarkerTrack, rest, *, method: str = "fapu", rigid: bool = True):
    """An actor's marker take as target points on a head, without simulating: what
    :func:`~facewarp.drive` with ``retarget=True`` solves towards (to look at them, or to drive a
    rig of one's own).

    Args:
        track: The actor's take (:class:`~facewarp.MarkerTrack`, metres, any frame); its
            ``neutral`` (default its first frame) is the actor at rest.
        rest: The head at rest: a mapping from point name to position [m], shape (3,), holding
            every name of the take (e.g. ``dict(zip(rig.fdp_ids, sim.fdp_points()))``).
        method: ``"fapu"`` (MPEG-4 face animation parameter units, default) or ``"affine"``.
        rigid: Remove the actor's head motion against its neutral first (three stable points needed).

    Returns:
        ``(targets, motion, map)``: the targets in the head's frame (a MarkerTrack, NaN where a
        marker is missing), the actor's head motion relative to its neutral (a
        :class:`~facewarp.takes.HeadMotion`, or None when not removed) and the map (``method``,
        ``regions``, ``linear`` (K, 3, 3), ``rotation``, ``scale``, ``units``, ``notes``, ``to_dict()``).

    Raises:
        InputError: a bad argument, a name the head lacks, fewer than four points in the neutral,
        stable points that cannot give the head motion.
    """
    from ..core.checks import check_bool

    rigid = check_bool("rigid", rigid)
    method = check_choice("method", method, METHODS)
    return retarget_track(track, rest, method=method, rigid=rigid)
