"""The ``facewarp`` command: argument parsing and printing only (the work is in ``_src.jobs``).

Streams: results go to stdout (text, or exactly one JSON document with ``--json``); progress
bars, Warp's messages (``--verbose``) and errors go to stderr. Every error a user can cause
ends as one line ``facewarp: error: ...`` on stderr and exit code 2; an internal error is one
line too (exit code 1; ``--verbose`` shows its traceback). Numbers are checked while the
arguments are parsed, before any work. Nothing is imported at module level but the error types,
so ``facewarp --help`` starts in a fraction of a second; nothing below this module prints or
exits.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import sys
import time
from pathlib import Path

from ._src.core.errors import FacewarpError
from ._src.core.limits import (MAX_ADAPT_LEVELS, MAX_FPS, MAX_LAYERS, MAX_MORPH_STEPS, MAX_SECONDS, MAX_SEED,
                               MAX_SUBSTEPS)

EXIT_USAGE = 2
EXIT_INTERNAL = 1
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, as if killed by it

MAX_TEMPLATE_LEVEL = 4  # facewarp._src.template.head.MAX_LEVEL (a test keeps them equal)


class _Parser(argparse.ArgumentParser):
    """One-line usage errors; an epilog can be made only when the help is shown (``epilog_factory``),
    so that building the parser imports nothing heavy."""

    def __init__(self, *args, epilog_factory=None, **kwargs):
        super().__init__(*args, **kwargs)
        self._epilog_factory = epilog_factory

    def format_help(self):
        if self._epilog_factory is not None:
            self.epilog, self._epilog_factory = self._epilog_factory(), None
        return super().format_help()

    def error(self, message):  # one line, exit 2, like every other error
        self.exit(EXIT_USAGE, f"facewarp: error: {message}\n")


class _HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the line breaks of epilogs (the sequence file schema)."""


# ----------------------------------------------------------------------------- argument types
def _number(parse, ok, expected: str):
    """An argparse ``type=``: ``parse(text)`` must succeed and satisfy ``ok``, else the usage
    error "argument --flag: expected <expected>, got 'text'"."""

    def check(text: str):
        try:
            v = parse(text)
        except ValueError:
            v = None
        if v is None or not ok(v):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return v

    return check


def _whole_in(low: int, high: int):
    return _number(int, lambda v: low <= v <= high, f"a whole number {low}..{high}")


def _amount_up_to(high: float):
    return _number(float, lambda v: math.isfinite(v) and 0 < v <= high, f"a finite number > 0 and <= {high:g}")


_seconds = _amount_up_to(MAX_SECONDS)
_fps = _amount_up_to(MAX_FPS)
_level = _number(int, lambda v: 0 <= v <= MAX_TEMPLATE_LEVEL, f"a level 0..{MAX_TEMPLATE_LEVEL}")


def _device(text: str) -> str:
    t = text.strip().lower()
    if t == "cpu" or t == "cuda" or (t.startswith("cuda:") and t[5:].isdigit()):
        return t
    raise argparse.ArgumentTypeError(f"expected cpu, cuda or cuda:N, got {text!r}")


# ----------------------------------------------------------------------------- output
def _raise_if_interrupted() -> None:
    """Raise again at a progress callback when a signal came and a library swallowed its exception."""
    from ._src.core.outputs import raise_if_interrupted

    raise_if_interrupted()


class _Progress:
    """A tqdm bar on stderr over named steps (hidden when stderr is not a terminal or --json)."""

    def __init__(self, total: int, desc: str, enabled: bool):
        from tqdm import tqdm

        self.bar = tqdm(total=total, desc=desc, disable=None if enabled else True, file=sys.stderr, leave=False)

    def __call__(self, msg: str):
        _raise_if_interrupted()
        self.bar.set_postfix_str(msg)
        self.bar.update(1)

    def close(self):
        self.bar.close()


class _FrameBar:
    """A tqdm bar on stderr over simulated frames, made at the first frame (the count is known then)."""

    def __init__(self, enabled: bool, *, desc: str = "simulate", unit: str = "frame"):
        self.enabled, self.desc, self.unit = enabled, desc, unit
        self.bar = None

    def __call__(self, k: int, n: int):
        _raise_if_interrupted()
        if not self.enabled:
            return
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=n, desc=self.desc, unit=self.unit, file=sys.stderr, disable=None, leave=False)
        self.bar.update(1)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _jsonable(o):
    """``o`` with numpy scalars/arrays as Python numbers/lists, paths as strings and non-finite
    floats as null (strict JSON has no NaN or Infinity)."""
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, bool) or o is None or isinstance(o, (int, str)):
        return o
    if isinstance(o, float):
        return o if math.isfinite(o) else None
    if isinstance(o, os.PathLike):
        return os.fspath(o)
    if hasattr(o, "tolist"):  # numpy scalar or array
        return _jsonable(o.tolist())
    return str(o)


def _emit(args, data: dict, lines: list[str]):
    """The command's result on stdout: one JSON document (``--json``) or text lines."""
    out = args.stdout
    if args.json:
        out.write(json.dumps(_jsonable(data), indent=2, allow_nan=False) + "\n")
    else:
        out.write("\n".join(lines) + "\n")
    out.flush()


def _check_device(device: str) -> str:
    if device.startswith("cuda"):
        from ._src.core.warp import get_warp

        wp = get_warp()
        n = wp.get_cuda_device_count()
        if n == 0:
            raise FacewarpError(f"--device {device}: no CUDA device is available on this machine")
        idx = int(device.split(":")[1]) if ":" in device else 0
        if idx >= n:
            raise FacewarpError(f"--device {device}: only {n} CUDA device(s) present (cuda:0..cuda:{n - 1})")
    return device


# ----------------------------------------------------------------------------- template
def cmd_template_export(args):
    from ._src.jobs.checks import check_out_dir
    from ._src.jobs.template import export_template
    from ._src.template import default_template

    t0 = time.perf_counter()
    check_out_dir(args.out)
    prog = _Progress(5 if not args.no_preview else 3, "template export", not args.json)
    prog("building level %d" % args.level)
    t = default_template(args.level)
    written = export_template(t, args.out, previews=not args.no_preview, device=args.device, progress=prog)
    if args.usd:
        from usd_export import write_meshes_usd

        meshes = {"skin": (t.vertices, t.faces), **t.parts}
        written.append(write_meshes_usd(Path(args.out) / "template.usda", meshes))
    prog.close()
    data = {"out": str(args.out), "level": t.level, "vertex_count": t.vertex_count, "face_count": t.face_count,
            "fdp_count": len(t.fdp), "files": [str(p) for p in written], "seconds": round(time.perf_counter() - t0, 3)}
    _emit(args, data, [f"wrote {len(written)} files to {args.out} (level {t.level}: {t.vertex_count} vertices, "
                       f"{t.face_count} faces, {len(t.fdp)} FDPs) in {data['seconds']:.1f} s"])


def cmd_template_info(args):
    from ._src.template import default_template
    from ._src.template.files import template_summary

    t = default_template(args.level)
    s = template_summary(t)
    bb = s["bounding_box_m"]
    lines = [
        f"default template, level {s['level']}",
        f"  vertices {s['vertex_count']}, faces {s['face_count']} ({s['frontal_face_count']} in the frontal face)",
        f"  FDPs {s['fdp_count']}, boundary loops {s['boundary_loops']} (neck, mouth, two eyes)",
        f"  bounding box [m] min {[round(v, 4) for v in bb[0]]} max {[round(v, 4) for v in bb[1]]}",
        f"  skin thickness factor {s['thickness_factor']} x Table 6.1",
        "  regions (faces): " + ", ".join(f"{k} {v}" for k, v in s["regions"].items()),
        "  rigid parts (vertices): " + ", ".join(f"{k} {v}" for k, v in s["parts"].items()),
    ]
    _emit(args, s, lines)


