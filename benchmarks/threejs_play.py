"""A rig's glTF in three.js, headless: GLTFLoader loads it, an AnimationMixer plays a clip by name, the frame is drawn.

``benchmarks/threejs/play.html`` runs in headless Chromium (Debian's ``chromium``; WebGL through
SwiftShader), served from a temporary folder on 127.0.0.1 with the ``three`` npm package beside it
(found in ``FACEWARP_THREE`` or the folders of ``NODE_PATH``). The page reports what three.js
sees -- the morph targets by name, the clips, the skeleton's joints, a named shape's influence at
time ``--t`` of the clip ``--clip`` and how far the skin's vertices moved (morph targets and
skinning, as three.js computes them) -- and the screenshot is the picture. Results:
benchmarks/results/<name>.json and .png.

    NODE_PATH=/path/to/node_modules python -m benchmarks threejs_play rig/rig.glb --clip arkit_tour --t 4.1 \\
        --shape jawOpen
"""

from __future__ import annotations

import argparse
import functools
import html
import http.server
import json
import os
import re
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

PAGE = Path(__file__).resolve().parent / "threejs" / "play.html"


def find_three() -> Path | None:
    """The ``three`` npm package's folder, or None."""
    for d in [os.environ.get("FACEWARP_THREE", "")] + os.environ.get("NODE_PATH", "").split(os.pathsep):
        for cand in (Path(d), Path(d) / "three"):
            if d and (cand / "build" / "three.module.js").is_file() and (cand / "examples" / "jsm").is_dir():
                return cand
    return None


def find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "chrome"):
        if shutil.which(name):
            return shutil.which(name)
    return None


def play(glb, *, clip: str, t: float = 0.0, shape: str | None = None, size: int = 360,
         picture: Path | None = None) -> dict:
    """Load ``glb`` in three.js and play ``clip`` at ``t`` [s]; returns the page's report (see the docstring)."""
    three, chromium = find_three(), find_chromium()
    if three is None or chromium is None:
        raise RuntimeError("needs Chromium and the three npm package (NODE_PATH or FACEWARP_THREE)")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        shutil.copyfile(PAGE, tmp / "index.html")
        os.symlink(three, tmp / "three")
        shutil.copyfile(glb, tmp / "rig.glb")
        handler = functools.partial(_Quiet, directory=str(tmp))
        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        th = threading.Thread(target=server.serve_forever, daemon=True)
        th.start()
        try:
            url = (f"http://127.0.0.1:{server.server_address[1]}/index.html?clip={clip}&t={t}&size={size}"
                   + (f"&shape={shape}" if shape else ""))
            flags = [chromium, "--headless=new", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
                     "--enable-unsafe-swiftshader", "--hide-scrollbars", "--virtual-time-budget=60000",
                     f"--window-size={size},{size}", f"--user-data-dir={tmp / 'profile'}"]
            for attempt in range(3):  # a first start of Chromium may end before the page's module ran
                r = subprocess.run(flags + ["--dump-dom", url], capture_output=True, text=True, timeout=300)
                m = re.search(r'<pre id="out"[^>]*>(.*?)</pre>', r.stdout, re.S)
                text = html.unescape(m.group(1)) if m else "pending"
                if text.strip() != "pending":
                    break
            else:
                raise RuntimeError(f"the page did not report: {r.stderr[-1500:]}")
            rep = json.loads(text)
            if picture is not None and rep.get("ok"):
                import numpy as np
                from PIL import Image

                for attempt in range(4):  # as above: a screenshot may come before the page drew its frame
                    subprocess.run(flags + [f"--screenshot={picture}", url], capture_output=True, text=True,
                                   timeout=300)
                    drawn = np.asarray(Image.open(picture).convert("L")) < 240
                    if drawn.mean() > 0.05:  # the head covers the picture, not just the "pending" line
                        break
                else:
                    raise RuntimeError("the page's frame did not come in the screenshot")
        finally:
            server.shutdown()
            server.server_close()
    return rep


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:
        pass

    def guess_type(self, path):
        return "text/javascript" if str(path).endswith(".js") else super().guess_type(path)


def main(argv=None) -> int:
    from benchmarks._common import RESULTS, save

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("glb", type=Path)
    ap.add_argument("--clip", required=True)
    ap.add_argument("--t", type=float, default=0.0)
    ap.add_argument("--shape", default=None)
    ap.add_argument("--size", type=int, default=360)
    ap.add_argument("--name", default="threejs_play")
    a = ap.parse_args(argv)
    rep = play(a.glb, clip=a.clip, t=a.t, shape=a.shape, size=a.size, picture=RESULTS / f"{a.name}.png")
    print(json.dumps({k: v for k, v in rep.items() if k != "targets"}))
    save(a.name, {"file": a.glb.name, "clip": a.clip, "t": a.t, "shape": a.shape, **rep})
    return 0 if rep.get("ok") else 1


if __name__ == "__main__":
    raise SystemExit(main())
