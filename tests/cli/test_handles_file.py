"""``--handles FILE``: what is not a handles file is refused on one line naming it, never with a
traceback (a folder, a file nested 100,000 deep, numbers no float holds, bytes that are not
UTF-8, entries thousands of characters long)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from bezmotion._src.messages import MESSAGE_CHARS
from bezmotion.cli.handles import read_handles_file
from bezmotion._src.structured_files import MAX_NESTING
from bezmotion.pipeline.authoring import read_mapping


def refused(path: Path, error=ValueError) -> str:
    """The one-line message ``read_handles_file`` refuses ``path`` with."""
    with pytest.raises(error) as info:
        read_handles_file(path)
    message = str(info.value)
    assert message.startswith(f"--handles {path}: ") and "\n" not in message, message
    assert len(message) <= MESSAGE_CHARS + len(str(path)), message
    return message.removeprefix(f"--handles {path}: ")


def test_a_folder_or_no_file(tmp_path: Path):
    assert refused(tmp_path) == "is a folder, not a handles file"
    assert refused(tmp_path / "absent.json", FileNotFoundError) == "no such file"


@pytest.mark.parametrize(
    "name, text, line",
    [
        ("deep.json", "[" * 100_000 + "]" * 100_000, 1),
        ("deep_value.json", '[{"joint": "head", "frame": 6,\n "position": ' + "[" * 5_000 + "]" * 5_000 + "}]", 2),
        ("deep.toml", 'a = "[[[["  # [[[[\nb = ' + "[" * 1_100 + "]" * 1_100, 2),
    ],
)
def test_nesting_deeper_than_max_nesting_is_refused_at_its_line(tmp_path: Path, name: str, text: str, line: int):
    """Python's JSON and TOML parsers recurse: the depth is told before they run (brackets in
    strings and TOML comments do not count)."""
    path = tmp_path / name
    path.write_text(text)
    assert refused(path) == f"lists and tables nested more than {MAX_NESTING} deep (line {line})"


def test_tables_nested_by_dotted_keys_are_refused(tmp_path: Path):
    """TOML's dotted keys nest tables without a bracket: the parsed value is measured too."""
    path = tmp_path / "dotted.toml"
    path.write_text("[" + ".".join(f"k{i}" for i in range(5_000)) + "]\nx = 1\n")
    assert refused(path) == f"lists and tables nested more than {MAX_NESTING} deep"
    mapping = tmp_path / "mapping.toml"
    mapping.write_text(path.read_text())
    with pytest.raises(ValueError, match=f"^lists and tables nested more than {MAX_NESTING} deep$"):
        read_mapping(mapping)


@pytest.mark.parametrize(
    "entry",
    [
        '{"joint": "head", "frame": 6, "position": [0, 1' + "0" * 400 + ", 0]}",  # an integer beyond float
        '{"joint": "head", "frame": 6, "offset": [0, 1e999, 0]}',  # JSON's own overflow to inf
        '{"joint": "' + "x" * 20_000 + '", "frame": "6", "position": [0, 0, 0]}',
    ],
)
def test_an_entry_is_refused_and_shown_in_part(tmp_path: Path, entry: str):
    path = tmp_path / "handles.json"
    path.write_text(f"[{entry}]")
    message = refused(path)
    assert message.startswith('handle 0: expected {"joint": name, "frame": integer, "position" or "offset": [x, y, z]}, got {'), message


def test_bytes_that_are_not_utf8_or_json(tmp_path: Path):
    path = tmp_path / "handles.json"
    path.write_bytes(b'[{"joint": "h\xffad"}]')
    assert refused(path) == "not UTF-8 text (invalid start byte at byte 13)"
    path.write_text('[{"joint": "head", "frame": ' + "9" * 5_000 + "}]")
    assert re.fullmatch(r"not valid JSON \(.*digits.*\)", refused(path))