def cmd_template_import_ict(args):
    from ._src.jobs.template import import_ict_files

    prog = _Progress(5 if not args.no_preview else 4, "template import-ict", not args.json)
    rep = import_ict_files(args.ict_dir, args.out, previews=not args.no_preview, device=args.device, progress=prog)
    prog.close()
    _emit(args, rep, [f"imported {args.ict_dir} into {args.out}: {rep['vertex_count']} vertices, {rep['face_count']} "
                      f"faces ({rep['frontal_face_count']} frontal), {rep['fdp_count']} FDPs, parts "
                      + ", ".join(f"{k} {v}" for k, v in rep["parts"].items())
                      + f"; wrote {len(rep['files'])} files in {rep['seconds']:.1f} s"])


# ----------------------------------------------------------------------------- inputs
def cmd_mesh_check(args):
    from ._src.geometry.mesh import load_mesh, mesh_report

    m = load_mesh(args.mesh, units=args.units)
    rep = mesh_report(m.vertices, m.faces)
    rep["path"] = str(args.mesh)
    rep["has_uv"] = m.uv is not None
    lines = [f"{args.mesh}: " + ", ".join(f"{k} {v}" for k, v in rep.items() if k not in ("path", "bounding_box"))]
    _emit(args, rep, lines)


def cmd_landmarks_check(args):
    from ._src.geometry.landmarks import FDP_CATALOGUE, fdp_sort_key, load_landmarks

    lm = load_landmarks(args.landmarks, units=args.units)
    ids = sorted(lm, key=fdp_sort_key)
    data = {"path": str(args.landmarks), "count": len(ids), "fdps": {k: lm[k].tolist() for k in ids}}
    lines = [f"{args.landmarks}: {len(ids)} FDPs"] + [
        f"  {k:>5} {FDP_CATALOGUE[k].description:<45} {lm[k][0]:+.4f} {lm[k][1]:+.4f} {lm[k][2]:+.4f} m" for k in ids
    ]
    _emit(args, data, lines)


def cmd_landmarks_detect(args):
    from ._src.jobs.adapt import detect_landmarks_files

    if args.template_mesh is not None and args.template is not None:
        raise FacewarpError("give --template or --template-mesh, not both")
    if (args.template_mesh is None) != (args.template_landmarks is None):
        raise FacewarpError("--template-mesh and --template-landmarks go together (a mesh and its FDPs)")
    prog = _Progress(3, "detect", not args.json)
    rep = detect_landmarks_files(args.scan, args.out, units=args.units, template_dir=args.template,
                                 template_mesh=args.template_mesh, template_landmarks=args.template_landmarks,
                                 template_units=args.template_units, device=args.device, progress=prog)
    prog.close()
    conf = rep["confidence"]
    _emit(args, rep, [f"found {len(rep['landmarks'])} FDPs on {args.scan} (confidence 0..1):"]
          + [f"  {k:>5} {conf.get(k, 0.0):.2f}  " + " ".join(f"{x:+.4g}" for x in v) + f" {args.units}"
             for k, v in rep["landmarks"].items()]
          + [f"  wrote {rep['path']} and {rep['confidence_path']}"])


# ----------------------------------------------------------------------------- adapt, build, simulate
def _refinement_summary(levels: list[dict], requested: int) -> str:
    """'FDP level + 3 of 5 refinement levels (level 5 raised E and was undone)'."""
    refine = [r for r in levels if r.get("level", 0) >= 2 and r.get("kind") in ("rbf", "csrbf")]
    kept = [r for r in refine if r.get("accepted", True)]
    undone = [r for r in refine if not r.get("accepted", True)]
    text = f"FDP level + {len(kept)} of {requested} refinement levels"
    if undone:
        text += f" (level {undone[0]['level']} raised the error E and was undone)"
    return text


def cmd_adapt(args):
    from ._src.jobs.adapt import adapt_files

    if args.template_mesh is not None and args.template is not None:
        raise FacewarpError("give --template or --template-mesh, not both")
    if (args.template_mesh is None) != (args.template_landmarks is None):
        raise FacewarpError("--template-mesh and --template-landmarks go together (a mesh and its FDPs)")
    prog = _Progress(4, "adapt", not args.json)
    rep = adapt_files(args.scan, args.landmarks, args.out, template_dir=args.template, template_mesh=args.template_mesh,
                      template_landmarks=args.template_landmarks, method=args.method, levels=args.levels,
                      markers=args.markers, units=args.units, template_units=args.template_units,
                      device=args.device, progress=prog, texture_size=args.texture_size)
    prog.close()
    last = rep["levels"][-1] if rep["levels"] else {}
    d = rep["distance_to_scan_m"]
    sc = rep["scale"]
    if sc["units"] == "auto":
        scale_line = (f"  scale: auto from the FDPs, 1 scan unit = {sc['metres_per_unit']:.4g} m (eye distance "
                      f"{sc['measures_file_units']['eye_distance']:.4g} units; measures agree within "
                      f"{(sc['spread'] - 1) * 100:.0f} %)")
    else:
        scale_line = f"  scale: units {sc['units']} (1 unit = {sc['metres_per_unit']:g} m)"
    tex = rep.get("texture")
    lk = rep.get("likeness", {}).get("mean")
    _emit(args, rep, [
        f"adapted {rep['vertex_count']} template vertices to {args.scan} in {rep['seconds']:.2f} s ({rep['method']})",
        scale_line,
        *([f"  texture: the scan's colour baked into {args.out}/texture.png ({tex['size']} px; "
           f"{tex['covered_fraction'] * 100:.0f} % of the head's texels from the scan, the rest filled)",
           f"  likeness: head vs scan from the same cameras, Delta E {lk['delta_e_mean']['textured']:.2f} "
           f"(one flat colour {lk['delta_e_mean']['flat']:.2f}), L* correlation "
           f"{lk['lightness_correlation']['textured']:.2f} (likeness.png)"]
          if tex else []),
        f"  calibration FDPs: {', '.join(rep['calibration']['fdps_used'])}",
        f"  {_refinement_summary(rep['levels'], args.levels)}; final FPs {rep['fp_count']}, "
        f"E_d {last.get('E_d', float('nan')):.3g} m^2",
        f"  distance to scan: median {d['median'] * 1e3:.2f} mm, RMS {d['rms'] * 1e3:.2f} mm",
        f"  surface: {rep['quality']['surface']['folds']} folds; template edges stretched "
        f"{rep['quality']['distortion']['all']['stretch_rms'] * 100:.1f} % RMS (report.json: per region)",
        f"  wrote {args.out}/adapted.obj, adapted_scan_frame.obj, adapted_landmarks.json, report.json, "
        "error_heatmap.png, quality_heatmap.png, distortion_heatmap.png, error_curve.png"
        + (", adapted.glb" if rep.get("uv") else "") + (", texture.png, adapted.mtl, likeness.png" if tex else "")
        + (", detected_landmarks.json" if "detected_landmarks" in rep else ""),
    ])


def cmd_build(args):
    from ._src.jobs.face import build_files

    prog = _Progress(4, "build", not args.json)
    q = build_files(args.head, args.out, layers=args.layers, device=args.device, progress=prog, up=args.up,
                    prefix=args.prefix)
    prog.close()
    _emit(args, q, [
        f"built anatomy of {args.head} into {args.out}: {q['tet_count']} tets, {q['inverted_count']} inverted, "
        f"min dihedral {q.get('min_dihedral_deg', float('nan')):.1f} deg, conforming {q.get('conforming')}",
        f"  {q['muscle_count']} muscles, attached skin nodes per muscle: min {q.get('min_attached_nodes', 0)}",
        "  lips: {crossing_nodes_before} nodes crossing the other lip at rest, {moved_nodes} moved apart, "
        "{crossing_nodes_after} left".format(**q["lip_separation"]),
        "  wrote tets.npz, muscles.json, anatomy.json, anatomy.png, face_rig.npz, head.xml, scene.xml"
        + (", texture.png" if (Path(args.out) / "texture.png").is_file() else ""),
    ])


