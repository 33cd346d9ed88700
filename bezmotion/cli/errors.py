"""The commands' errors: a library error told as the argument (or default) it came from."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bezmotion._src.checksums import CHECKSUM_FILE, MissingChecksums
from bezmotion.assets.registry import NotTrained


def argument_error(argument: str, value: Any, error: BaseException) -> ValueError:
    """``ValueError("ARGUMENT VALUE: message")``, without the value repeated at the message's
    start, in the commands' words where the library's name a keyword (``verify=False``)."""
    if isinstance(error, NotTrained):  # the commands that train it are many and long: the table lists them
        message = f"{error.short()}; bezmotion models lists the commands that train it"
    elif isinstance(error, MissingChecksums):
        message = f"no {CHECKSUM_FILE} (saved before models carried checksums); --no-verify loads it if you trust its files"
    else:
        message = str(error.args[0]) if error.args else str(error)
    for prefix in (f"{value}: ", f"{Path(str(value)).absolute()}: "):
        if message.startswith(prefix):
            message = message[len(prefix) :]
    return ValueError(f"{argument} {value}: {message}")
