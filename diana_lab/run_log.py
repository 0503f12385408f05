"""The console's lines in the Hydra job's log file (``<run dir>/<job name>.log``).

Hydra's ``job_logging`` gives the root logger a console and a file handler, but the entry points talk to the user
with ``print`` (the progress lines, the end-of-run summary, the evaluation table) and SB3 draws its bar with tqdm
and rich: none of that goes through ``logging``, so the log file stayed empty. :func:`console_to_log_file` tees
``sys.stdout`` and ``sys.stderr`` for the duration of a job: everything still goes to the console, as written,
and every finished line also goes to the job's log file handler(s) through :data:`FILE_ONLY` (a logger that does
not propagate, so nothing reaches the console twice). What a terminal draws in place (a progress bar redrawn
after ``\\r``, rich's cursor moves and colours) is reduced to the text it leaves on screen, and the bars
themselves are left out; :class:`diana_lab.training.progress.ProgressWithStats` writes its plain line to the file
instead while it draws a bar.

Outside a Hydra job (tests, notebooks) or with ``hydra/job_logging=disabled`` there is no file handler and
nothing changes.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any, TextIO

__all__ = ["FILE_ONLY", "console_to_log_file", "log_file_handlers", "log_only", "plain_line"]

# records sent here reach the job's log file and nothing else (its handlers are the root's file handlers, added
# for the duration of a job); with no handler, Python's last resort shows WARNING and above only
FILE_ONLY = logging.getLogger("diana_lab.console")
FILE_ONLY.propagate = False
FILE_ONLY.setLevel(logging.INFO)  # the console's lines whatever the root logger's level
_INSTALLED: list[logging.Handler] = []  # the job's file handlers, while console_to_log_file runs

# terminal control: CSI (cursor moves, erase, colours), OSC (titles, links) and the other two-byte escapes
_ESCAPES = re.compile(r"\x1b\[[0-?]*[ -/]*[@-~]|\x1b\][^\x07\x1b]*(?:\x07|\x1b\\)|\x1b[@-Z\\-_]")
# a progress bar's own line: tqdm's ' 42%|####  | 4/10 [...]' or rich's '━━━━' (and its half cells; squeezed
# into a narrow console, rich wraps the rest of the bar onto a line of its own that holds only '…')
_BAR = re.compile(r"\d+%\|.*\||[━╸╺]")
_MAX_PENDING = 1 << 16  # an unfinished line longer than this is written out as it is


def plain_line(line: str) -> str | None:
    """What ``line`` leaves on a terminal, without control codes; ``None`` for a bar or nothing visible."""
    text = _ESCAPES.sub("", line.rstrip("\r"))
    text = text.rsplit("\r", 1)[-1].rstrip()  # a line redrawn after a carriage return shows its last drawing
    text = "".join(c for c in text if c == "\t" or c >= " ")
    if not text.strip(" \t…") or _BAR.search(text):
        return None
    return text


def log_only(line: str, level: int = logging.INFO) -> None:
    """Write ``line`` to the job's log file only (nothing on the console; nothing outside a Hydra job)."""
    if _INSTALLED:
        FILE_ONLY.log(level, line)


class _Tee:
    """A text stream that writes through to ``stream`` and hands every finished line to ``sink``; any other
    attribute (``isatty``, ``fileno``, ``encoding``...) is the stream's, so a bar still sees its terminal."""

    def __init__(self, stream: TextIO, sink: Callable[[str], None]) -> None:
        self._stream = stream
        self._sink = sink
        self._pending = ""
        self._lock = threading.Lock()

    def write(self, text: str) -> int:
        written = self._stream.write(text)
        with contextlib.suppress(Exception):  # the log file must never break the console
            self._capture(text)
        return written

    def writelines(self, lines: Any) -> None:
        for line in lines:
            self.write(line)

    def flush(self) -> None:
        self._stream.flush()

    def _capture(self, text: str) -> None:
        with self._lock:
            pending = self._pending + text
            *lines, pending = pending.split("\n")
            head, cr, tail = pending.rpartition("\r")
            if cr and tail:  # redrawn in place: only the last drawing can still show
                pending = cr + tail
            if len(pending) > _MAX_PENDING:
                lines.append(pending)
                pending = ""
            self._pending = pending
        for line in lines:
            shown = plain_line(line)
            if shown is not None:
                self._sink(shown)

    def close_line(self) -> None:
        """Hand on an unfinished last line (the job ends without a newline)."""
        with self._lock:
            pending, self._pending = self._pending, ""
        shown = plain_line(pending)
        if shown is not None:
            self._sink(shown)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def log_file_handlers() -> list[logging.FileHandler]:
    """The root logger's file handlers: Hydra's ``job_logging`` ``file`` handler in a job, none elsewhere (pytest's
    ``/dev/null`` one left out)."""
    root = logging.getLogger()
    return [h for h in root.handlers if isinstance(h, logging.FileHandler) and h.baseFilename != os.devnull]


@contextlib.contextmanager
def console_to_log_file() -> Iterator[bool]:
    """For the duration of the block, every line written to ``sys.stdout`` (level INFO) and ``sys.stderr``
    (WARNING) also goes to the job's log file. Yields whether there was a log file to write to."""
    handlers = [h for h in log_file_handlers() if h not in _INSTALLED]
    if not handlers:
        yield False
        return
    # as at import: a logging config since (Hydra's, per job) may have disabled it or, naming a parent, reset it
    FILE_ONLY.propagate, FILE_ONLY.disabled = False, False
    FILE_ONLY.setLevel(logging.INFO)
    for handler in handlers:
        FILE_ONLY.addHandler(handler)
        _INSTALLED.append(handler)
    saved = sys.stdout, sys.stderr
    out = _Tee(sys.stdout, lambda line: FILE_ONLY.info(line))
    err = _Tee(sys.stderr, lambda line: FILE_ONLY.warning(line))
    sys.stdout, sys.stderr = out, err  # type: ignore[assignment]
    try:
        yield True
    finally:
        # put back what we replaced; something that replaced us since (and did not restore) is left alone
        if sys.stdout is out:
            sys.stdout = saved[0]
        if sys.stderr is err:
            sys.stderr = saved[1]
        out.close_line()
        err.close_line()
        for handler in handlers:
            FILE_ONLY.removeHandler(handler)
            _INSTALLED.remove(handler)
            with contextlib.suppress(Exception):
                handler.flush()