def cmd_rig(args):
    from ._src.jobs.rig import rig_files

    muscles = [m for m in args.muscles.split(",") if m] if args.muscles else None
    prog = _Progress(1, "rig", not args.json)
    rep = rig_files(args.build, args.out, shapes=args.shapes, inbetweens=args.inbetweens, muscles=muscles,
                    device=args.device, progress=lambda k, n, name: (setattr(prog.bar, "total", n), prog(name)))
    prog.close()
    _emit(args, rep, [
        f"baked {rep['muscles']} muscle shapes ({rep['inbetweens']} in-betweens each) and the jaw corrective of "
        f"{args.build} ({rep['vertices']} skin vertices), the jaw as a joint",
        f"  animation: the Fig. 6.16 sequence, {rep['frames']} frames; wrote {rep['file']}",
    ])


def cmd_simulate(args):
    from ._src.core.errors import InputError
    from ._src.expressions import Timeline, expression_from_activations, timeline_from_spec
    from ._src.jobs.face import simulate_files

    if (args.expression is None) == (args.activations is None):
        raise InputError("simulate: give exactly one of expression or activations")
    if args.activations is not None:  # the user's own muscles, held over the run
        name = args.activations
        timeline = Timeline.held(expression_from_activations(args.activations), args.seconds)
    else:  # a preset, "sequence" or a sequence file
        name = args.expression
        timeline = timeline_from_spec(args.expression, args.seconds)
    bar = _FrameBar(not args.json)
    try:
        rep = simulate_files(args.head, timeline, args.out, seconds=args.seconds, fps=args.fps, name=name,
                             substeps=args.substeps, device=args.device, usd=args.usd, tets=args.tets, progress=bar,
                             solver=args.solver, material=args.material, jaw=args.jaw)
    finally:
        bar.close()
    _emit(args, rep, [
        f"simulated {rep['expression']} for {rep['seconds']} s on {rep['device']}: {rep['frames']} frames x "
        f"{rep['substeps']} substeps (dt {rep['dt_s']:.2e} s), {rep['nodes']} nodes, {rep['tets']} tets",
        f"  {rep.get('solver', 'implicit')} solver, {rep.get('material', 'physical')} material, "
        f"{rep.get('jaw', 'kinematic')} jaw: {rep.get('frames_per_second', float('nan')):.1f} frames/s "
        f"({rep.get('frames_per_second', float('nan')) / rep['fps']:.2f}x real time), "
        f"{rep['steps_per_second']:.0f} steps/s",
        *_frame_stats_lines(rep.get("frame_stats")),
        *[f"  MuJoCo: {e}" for e in rep.get("mujoco_events", [])[:5]],
        "  wrote " + ", ".join(rep["files"]),
    ])


def _frame_stats_lines(st) -> list[str]:
    """The report lines of the simulator's frame stats (sub-stepped frames, volume floor)."""
    if not st:
        return []
    line = (f"  {st['substepped_frames']} of {st['frames']} frames sub-stepped (up to {st['max_substep_factor']}x), "
            f"smallest tet volume {st['min_volume_ratio'] * 100:.1f} % of rest")
    if st.get("frames_below_floor"):
        line += f", {st['frames_below_floor']} frames below the {st['volume_floor'] * 100:.0f} % floor"
    if st.get("unconverged_frames"):
        line += f", {st['unconverged_frames']} frames not converged"
    return [line]


class _StageBar:
    """A tqdm bar over a job's named stages that gives way to a frame bar while simulating."""

    def __init__(self, stages, desc: str, enabled: bool):
        self.stages, self.enabled = list(stages), enabled
        self.bar = _Progress(len(self.stages), desc, enabled)
        self.frames = _FrameBar(enabled)

    def __call__(self, msg: str):
        self.frames.close()
        self.frames = _FrameBar(self.enabled)
        self.bar(msg)

    def close(self):
        self.frames.close()
        self.bar.close()


def cmd_demo(args):
    from ._src.jobs.demo import DEMO_STAGES, demo_files

    bar = _StageBar(DEMO_STAGES, "demo", not args.json)
    try:
        rep = demo_files(args.out, seconds=args.seconds, quick=args.quick, device=args.device, jaw=args.jaw,
                         seed=args.seed, progress=bar, frame_progress=lambda k, n: bar.frames(k, n))
    finally:
        bar.close()
    a, q, s = rep["adaptation"], rep["anatomy"], rep["simulation"]
    _emit(args, rep, [
        f"demo in {args.out} ({rep['timings_s']['total']:.1f} s on {s['device']}):",
        f"  scan: {rep['scan']['vertex_count']} vertices in mm, {rep['scan']['landmark_count']} FDPs, "
        f"pose {rep['scan']['pose']['rotation_deg']:.1f} deg",
        f"  adaptation: {a['seconds']:.1f} s, vertex error E_v median {a['E_v_mm']['median']:.2f} mm, RMS "
        f"{a['E_v_mm']['rms']:.2f} mm; distance to scan median {a['distance_to_scan_mm']['median']:.2f} mm",
        f"  anatomy: {q['tet_count']} tets, {q['inverted_count']} inverted, {q['muscle_count']} muscles",
        f"  simulation: {s['frames']} frames ({s['seconds']:g} s), {s['frames_per_second']:.1f} frames/s "
        f"({s['jaw']} jaw)",
        *_frame_stats_lines(s.get("frame_stats")),
        *[f"  MuJoCo: {e}" for e in s.get("mujoco_events", [])[:5]],
        "  wrote animation.usdc, head.xml, scene.xml, report.json, adapted_head.png, likeness.png, expressions.png, sequence.gif",
    ])


def cmd_morph(args):
    from ._src.jobs.morph import morph_files

    prog = _Progress(3 + (args.steps + 2 if args.build is not None else 0), "morph", not args.json)
    try:
        rep = morph_files(args.a, args.b, args.out, steps=args.steps, fps=args.fps, build=args.build,
                          device=args.device, progress=prog)
    finally:
        prog.close()
    lines = [f"morphed {args.a} into {args.b}: {rep['samples']} heads (s = 0..1) in {args.out}",
             f"  largest vertex distance A-B {rep['max_vertex_distance_mm']:.1f} mm; parts "
             + ", ".join(f"{k} {'rigid' if v['rigid'] else 'affine'}" for k, v in rep["parts"].items())]
    if "heads" in rep:
        lines.append(f"  anatomy of every head in {args.build}: "
                     + ", ".join(f"{h['tet_count']} tets/{h['inverted_count']} inverted" for h in rep["heads"]))
    _emit(args, rep, lines)


def cmd_retarget(args):
    from ._src.jobs.retarget import retarget_files

    bar = _StageBar(range(2 * len(args.heads) + 1), "retarget", not args.json)
    try:
        rep = retarget_files(args.expression, args.heads, args.out, seconds=args.seconds, fps=args.fps,
                             device=args.device, progress=bar, frame_progress=lambda k, n: bar.frames(k, n))
    finally:
        bar.close()
    _emit(args, rep, [f"played {rep['expression']} ({rep['seconds']:g} s) on {len(rep['heads'])} heads into {args.out}:"]
          + [f"  {h['name']}: {h['frames']} frames, {h['frames_per_second']:.1f} frames/s, lip corners "
             f"{h['max_fdp_motion_mm'].get('8.3', float('nan')):.1f}/{h['max_fdp_motion_mm'].get('8.4', float('nan')):.1f} mm"
             for h in rep["heads"]] + ["  wrote " + ", ".join(Path(f).name for f in rep["files"])])


