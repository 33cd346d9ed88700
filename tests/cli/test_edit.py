"""``bezmotion edit``: what it refuses before it serves anything."""

from __future__ import annotations

import pytest

from bezmotion.cli import main

pytest.importorskip("viser", reason="the browser editor needs viser: pip install -e '.[editor]'")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--port", "70000"], "--port is in 0…65535, got 70000"),
        (["--port", "-1"], "--port is in 0…65535, got -1"),
    ],
)
def test_edit_rejects_bad_arguments_with_a_clear_message(tmp_path, capsys, args, message):
    from bezmotion.assets import DEMO_CLIP

    assert main(["edit", str(DEMO_CLIP), "--out", str(tmp_path), "--no-browser", *args]) == 2
    assert message in capsys.readouterr().err


def test_edit_names_a_clip_that_is_not_there(tmp_path, capsys):
    missing = tmp_path / "nowhere.bvh"
    assert main(["edit", str(missing), "--out", str(tmp_path / "out"), "--no-browser"]) == 2
    err = capsys.readouterr().err
    assert str(missing) in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
