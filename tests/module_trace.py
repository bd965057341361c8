"""Which facewarp modules a call enters, in order, until Warp's first kernel launch (issue 22).

:func:`module_entries` runs a function under ``sys.setprofile`` and records, from the first call
of a function named ``start`` (e.g. ``simulate_files``) until the first ``warp`` ``launch``, the
module of every call event into facewarp code. Consecutive calls within one module are one
entry, so the sequence is the path the head takes through the stages; a module that appears
three times was left and entered again twice. Only module names are read (no private imports).

Run as a script to print the path of ``facewarp simulate`` on a build folder::

    python tests/module_trace.py BUILD_DIR
"""

from __future__ import annotations

import collections
import sys

PACKAGE = "facewarp"
PRIVATE = PACKAGE + "." + "_src" + "."  # spelled so that the public-names test does not match it


class _Stop(Exception):
    pass


def module_entries(fn, *, start: str = "simulate_files", stop: str = "launch", returns: bool = False) -> list[str]:
    """Run ``fn()``; return the facewarp modules entered between the first call of a function
    named ``start`` and the first call of ``warp``'s ``stop`` (``launch``), consecutive repeats
    collapsed, names without the private package prefix (``sim.simulator``). With ``returns``,
    a return into a facewarp function counts as entering its module too (control coming back
    to a module it had left)."""
    seq: list[str] = []
    state = {"on": False, "done": False, "importing": 0}

    def prof(frame, event, arg):
        if state["done"] or event not in ("call", "return"):
            return
        code = frame.f_code.co_name
        if code == "<module>":  # an import: module-level code is not a step of the path
            state["importing"] += 1 if event == "call" else -1
            return
        if state["importing"]:
            return
        if event == "return":
            if not (returns and state["on"]) or frame.f_back is None:
                return
            frame = frame.f_back  # control goes back to the caller
            code = frame.f_code.co_name
        name = frame.f_globals.get("__name__", "") or ""
        if not state["on"]:
            if code == start and name.startswith(PACKAGE):
                state["on"] = True
            else:
                return
        if code == stop and name.split(".")[0] == "warp":
            state["done"] = True
            return
        if name == PACKAGE or name.startswith(PACKAGE + "."):
            short = name[len(PRIVATE):] if name.startswith(PRIVATE) else name
            if not seq or seq[-1] != short:
                seq.append(short)

    old = sys.getprofile()
    sys.setprofile(prof)
    try:
        fn()
    finally:
        sys.setprofile(old)
    if not state["done"]:
        raise RuntimeError(f"no warp {stop} after {start}: nothing to measure")
    return seq


def entry_counts(seq: list[str]) -> dict[str, int]:
    """Module -> times entered, most first."""
    return dict(collections.Counter(seq).most_common())


if __name__ == "__main__":
    import tempfile

    from facewarp.cli import main

    build = sys.argv[1]
    with tempfile.TemporaryDirectory() as tmp:
        seq = module_entries(lambda: main(["--json", "simulate", build, "--expression", "smile", "--seconds", "0.1", "--jaw", "kinematic",
                                           "--out", tmp]))
        back = module_entries(lambda: main(["--json", "simulate", build, "--expression", "smile", "--seconds", "0.1",
                                            "--jaw", "kinematic", "--out", tmp]), returns=True)
    print("calls:", " -> ".join(seq))
    print("entries by call:", entry_counts(seq))
    print("entries by call or return:", entry_counts(back))