def cmd_drive(args):
    from ._src.jobs.drive import drive_files

    bar = _FrameBar(not args.json)
    table_bar = _FrameBar(not args.json, desc="ARKit table (once per build)", unit="shape")
    try:
        rep = drive_files(args.build, args.out, markers=args.markers, arkit=args.arkit, mediapipe=args.mediapipe,
                          map=args.map, units=args.units, fps=args.fps, rigid=not args.no_rigid, device=args.device,
                          progress=bar, table_progress=lambda done, total, name: table_bar(done, total))
    finally:
        table_bar.close()
        bar.close()
    lines = [f"drove {args.build} from {rep['source']} ({rep['kind']}): {rep['frames']} frames at {rep['fps']:g} fps "
             f"in {rep['seconds']:.1f} s on {rep['device']}"]
    e = rep.get("error_mm")
    if e and e.get("rms") is not None:
        worst = max(((v, k) for k, v in e["per_point_rms"].items() if v is not None), default=(None, None))
        what = "simulated to target" if rep["kind"] == "markers" else "head FDPs to the blended ARKit targets"
        lines.append(f"  distance {what}: RMS {e['rms']:.2f} mm, max {e['max']:.2f} mm"
                     + (f" (worst point {worst[1]}: RMS {worst[0]:.2f} mm)" if worst[1] is not None else ""))
    if rep.get("table"):
        lines.append(f"  ARKit table {rep['table']['file']}" + (" (cached)" if rep["table"]["from_cache"] else
                                                                 " (built now, cached for later runs)"))
    hm = rep.get("head_motion")
    if hm:
        lines.append(f"  head motion removed by a fit of {len(hm['stable_points'])} stable points"
                     + (f" ({hm['frames_held']} frames held the pose before them)" if hm["frames_held"] else ""))
    notes = rep.get("notes", [])
    lines += [f"  note: {n}" for n in notes[:6]]
    if len(notes) > 6:
        lines.append(f"  ... {len(notes) - 6} more notes in report.json")
    lines.append("  wrote " + ", ".join(rep["files"]))
    _emit(args, rep, lines)


# ----------------------------------------------------------------------------- batch
def _steps(text: str) -> tuple[str, ...]:
    from ._src.fleet.manifest import STEPS as known

    names = [t.strip() for t in text.split(",") if t.strip()]
    bad = [n for n in names if n not in known]
    if not names or bad:
        raise argparse.ArgumentTypeError(f"expected a comma list of {', '.join(known)}, got {text!r}")
    return tuple(names)




def _rig_formats(text: str) -> tuple[str, ...]:
    from ._src.fleet.batch import RIG_FORMATS

    names = [t.strip().lower().lstrip(".") for t in text.split(",") if t.strip()]
    bad = [n for n in names if n not in RIG_FORMATS]
    if not names or bad:
        raise argparse.ArgumentTypeError(f"expected a comma list of {', '.join(RIG_FORMATS)}, got {text!r}")
    return tuple(names)


def cmd_batch_run(args):
    from ._src.fleet.batch import run_batch
    from ._src.fleet.manifest import STEPS, read_input_list, scans_from_paths

    if bool(args.scans) == (args.manifest is not None):
        raise FacewarpError("batch run: give scans or --manifest IN.json, not both" if args.scans
                            else "batch run: give scans (SCANS...) or --manifest IN.json")
    if args.ray is not None and args.ray != "local" and Path(args.ray).is_file():
        raise FacewarpError(f"--ray {args.ray}: is a file, not a Ray address (put --ray after the scans, "
                            "or write --ray local)")
    scans = (read_input_list(args.manifest, units=args.units) if args.manifest is not None
             else scans_from_paths(args.scans, units=args.units))
    rep = run_batch(scans, args.out, steps=args.steps, expression=args.expression, seconds=args.seconds,
                    levels=args.levels, rig_formats=args.rig_formats, rig_inbetweens=args.rig_inbetweens,
                    rig_muscles=[m for m in args.rig_muscles.split(",") if m] if args.rig_muscles else None,
                    device=args.device, ray=args.ray, workers=args.workers,
                    gpus_per_task=args.gpus_per_task, simulate_batch=args.simulate_batch,
                    max_retries=args.max_retries, retry_failed=args.retry_failed,
                    progress=not args.json)
    cols = list(STEPS)
    width = max([len(r["name"]) for r in rep["rows"]] + [4])
    lines = [f"batch of {rep['scans']} scans in {args.out} on {rep['executor']}: {rep['done']} done, "
             f"{rep['failed']} failed, {rep['incomplete']} incomplete ({rep['tasks_run']} steps run, "
             f"{rep['tasks_kept']} kept from earlier runs) in {rep['seconds']:.1f} s",
             f"  {'scan':<{width}}  " + "  ".join(f"{c + ' [s]':>12}" for c in cols) + "  status"]
    shown = rep["rows"][:50]
    for r in shown:
        cells = []
        for c in cols:
            v = r.get(f"{c}_s")
            cells.append(f"{v:>12.1f}" if v is not None else f"{('failed' if r['failed_step'] == c else '-'):>12}")
        lines.append(f"  {r['name']:<{width}}  " + "  ".join(cells) + f"  {r['status']}"
                     + (f": {r['failed_step']}: {r['error']}" if r["error"] else ""))
    if len(rep["rows"]) > len(shown):
        lines.append(f"  ... {len(rep['rows']) - len(shown)} more in {rep['report_csv']}")
    g = rep["simulate_grouping"]
    if g["groups"]:
        lines.append(f"  simulate: {g['grouped_scans']} scans in {g['groups']} FaceBatch groups of up to "
                     f"{g['batch']}")
    if g["fallbacks"]:
        lines.append(f"  simulate: {g['fallbacks']} scans of a group simulated alone instead (the group could not "
                     f"step together: {'; '.join(g['fallback_errors'])})")
    lines.append(f"  wrote {rep['manifest']}, {rep['report']}, {rep['report_csv']}")
    _emit(args, rep, lines)


def cmd_batch_simulate(args):
    from ._src.jobs.batch_simulate import batch_simulate_files

    bar = _FrameBar(not args.json)
    try:
        rep = batch_simulate_files(args.builds, args.expression, args.out, per_head=args.per_head,
                                   seconds=args.seconds, fps=args.fps, device=args.device, jaw=args.jaw, stage=args.stage,
                                   progress=bar)
    finally:
        bar.close()
    width = max(len(Path(r["build"]).name) for r in rep["rows"])
    lines = [f"batch of {rep['heads']} heads on {rep['device']} ({rep['jaw']} jaw): {rep['ok']} ok, {rep['failed']} failed; "
             f"{rep['frames']} frames ({rep['seconds']:g} s) at {rep['frames_per_second']:.1f} frames/s, "
             f"{rep['head_frames_per_second']:.1f} head-frames/s (heads made in {rep['build_seconds']:.1f} s)"]
    for r in rep["rows"][:50]:
        lines.append(f"  {r['head']:>4}  {Path(r['build']).name:<{width}}  {r['expression']:<12}  "
                     + ("ok" if r["ok"] else f"FAILED: {r['error']}")
                     + (f" ({r['substepped_frames']} frames sub-stepped)" if r["substepped_frames"] else ""))
    if len(rep["rows"]) > 50:
        lines.append(f"  ... {len(rep['rows']) - 50} more in report.json")
    lines.append(f"  wrote {len(rep['files']) - 1} USD files and report.json in {args.out}"
                 + (f" ({args.stage}: every head in one stage)" if args.stage else ""))
    _emit(args, rep, lines)


