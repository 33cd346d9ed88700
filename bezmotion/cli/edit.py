"""``bezmotion edit CLIP.bvh``: the browser editor (:mod:`bezmotion.editor.app`) of one clip.

It listens on 127.0.0.1 (this machine only) unless ``--host`` names another address, and
every request needs the random token in the address it prints (as Jupyter's).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import webbrowser
from pathlib import Path

EDIT_HELP = "edit an in-between of your BVH clip in the browser: drag handles, resample, undo, export"


def add_edit_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``bezmotion edit`` arguments."""
    parser.add_argument("clip", type=Path, help="the BVH clip")
    parser.add_argument("--frames", type=int, nargs="+", default=[0, 30], metavar="F", help="the clip frames that are keys (default 0 30; more: a chain)")
    parser.add_argument("--model", default="bandai_namco", metavar="NAME|PATH", help="a pretrained model's name (bezmotion models) or a saved model's folder")
    parser.add_argument("--out", type=Path, default=Path("edit"), metavar="DIR", help="the folder exports go to (default edit/)")
    parser.add_argument("--host", default="127.0.0.1", help="the address to listen on (default 127.0.0.1; another one is open to whoever reaches it with the token, over plain HTTP)")
    parser.add_argument("--port", type=int, default=8080, help="the port (default 8080; 0: any free one)")
    parser.add_argument("--no-browser", action="store_true", help="print the address only; do not open a browser")


def has_display() -> bool:
    """Whether a graphical browser can open here (not a console one taking over the terminal)."""
    return sys.platform in ("darwin", "win32") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def run_edit(parsed: argparse.Namespace) -> None:
    """Open the session, serve it (its first view and drag compiling meanwhile) and wait for Ctrl-C."""
    from bezmotion.editor.session import EditSession  # here: the session imports the command's handle checks

    try:
        from bezmotion.editor.app import LOOPBACK, serve
        import viser  # noqa: F401 (the editor's one extra dependency)
    except ImportError:
        raise ValueError("bezmotion edit needs viser: pip install -e '.[editor]'") from None
    if not 0 <= parsed.port <= 65535:
        raise ValueError(f"--port is in 0…65535, got {parsed.port}")
    session = EditSession.open(parsed.clip, parsed.out, keys=tuple(parsed.frames), model=parsed.model)
    try:
        app = serve(session, host=parsed.host, port=parsed.port, background=True)  # the page first, then the in-between
    except OSError as error:
        raise ValueError(f"--host {parsed.host} --port {parsed.port}: cannot listen there ({error.strerror or error})") from None
    if parsed.host not in LOOPBACK:
        print(f"warning: listening on {parsed.host}: whoever reaches it with the address below can edit and export (plain HTTP)", flush=True)
    print(f"bezmotion edit: open {app.url} (Ctrl-C stops)", flush=True)
    print("the page shows the clip at once and the in-between once it is sampled (a first run compiles for about a minute)", flush=True)
    if not parsed.no_browser and has_display():
        webbrowser.open(app.url)
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C does not break off the stop
        app.stop()
