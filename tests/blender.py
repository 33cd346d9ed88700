"""Running code in Blender from the tests: a ``blender`` binary or a Python with the ``bpy`` wheel.

Nothing is downloaded: tests skip when :func:`find_blender` finds neither. To run them,
``python3 -m venv ~/.cache/bezmotion/bpy-venv && ~/.cache/bezmotion/bpy-venv/bin/pip install 'bpy==4.2.*'``
(Blender 4.2's wheel is for Python 3.11), or point ``$BEZMOTION_BLENDER`` at a Blender.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path


def find_blender() -> list[str] | None:
    """A command that runs the script in Blender: ``blender --background --python`` or a
    Python that imports ``bpy``; ``None`` when neither is installed (nothing is downloaded)."""
    candidates = [os.environ.get("BEZMOTION_BLENDER"), shutil.which("blender"), str(Path.home() / ".cache/bezmotion/bpy-venv/bin/python")]
    for exe in filter(None, candidates):
        if not (Path(exe).is_file() and os.access(exe, os.X_OK)):
            continue
        if "python" in Path(exe).name:
            ok = subprocess.run([exe, "-c", "import bpy"], capture_output=True, timeout=120).returncode == 0
            if ok:
                return [exe]
        else:
            return [exe, "--background", "--factory-startup", "--python-exit-code", "1", "--python-expr"]
    return None


def run_in_blender(blender: list[str], code: str, cwd: Path) -> str:
    if blender[-1] == "--python-expr":
        command = [*blender, code]
    else:
        command = [*blender, "-c", code]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300, cwd=cwd)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return done.stdout