# ----------------------------------------------------------------------------- parser
def _simulate_epilog() -> str:
    import textwrap

    from . import MUSCLES, PRESETS

    muscles = textwrap.fill("muscles (Table 6.2; add _L or _R for one side): " + ", ".join(MUSCLES), width=100,
                            initial_indent="  ", subsequent_indent="    ")
    return f"""\
expressions:
  presets      {', '.join(PRESETS)}
               (Table 6.4 and named activation sets; ramp up 0.3 s, hold, ramp down; jaw openings
               are chin drops in mm turned into this head's angle by its condyle-to-chin lever)
  --activations MUSCLE=V,...  your own: e.g. zygomatic_major_L=0.8,frontalis_inner=0.5,jaw_drop_mm=12
  sequence     Fig. 6.16: smile, laugh, surprise, angry, sad, each ramping into the next,
               spread over --seconds
  FILE.json    a sequence file:
    {{"segments": [
      {{"expression": "smile", "start": 0.5, "attack": 0.3, "hold": 1.0, "release": 0.3, "weight": 1.0}},
      {{"expression": {{"blend": {{"smile": 0.5, "surprise": 0.5}}}}, "start": 2.0}},
      {{"expression": {{"muscles": {{"zygomatic_major": 0.6, "corrugator_L": 0.3}}, "jaw_deg": 10}}, "start": 3.5}}]}}
    expression: a preset name, {{"blend": {{preset: weight}}}}, or {{"muscles": {{name: 0..1}}, "jaw_deg": 0..60
    or "jaw_drop_mm": chin drop, "jaw_side_deg": -5..5}}; times in seconds >= 0 (defaults: start 0, attack 0.3, hold 1, release 0.3),
    weight >= 0 (default 1). Overlapping segments add; activations are clamped to 0..1.
    The run lasts --seconds whatever the segments' end.
{muscles}"""


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="facewarp",
        description="Personalized, physically simulated faces (template head, adaptation, anatomy, physics).",
        epilog="Units: the library works in metres; --units converts input files. Results go to stdout (one JSON "
               "document with --json); progress and errors to stderr. Errors: one line, exit code 2.",
    )
    p.add_argument("--device", type=_device, metavar="cpu|cuda|cuda:N", default="cpu", help="Warp device: cpu (default), cuda or cuda:N")
    p.add_argument("--json", action="store_true", help="print the result as one JSON document on stdout")
    p.add_argument("--verbose", action="store_true",
                   help="let Warp print its messages (banner, CUDA driver notes, kernel builds) on stderr, "
                        "and show tracebacks of internal errors")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    t = sub.add_parser("template", help="the default template head authored in code")
    tsub = t.add_subparsers(dest="template_command", metavar="ACTION", parser_class=_Parser)
    tsub.required = True
    level_help = (f"resolution level 0..{MAX_TEMPLATE_LEVEL} (default 0: 3,415 vertices; each level has about 4x the "
                  "vertices of the one before)")
    e = tsub.add_parser("export", help="write the template (mesh, FDPs, regions, anatomy refs, previews) to a folder")
    e.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder (created if needed)")
    e.add_argument("--level", type=_level, metavar="N", default=0, help=level_help)
    e.add_argument("--no-preview", action="store_true", help="skip preview_front.png / preview_side.png")
    e.add_argument("--usd", action="store_true", help="also write template.usda (skin and rigid parts)")
    e.set_defaults(func=cmd_template_export)
    i = tsub.add_parser("info", help="print counts, FDPs, regions and bounding box")
    i.add_argument("--level", type=_level, metavar="N", default=0, help=level_help)
    i.set_defaults(func=cmd_template_info)
    ic = tsub.add_parser("import-ict", help="make the ICT-FaceKit neutral head a full template (FDPs, regions, parts)")
    ic.add_argument("ict_dir", type=Path, metavar="ICT_DIR", help="ICT-FaceKit folder with generic_neutral_mesh.obj")
    ic.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder (created if needed)")
    ic.add_argument("--no-preview", action="store_true", help="skip preview_front.png / preview_side.png")
    ic.set_defaults(func=cmd_template_import_ict)

    m = sub.add_parser("mesh", help="inspect input meshes")
    msub = m.add_subparsers(dest="mesh_command", metavar="ACTION", parser_class=_Parser)
    msub.required = True
    c = msub.add_parser("check", help="load and validate a mesh; report degenerate faces, non-manifold edges, holes")
    c.add_argument("mesh", type=Path, metavar="MESH", help="OBJ, PLY, STL, OFF, GLB or GLTF file")
    c.add_argument("--units", choices=["mm", "cm", "m"], default="m", help="units of the file (default m)")
    c.set_defaults(func=cmd_mesh_check)

    lmp = sub.add_parser("landmarks", help="inspect FDP landmark files")
    lsub = lmp.add_subparsers(dest="landmarks_command", metavar="ACTION", parser_class=_Parser)
    lsub.required = True
    c = lsub.add_parser("check", help="load and validate a landmark file (JSON or MeshLab .pp)")
    c.add_argument("landmarks", type=Path, metavar="LANDMARKS.json|.pp", help='JSON {"3.7": [x, y, z], ...} or MeshLab picked points .pp')
    c.add_argument("--units", choices=["mm", "cm", "m"], default="m", help="units of the file (default m)")
    c.set_defaults(func=cmd_landmarks_check)
    dt = lsub.add_parser("detect", help="find the FDPs on a scan in any pose, without a person (symmetry plane, "
                         "coarse fit of the template, non-rigid fit); writes a landmarks JSON and confidences")
    dt.add_argument("scan", type=Path, help="scan mesh (OBJ, PLY, STL, OFF, GLB, GLTF)")
    dt.add_argument("--out", required=True, type=Path, metavar="LM.json", help="landmarks JSON to write (confidences go beside it, "
                    "NAME_confidence.json)")
    dt.add_argument("--units", choices=["mm", "cm", "m"], default="m", help="units of the scan (and of the written landmarks)")
    dt.add_argument("--template", type=Path, metavar="DIR", help="template folder whose FDPs to find (default: the built-in level 0)")
    dt.add_argument("--template-mesh", type=Path, metavar="MESH", help="any template mesh with FDP landmarks (e.g. ICT-FaceKit neutral)")
    dt.add_argument("--template-landmarks", type=Path, metavar="LM.json", help="FDPs of --template-mesh (JSON or .pp)")
    dt.add_argument("--template-units", choices=["mm", "cm", "m"], default="m", help="units of --template-mesh")
    dt.set_defaults(func=cmd_landmarks_detect)

    a = sub.add_parser("adapt", help="fit the template to a range scan (calibration, RBF, multi-level CSRBF)",
                       epilog="Inputs are checked before the adaptation: scan and landmarks in the same units, at "
                              "least 4 FDPs shared with the template and not coplanar, every landmark near the scan "
                              "surface.")
    a.add_argument("scan", type=Path, help="scan mesh (OBJ, PLY, STL, OFF, GLB, GLTF)")
    a.add_argument("--landmarks", type=Path, metavar="LM.json", help="FDPs on the scan (JSON or .pp), in --units (default: found on the "
                   "scan as by `facewarp landmarks detect`, written to detected_landmarks.json)")
    a.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder")
    a.add_argument("--template", type=Path, metavar="DIR", help="template folder from `facewarp template export` (default: the built-in level 0)")
    a.add_argument("--template-mesh", type=Path, metavar="MESH", help="any template mesh with FDP landmarks (e.g. ICT-FaceKit neutral)")
    a.add_argument("--template-landmarks", type=Path, metavar="LM.json", help="FDPs of --template-mesh (JSON or .pp)")
    a.add_argument("--method", choices=["rbf", "csrbf", "multilevel"], default="multilevel",
                   help="multilevel (default: global RBF while the feature points are few, then compactly "
                        "supported RBF), rbf or csrbf at every level")
    a.add_argument("--levels", type=_whole_in(1, MAX_ADAPT_LEVELS), metavar="N", default=2,
                   help="refinement levels after the FDP level, each adding feature points from the feature mesh "
                        f"and the curvature search (Sec. 4.5); whole number 1..{MAX_ADAPT_LEVELS}, default 2; stops early when the "
                        "error E (Eq. 5.2.3) rises. report.json numbers them 2..N+1 after level 0 (the calibrated "
                        "template) and level 1 (the FDPs), then the final stages (field: a smooth field fitted to "
                        "point-to-plane pairs; land: onto the scan along the normals; relax)")
    a.add_argument("--markers", type=Path, metavar="MARKERS.json", help="FDPs held out of training, for the marker error E_m")
    a.add_argument("--units", choices=["mm", "cm", "m", "auto"], default=None,
                   help="units of the scan and its landmarks; auto: the scale from the FDPs against human proportions "
                        "(eye distance, eye to mouth, nose length; README). Default: m when the scan's extent is a "
                        "plausible head in metres, else auto. FDPs far outside human proportions in the given units "
                        "stop the run")
    a.add_argument("--template-units", choices=["mm", "cm", "m"], default="m", help="units of --template-mesh")
    a.add_argument("--texture-size", type=_whole_in(64, 16384), default=2048, metavar="PX",
                   help="side of texture.png, the scan's colour baked over the head's UVs (64..16384, default 2048; "
                        "written when the scan has colour)")
    a.set_defaults(func=cmd_adapt)

    b = sub.add_parser("build", help="skin tetrahedra, muscles and boundary conditions of a head (Sec. 6.2-6.3)")
    b.add_argument("head", help="a `template export` folder, an `adapt` output folder, or 'default[:LEVEL]' "
                                f"(LEVEL 0..{MAX_TEMPLATE_LEVEL}, default 0)")
    b.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder")
    b.add_argument("--layers", type=_whole_in(1, MAX_LAYERS), metavar="N", default=1,
                   help=f"tet layers through the skin (whole number 1..{MAX_LAYERS}, default 1)")
    b.add_argument("--up", choices=["z", "y"], default="z",
                   help="up axis of head.xml's world: z (MuJoCo's convention, the head looks along +x; default) or y "
                        "(the head's own frame)")
    b.add_argument("--prefix", default="", metavar="STR",
                   help="put STR before every name in head.xml (two heads in one model; letters, digits, _ . : / -)")
    b.set_defaults(func=cmd_build)

    rg = sub.add_parser("rig", help="a blendshape rig baked from the physics (USD UsdSkel or glTF), the jaw as a joint")
    rg.add_argument("build", type=Path, help="a `facewarp build` output folder")
    rg.add_argument("--out", required=True, type=Path, metavar="FILE", help="rig.usdc, rig.usda or rig.glb")
    rg.add_argument("--shapes", choices=["muscles"], default="muscles", help="muscles: each muscle alone (default)")
    rg.add_argument("--inbetweens", type=_whole_in(0, 8), default=0, metavar="K",
                    help="in-between shapes per muscle at k/(K+1) of full activation (0..8, default 0)")
    rg.add_argument("--muscles", default=None, metavar="A,B,...", help="bake only these muscles (default all)")
    rg.set_defaults(func=cmd_rig)

    s = sub.add_parser("simulate", help="play an expression on a `build` output (Warp physics, Sec. 6.4-6.5)",
                       epilog_factory=_simulate_epilog, formatter_class=_HelpFormatter)
    s.add_argument("head", type=Path, help="a `facewarp build` output folder")
    s.add_argument("--expression", metavar="NAME|sequence|FILE.json",
                   help="a preset, 'sequence' or a sequence file (see below); or use --activations")
    s.add_argument("--activations", metavar="MUSCLE=V,...",
                   help="your own expression instead of --expression: muscle=activation (0..1) items, "
                        "e.g. zygomatic_major=0.6,corrugator_L=0.3,jaw_drop_mm=10")
    s.add_argument("--seconds", type=_seconds, metavar="S", default=2.0,
                   help=f"simulated time [s], > 0 and <= {MAX_SECONDS:g} (default 2)")
    s.add_argument("--fps", type=_fps, metavar="F", default=30.0,
                   help=f"frames per second, > 0 and <= {MAX_FPS:g} (default 30)")
    s.add_argument("--substeps", type=_whole_in(1, MAX_SUBSTEPS), metavar="N",
                   help=f"substeps per frame, 1..{MAX_SUBSTEPS} (default: enough for the stable time step)")
    s.add_argument("--out", required=True, type=Path, metavar="DIR|FILE.usd[a|c|z]",
                   help="output folder (frames.npz, frames.png), or a .usda/.usdc/.usdz file: only the USD "
                        "animation, streamed while simulating, no frame cap")
    s.add_argument("--usd", action="store_true",
                   help="with an output folder, also write animation.usdc (whole head, eyes, teeth and tongue "
                        "as moving parts, muscles with activations), streamed while simulating")
    s.add_argument("--tets", action="store_true",
                   help="put the skin's tet layer into the USD too (a TetMesh of purpose guide, hidden by default)")
    s.add_argument("--solver", choices=["implicit", "verlet"], default="implicit",
                   help="implicit (default: backward Euler, one step per frame) or verlet (the thesis's explicit "
                        "reference, ~2,000-5,500 substeps per frame)")
    s.add_argument("--material", choices=["physical", "thesis"], default="physical",
                   help="physical (default: tissue density and moduli in SI) or thesis (Table 6.3 as printed)")
    s.add_argument("--jaw", choices=["mujoco", "kinematic"], default=None,
                   help="mujoco (default with --material physical: the mandible is the hinge body of the build's "
                        "head.xml, two-way coupled to the skin) or kinematic (Eq. 6.4.9 angles imposed; default "
                        "with --material thesis; the MuJoCo jaw couples it too, its stiff holds scaled to MuJoCo's step)")
    s.set_defaults(func=cmd_simulate)

    dr = sub.add_parser(
        "drive", help="drive a `build` output from data: muscle activations and jaw solved per frame from markers, "
                      "or ARKit curves through the head's ARKit table",
        epilog="Formats (docs: guides/driving): markers JSON {\"fps\": 30, \"units\": \"mm\", \"markers\": "
               "{\"2.1\": [[x, y, z], null, ...], \"v123\": [...]}}; markers CSV: time (s) or frame column, then "
               "NAME_x, NAME_y, NAME_z per marker; C3D (pip install 'facewarp[mocap]') with --map; points are FDP "
               "ids or v<vertex index>. Live Link Face CSV (Timecode, BlendShapeCount, EyeBlinkLeft, ..., HeadYaw, "
               "HeadPitch, HeadRoll, ...); MediaPipe Face Landmarker JSON [{\"timestamp_ms\": .., "
               "\"face_blendshapes\": [[{\"category_name\": .., \"score\": ..}, ...]]}, ...]. Writes "
               "DIR/activations.csv, frames.npz, animation.usdc, report.json, drive.png (markers), activations.png; "
               "a .usd[a|c|z] --out is the animation alone.")
    dr.add_argument("build", type=Path, metavar="BUILD", help="a `facewarp build` output folder")
    src = dr.add_mutually_exclusive_group(required=True)
    src.add_argument("--markers", type=Path, metavar="FILE", help="a marker take: .json, .csv or .c3d")
    src.add_argument("--arkit", type=Path, metavar="FILE.csv", help="ARKit curves: a Live Link Face CSV")
    src.add_argument("--mediapipe", type=Path, metavar="FILE.json", help="ARKit curves: MediaPipe Face Landmarker "
                     "blendshapes")
    dr.add_argument("--map", type=Path, metavar="MAP.json", help='marker labels to points: {"LBRO": "4.1", '
                    '"CHIN": "2.1", "M12": "v966"}; labels not in it are left out')
    dr.add_argument("--units", choices=["mm", "cm", "m"], default=None,
                    help="units of the marker coordinates (CSV: default m; JSON and C3D say their own)")
    dr.add_argument("--fps", type=_fps, metavar="F", default=None,
                    help="frames per second, for files that do not carry it (a CSV with a frame column)")
    dr.add_argument("--no-rigid", action="store_true",
                    help="keep the take as it is (already in the head's frame): no fit of forehead, nose bridge and "
                         "ear roots to remove head motion")
    dr.add_argument("--out", required=True, type=Path, metavar="DIR|FILE.usd[a|c|z]",
                    help="output folder, or a USD file (the animation alone)")
    dr.set_defaults(func=cmd_drive)

    d = sub.add_parser("demo", help="the whole main job on built-in data: synthetic scan -> adaptation -> anatomy -> "
                                    "the Fig. 6.16 sequence -> USD, MuJoCo head, pictures",
                       epilog="Writes DIR/animation.usdc, DIR/head.xml, DIR/scene.xml, DIR/report.json, DIR/adapted_head.png, "
                              "DIR/expressions.png, DIR/sequence.gif and the intermediate folders scan/, adapt/, "
                              "build/.")
    d.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder")
    d.add_argument("--seconds", type=_seconds, metavar="S",
                   help=f"length of the sequence [s], > 0 and <= {MAX_SECONDS:g} (default: the full sequence, 8 s; "
                        "shorter squeezes it)")
    d.add_argument("--quick", action="store_true", help="a smoke run: 0.2 s of sequence, small pictures")
    d.add_argument("--seed", type=_whole_in(0, MAX_SEED), metavar="N", default=0,
                   help=f"seed of the synthetic scan (face proportions, noise, holes, pose), 0..{MAX_SEED}, default 0")
    d.add_argument("--jaw", choices=["mujoco", "kinematic"], default="mujoco",
                   help="the jaw: the MuJoCo hinge body of head.xml, two-way coupled (default), or kinematic (Eq. 6.4.9)")
    d.set_defaults(func=cmd_demo)

    mo = sub.add_parser("morph", help="in-between heads of two heads of the same topology, as one USD",
                        epilog="A and B: template folders, adapt outputs or default[:LEVEL] made from one template. "
                               "The USD holds steps + 2 time samples (A, the in-betweens, B); a picture "
                               "FILE.png is written beside it.")
    mo.add_argument("a", metavar="A", help="first head (s = 0)")
    mo.add_argument("b", metavar="B", help="second head (s = 1)")
    mo.add_argument("--steps", type=_whole_in(1, MAX_MORPH_STEPS), metavar="N", default=8,
                    help=f"in-between heads, 1..{MAX_MORPH_STEPS} (default 8)")
    mo.add_argument("--out", required=True, type=Path, metavar="FILE.usd[a|c|z]", help="the USD file")
    mo.add_argument("--fps", type=_fps, metavar="F", default=30.0,
                    help=f"time codes per second of the file, > 0 and <= {MAX_FPS:g} (default 30)")
    mo.add_argument("--build", type=Path, metavar="DIR",
                    help="also write every head as a template folder DIR/head_KK with its anatomy in "
                         "DIR/head_KK/build (simulate it with `facewarp simulate DIR/head_KK/build`)")
    mo.set_defaults(func=cmd_morph)

    r = sub.add_parser("retarget", help="one activation sequence on several heads: a USD per head and a picture",
                       epilog="SEQUENCE: a sequence file (see `facewarp simulate --help`), a preset name or "
                              "'sequence'. HEAD: a `facewarp build` output, a template folder, an adapt output or "
                              "default[:LEVEL]. Every head gets the same physical parameters.")
    r.add_argument("expression", metavar="SEQUENCE", help="sequence .json, preset or 'sequence'")
    r.add_argument("heads", nargs="+", metavar="HEAD", help="heads to play it on")
    r.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder")
    r.add_argument("--seconds", type=_seconds, metavar="S",
                   help=f"length [s], > 0 and <= {MAX_SECONDS:g} (default: the file's length + 0.5 s; 2 s for a "
                        "preset, 8 s for 'sequence')")
    r.add_argument("--fps", type=_fps, metavar="F", default=30.0,
                   help=f"frames per second, > 0 and <= {MAX_FPS:g} (default 30)")
    r.set_defaults(func=cmd_retarget)

    bt = sub.add_parser("batch", help="many scans through adapt, build, simulate and rig, in local processes or on Ray")
    btsub = bt.add_subparsers(dest="batch_command", metavar="ACTION", parser_class=_Parser)
    btsub.required = True
    br = btsub.add_parser(
        "run", help="run every scan through the chosen steps; a manifest makes re-runs skip finished work",
        epilog="Writes DIR/manifest.json (per scan: inputs with their SHA-256, each step's status, error, outputs, "
               "seconds and worker; rewritten atomically as tasks finish), DIR/scans/NAME-KEY/{adapt,build,simulate,rig}/, "
               "DIR/report.json and DIR/report.csv. A scan is known by its content: a re-run (or a renamed copy) "
               "skips the steps done; a step not chosen must be done from an earlier run for the steps that read it "
               "(simulate and rig read the build: --steps rig alone rigs the builds in DIR). A scan's landmarks are looked for beside it (NAME_landmarks.json, "
               "NAME.landmarks.json, NAME.json, NAME.pp, landmarks.json), else found on the scan. Ray: "
               "pip install 'facewarp[ray]'; --ray alone starts a local Ray, --ray auto or --ray ray://HOST:10001 "
               "joins a cluster (`ray start --head`; the scans and DIR on a file system every node sees).")
    br.add_argument("scans", nargs="*", type=Path, metavar="SCANS", help="scan meshes (OBJ, PLY, STL, OFF, GLB, GLTF)")
    br.add_argument("--manifest", type=Path, metavar="IN.json",
                    help='the scans as a file: {"scans": ["a.obj", {"scan": "b.ply", "landmarks": "b.json", '
                         '"units": "mm", "name": "b"}]} (paths relative to the file), or a batch\'s manifest.json')
    br.add_argument("--out", required=True, type=Path, metavar="DIR", help="batch folder (continued if it has a manifest)")
    br.add_argument("--steps", type=_steps, default=("adapt", "build", "simulate"), metavar="adapt,build,simulate,rig",
                    help="the steps to run, in this order per scan (default adapt,build,simulate); rig: the build's "
                         "blendshape rig as `facewarp rig` bakes it (UsdSkel, glTF) into NAME-KEY/rig/")
    br.add_argument("--expression", default="smile", metavar="NAME|sequence|FILE.json",
                    help="what simulate plays (as `facewarp simulate --expression`; default smile)")
    br.add_argument("--seconds", type=_seconds, metavar="S", default=2.0,
                    help=f"simulated time [s], > 0 and <= {MAX_SECONDS:g} (default 2)")
    br.add_argument("--levels", type=_whole_in(1, MAX_ADAPT_LEVELS), metavar="N", default=2,
                    help=f"adapt's refinement levels after the FDP level (as `facewarp adapt --levels`; 1..{MAX_ADAPT_LEVELS}, default 2)")
    br.add_argument("--rig-formats", type=_rig_formats, default=("usdc", "glb"), metavar="usdc,usda,glb",
                    help="the rig step's files rig.FORMAT, one bake written in each (default usdc,glb)")
    br.add_argument("--rig-inbetweens", type=_whole_in(0, 8), default=0, metavar="K",
                    help="the rig step's in-between shapes per muscle (as `facewarp rig --inbetweens`; 0..8, default 0)")
    br.add_argument("--rig-muscles", default=None, metavar="A,B,...",
                    help="the rig step bakes only these muscles (as `facewarp rig --muscles`; default all)")
    br.add_argument("--units", choices=["mm", "cm", "m"], default="m", help="units of the scans and their landmarks")
    br.add_argument("--ray", nargs="?", const="local", metavar="ADDRESS",
                    help="run as Ray tasks: alone, on a local Ray started here; with auto, ray://HOST:10001 or "
                         "HOST:6379, on that cluster")
    br.add_argument("--workers", type=_whole_in(1, 1024), metavar="N",
                    help="local worker processes, 1..1024 (default: the usable cores); with --ray the CPUs of the local Ray "
                         "(default: all) or the tasks kept in flight on a cluster")
    br.add_argument("--gpus-per-task", type=_number(float, lambda v: math.isfinite(v) and 0 <= v <= 64, "a number 0..64"),
                    metavar="F", help="GPUs per simulate or rig task, 0..64: on Ray its num_gpus (default 1 when the "
                         "cluster has a GPU, else 0: on the CPU); with local processes > 0 runs those steps on cuda "
                         "when this machine has a GPU (default: on --device)")
    br.add_argument("--simulate-batch", type=_whole_in(1, 4096), metavar="K",
                    help="scans whose simulate steps together in one FaceBatch task, 1..4096 (default 64 when "
                         "simulate runs on a GPU, else 1: a task per scan); each scan still gets its own "
                         "simulate/ folder and record")
    br.add_argument("--max-retries", type=_whole_in(0, 100), metavar="N", default=2,
                    help="retries of a step whose worker process died (killed, out of memory), 0..100, default 2")
    br.add_argument("--retry-failed", action="store_true", help="run the steps that failed in an earlier run again")
    br.set_defaults(func=cmd_batch_run)
    bs = btsub.add_parser(
        "simulate", help="many built heads played together in one FaceBatch (one step, one CUDA graph per frame for all)",
        epilog="Writes DIR/head_KK.usdc (one USD animation per head, in the order given) and DIR/report.json "
               "(per head: status, error, frames sub-stepped; frames/s and head-frames/s of the batch). A head that fails (NaN, inverted tet even when sub-stepped) is frozen at its "
               "last good frame and reported; the others go on. --per-head FILE.json: {\"heads\": [\"smile\", "
               "{\"expression\": \"laugh\"}, ...]}, one entry per BUILD_DIR.")
    bs.add_argument("builds", nargs="+", type=Path, metavar="BUILD_DIR", help="`facewarp build` output folders")
    bs.add_argument("--expression", default="smile", metavar="NAME|sequence|FILE.json",
                    help="what every head plays (as `facewarp simulate --expression`; default smile)")
    bs.add_argument("--per-head", type=Path, metavar="FILE.json", help="one expression per head (overrides --expression)")
    bs.add_argument("--seconds", type=_seconds, metavar="S", default=2.0,
                    help=f"simulated time [s], > 0 and <= {MAX_SECONDS:g} (default 2)")
    bs.add_argument("--fps", type=_fps, metavar="F", default=30.0,
                    help=f"frames per second, > 0 and <= {MAX_FPS:g} (default 30)")
    bs.add_argument("--jaw", choices=["kinematic", "mujoco"], default="kinematic",
                    help="kinematic (default: Eq. 6.4.9 angles, inside the batched step) or mujoco (each build's "
                         "head.xml hinge body two-way coupled, one CPU MuJoCo per head stepped in a loop)")
    bs.add_argument("--stage", metavar="FILE.usda|FILE.usdc",
                    help="also DIR/FILE: one stage with every head as /Crowd/head_KK (referencing its file), side by side")
    bs.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder")
    bs.set_defaults(func=cmd_batch_simulate)
    return p


