"""Screenshots of the rerun web viewer opening the recordings the product writes.

    python docs/screenshots/take.py                 # run the four commands below, then screenshot
    python docs/screenshots/take.py --record-to DIR # the same, keeping the .rrd files in DIR
    python docs/screenshots/take.py --rrd-dir DIR   # screenshot DIR/{overtake,merge,highway,replay}.rrd as they are
    python docs/screenshots/take.py --only merge    # one of them

Each recording is served with ``rerun --serve-web FILE.rrd`` and opened in headless Chromium (WebGL through
SwiftShader; ``apt-get install chromium``, ``pip install playwright``). Nothing is clicked or zoomed: the
screenshot is taken once the viewer has loaded the file and its picture stops changing, so it shows what a
user sees on opening the file (the recording's own blueprint, the time cursor where the viewer leaves it).
Writes overtake.png, merge.png, highway.png and replay.png beside this script, and NAME_start.png: the same view
after pausing and moving the time cursor to the timeline's start (keys only, the view untouched), since the
viewer follows the streamed file to its last step.
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from urllib.parse import quote

HERE = Path(__file__).resolve().parent
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--ignore-gpu-blocklist", "--no-sandbox"]
SIZE = {"width": 1600, "height": 1000}

# name -> the product command that writes it (the .rrd path appended after --rerun)
COMMANDS = {
    "overtake": ["guardian", "rollout", "--env", "guardian/HighwayOvertake-v0", "--agent", "seek",
                 "--episodes", "1", "--seed", "0"],
    # three guarded cars on merge-v0's road among medium traffic (guardian/Merge-v0), 8 s: the road ends at 460 m, car 0 starts at 238 m
    "merge": ["guardian", "rollout", "--env", "guardian/Merge-v0", "--agent", "merge", "--action", "meta",
              "--controlled", "3", "--env-config", "traffic=medium", "--env-config", "duration=8", "--episodes", "1",
              "--seed", "0"],
    # one ego among highway-fast-v0's traffic, seeking the nearest car: the set's slice below the road
    "highway": ["guardian", "rollout", "--env", "highway-fast-v0", "--agent", "seek", "--action", "continuous",
                "--episodes", "1", "--seed", "0"],
    # a one-minute generated highD-format recording; input bounds from the data raise self-safety overrides
    "replay": ["guardian", "replay", "{highd}", "--input-bounds", "data", "--no-cache"],
}


def record(out: Path, names) -> None:
    """Run the product's commands ``names``, writing out/NAME.rrd."""
    highd = out / "highd"
    steps = [("highd", ["guardian", "highd", "generate", "--out", str(highd), "--recordings", "1",
                        "--minutes", "1", "--seed", "0"])] if "replay" in names else []
    steps += [(name, [str(highd) if a == "{highd}" else a for a in cmd] + ["--rerun", str(out / f"{name}.rrd")])
              for name, cmd in COMMANDS.items() if name in names]
    for name, cmd in steps:
        t0 = time.time()
        print("$", " ".join(cmd), flush=True)
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        print(f"  {name}: {time.time() - t0:.0f} s", flush=True)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rerun_binary() -> str:
    """The viewer binary itself (the ``rerun`` script on PATH starts it as a child process)."""
    try:
        import rerun_cli
        exe = Path(rerun_cli.__file__).parent / "rerun"
        if exe.exists():
            return str(exe)
    except ImportError:
        pass
    return shutil.which("rerun")


def wait_listening(port: int, timeout: float = 30.0) -> None:
    end = time.time() + timeout
    while time.time() < end:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.3)
    raise TimeoutError(f"nothing listens on port {port}")


def settled(page, settle: float, timeout: float) -> tuple[bytes, bool]:
    """A screenshot once two taken ``settle`` s apart agree (or the last one after ``timeout`` s)."""
    t0, last = time.time(), None
    while True:
        time.sleep(settle)
        shot = page.screenshot()
        if shot == last:
            return shot, True
        if time.time() - t0 > timeout:
            return shot, False
        last = shot


def screenshot(browser, rrd: Path, png: Path, settle: float = 4.0, timeout: float = 180.0) -> None:
    """Serve rrd, open it in the web viewer and save png once the picture stops changing; then png's
    ``_start`` sibling: the same view paused at the timeline's start (Space, then Ctrl+Shift+Left)."""
    web, grpc = free_port(), free_port()
    server = subprocess.Popen([rerun_binary(), "--serve-web", str(rrd), "--web-viewer-port", str(web),
                               "--port", str(grpc)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True)
    try:
        wait_listening(web)
        wait_listening(grpc)
        page = browser.new_page(viewport=SIZE)
        page.goto(f"http://127.0.0.1:{web}/?url=" + quote(f"rerun+http://127.0.0.1:{grpc}/proxy", safe=""))
        t0 = time.time()
        shot, ok = settled(page, settle, timeout)
        png.write_bytes(shot)
        print(f"  {png} ({time.time() - t0:.0f} s{'' if ok else ', not settled'})", flush=True)
        page.keyboard.press("Space")                     # pause (the viewer follows the stream to its end)
        page.keyboard.press("Control+Shift+ArrowLeft")   # the viewer's "Start of timeline"
        start = png.with_name(png.stem + "_start.png")
        shot, ok = settled(page, settle / 2, 60.0)
        start.write_bytes(shot)
        print(f"  {start}{'' if ok else ' (not settled)'}", flush=True)
        page.close()
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=10)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rrd-dir", type=Path, help="take DIR/{overtake,merge,highway,replay}.rrd instead of recording")
    ap.add_argument("--record-to", type=Path, help="where the commands write their .rrd (default: a temp folder)")
    ap.add_argument("--out", type=Path, default=HERE, help="where the PNGs go (default: beside this script)")
    ap.add_argument("--only", choices=sorted(COMMANDS), nargs="+", default=list(COMMANDS), help="these recordings only")
    args = ap.parse_args()
    t0 = time.time()
    rrd_dir = args.rrd_dir
    if rrd_dir is None:
        rrd_dir = args.record_to or Path(tempfile.mkdtemp(prefix="guardian-shots-"))
        rrd_dir.mkdir(parents=True, exist_ok=True)
        record(rrd_dir, args.only)
    from playwright.sync_api import sync_playwright
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        for name in args.only:
            screenshot(browser, rrd_dir / f"{name}.rrd", args.out / f"{name}.png")
        browser.close()
    print(f"done in {time.time() - t0:.0f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
