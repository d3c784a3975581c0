"""Temporary files that a killed process leaves behind, recognised by their name and removed by the next
writer: ``.NAME.jaxgaze-tmp-HOST-PID-RANDOM`` beside ``NAME`` (HOST: a hash of the machine's name, PID: the
writing process). Shared by the output writers (:mod:`jaxgaze.io.text`) and the compilation cache
(:mod:`jaxgaze.runtime`). SIGKILL leaves such files: no process can clean up after being killed.
"""

from __future__ import annotations

import contextlib
import os
import re
import socket
import zlib

__all__ = ["TEMPORARY_MARK", "temporary_prefix", "remove_stale_temporaries"]

TEMPORARY_MARK = ".jaxgaze-tmp-"
#: The machine, in the names (a hash of its name): a shared folder holds other machines' files too.
_HOST = format(zlib.crc32(socket.gethostname().encode("utf-8", "replace")), "08x")


def temporary_prefix(name: str) -> str:
    """The prefix of this process's temporary files for ``name`` (for ``tempfile.mkstemp``)."""
    return f".{name}{TEMPORARY_MARK}{_HOST}-{os.getpid()}-"


def _process_is_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True  # another user's process, or not a process id we can ask about: leave its files
    return True


def remove_stale_temporaries(directory, name: str | None = None) -> list:
    """Delete the temporary files in ``directory`` (of ``name``, or of any name) whose writer, on this
    machine, is gone; returns their paths."""
    written = r"[^/]*" if name is None else re.escape(name)
    pattern = re.compile(rf"\.{written}{re.escape(TEMPORARY_MARK + _HOST)}-(\d+)-")
    removed = []
    with contextlib.suppress(OSError):
        for entry in os.listdir(directory):
            match = pattern.match(entry)
            if match and not _process_is_alive(int(match[1])):
                with contextlib.suppress(OSError):
                    os.unlink(os.path.join(directory, entry))
                    removed.append(os.path.join(directory, entry))
    return removed