# ----------------------------------------------------------------------------- main
def _error(message: str, code: int = EXIT_USAGE) -> int:
    print(f"facewarp: error: {message}", file=sys.stderr)
    return code


def _os_error_text(e: OSError) -> str:
    what = e.strerror or str(e) or type(e).__name__
    return f"{e.filename}: {what}" if e.filename else what


def _quiet_broken_pipe() -> None:
    """stdout's reader went away (``facewarp ... | head``): send what is left to /dev/null."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):
        pass


def main(argv=None) -> int:
    """Run the command line ``argv`` (default ``sys.argv[1:]``); returns the exit code."""
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help, or a usage error already printed as one line
        return int(e.code or 0) if not isinstance(e.code, str) else EXIT_USAGE
    args.stdout = sys.stdout
    with _verbose_env(args.verbose):
        return _run(args)


def console_main() -> None:
    """The ``facewarp`` program (``python -m facewarp`` and the installed script): :func:`main`
    on ``sys.argv[1:]``, then exit with its code.

    The process ends right after, so the cyclic garbage collector is frozen first
    (``gc.freeze``): the interpreter's last collection at exit then skips the objects alive now
    (Warp's builtins, the arrays of the job), which took ~0.35 s of a ~4.5 s ``facewarp adapt``
    (one core). Every output is written and closed before :func:`main` returns, and atexit
    handlers still run.
    """
    import gc

    code = main()
    gc.freeze()
    sys.exit(code)


@contextlib.contextmanager
def _verbose_env(on: bool):
    """``FACEWARP_VERBOSE=1`` (read by facewarp._src.core.warp.get_warp) while a --verbose command runs."""
    old = os.environ.get("FACEWARP_VERBOSE")
    if on:
        os.environ["FACEWARP_VERBOSE"] = "1"
    try:
        yield
    finally:
        if on:
            if old is None:
                os.environ.pop("FACEWARP_VERBOSE", None)
            else:
                os.environ["FACEWARP_VERBOSE"] = old


def _output_targets(args) -> list[tuple[str, Path, str]]:
    """The outputs of the parsed command: (argument, path, "dir" | "file"), staged by _run."""
    func = args.func
    if func in (cmd_template_export, cmd_template_import_ict, cmd_adapt, cmd_build, cmd_demo, cmd_retarget,
                cmd_batch_simulate):
        return [("out", args.out, "dir")]
    if func is cmd_landmarks_detect:
        return [("out", args.out, "file")]
    if func in (cmd_simulate, cmd_drive):
        usd = Path(args.out).suffix.lower() in (".usda", ".usdc", ".usdz")  # jobs.animation.USD_SUFFIXES
        return [("out", args.out, "file" if usd else "dir")]
    if func is cmd_morph:
        return [("out", args.out, "file")] + ([("build", args.build, "dir")] if args.build is not None else [])
    return []


def _run(args) -> int:
    """Run the parsed command; every error becomes one line on stderr and an exit code.

    Outputs are staged (:mod:`facewarp._src.core.outputs`): the command writes into hidden
    siblings of its ``--out`` (and ``--build``), moved into place only when it finished, under a
    lock that refuses a second run on the same output. SIGINT and SIGTERM stop it with exit
    130 / 143 and nothing written. The result is held back until the outputs are in place.
    """
    from ._src.core.outputs import Interrupted, interrupted_by, signals_as_exceptions, staged_outputs

    stdout, args.stdout = args.stdout, io.StringIO()
    staging = None
    try:
        with signals_as_exceptions():
            # anything printed on the way (Warp with --verbose, libraries) goes to stderr: stdout is
            # for the result alone, written by _emit
            with contextlib.redirect_stdout(sys.stderr):
                _check_device(args.device)
                targets = _output_targets(args)
                with staged_outputs(targets) as staging:
                    for name, _, _ in targets:
                        setattr(args, name, staging.path(name))
                    args.func(args)
                    if interrupted_by() is not None:  # a library swallowed the KeyboardInterrupt
                        raise Interrupted(interrupted_by())
        text = args.stdout.getvalue()
        stdout.write(staging.unstage(text) if staging is not None else text)
        stdout.flush()
    except FacewarpError as e:
        return _error(_unstaged(staging, str(e)))
    except KeyboardInterrupt as e:
        print("facewarp: interrupted", file=sys.stderr)
        return 128 + e.signum if isinstance(e, Interrupted) else EXIT_INTERRUPTED
    except BrokenPipeError:
        _quiet_broken_pipe()
        return EXIT_BROKEN_PIPE
    except OSError as e:
        return _error(_unstaged(staging, _os_error_text(e)))
    except MemoryError:
        return _error("out of memory (try a lower level, fewer frames or a smaller mesh)", EXIT_INTERNAL)
    except Exception as e:  # a bug, or a broken installation (ImportError): one line unless --verbose
        if args.verbose:
            raise
        hint = "" if isinstance(e, ImportError) else "; --verbose shows the traceback, please report it"
        return _error(_unstaged(staging, f"{type(e).__name__}: {e}{hint}"), EXIT_INTERNAL)
    return 0


def _unstaged(staging, text: str) -> str:
    """``text`` (an error message) naming the user's output paths, not the staged ones, on one line."""
    text = staging.unstage(text) if staging is not None else text
    return " ".join(text.split("\n")).strip() if "\n" in text else text


def readme_reference() -> tuple[str, str, str]:
    """The README's command reference generated from :func:`build_parser`: (begin marker, block,
    end marker); ``python -m facewarp._src.cli_reference README.md`` rewrites it in place."""
    from ._src.cli_reference import BEGIN, END, reference

    return BEGIN, reference(), END


if __name__ == "__main__":
    sys.exit(main())
