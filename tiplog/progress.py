"""One progress line for the long commands (`tiplog sim generate`, `tiplog vision run`,
`tiplog fusion run`).

On a terminal the line is rewritten in place ("\\r"), at most every `min_interval_s`. Anywhere
else (a log file, a pipe, a CI log) an in-place line turns into one long line of carriage
returns, so nothing is written while the work runs and only the final line, if one is given,
ends up in the log.

    with Progress(sys.stderr, enabled=not args.quiet) as p:
        for k in ...:
            p.update(f"frame {k + 1}/{total}")
        p.close(f"frame {total}/{total} in {secs:.1f} s")
"""

from __future__ import annotations

import sys
import time
from types import TracebackType
from typing import TextIO


def is_terminal(stream: TextIO) -> bool:
    """Whether `stream` is an interactive terminal (False for files, pipes and streams without a
    file descriptor)."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):  # closed, or a stream without isatty
        return False


class Progress:
    """A status line: `update(text)` while the work runs, `close(final)` once at its end."""

    def __init__(self, stream: TextIO | None = None, *, enabled: bool = True, min_interval_s: float = 0.2) -> None:
        self.stream = sys.stderr if stream is None else stream
        self.enabled = enabled
        self.live = enabled and is_terminal(self.stream)  # in-place updates only on a terminal
        self.min_interval_s = min_interval_s
        self._last_t = -float("inf")
        self._width = 0  # length of the line on screen, to blank a longer one's tail
        self._closed = False

    def update(self, text: str, *, force: bool = False) -> None:
        """Show `text` in place of the previous line (terminal only; throttled unless `force`)."""
        if not self.live or self._closed:
            return
        now = time.monotonic()
        if not force and now - self._last_t < self.min_interval_s:
            return
        self._last_t = now
        self._write("\r" + text.ljust(self._width), end="")
        self._width = len(text)

    def close(self, final: str | None = None) -> None:
        """End the line: `final` (if given) as the last line on a terminal and in a log alike."""
        if self._closed:
            return
        self._closed = True
        if not self.enabled:
            return
        if self.live:
            if final is not None:
                self._write("\r" + final.ljust(self._width), end="\n")
            elif self._width:
                self._write("", end="\n")
        elif final is not None:
            self._write(final, end="\n")

    def _write(self, text: str, end: str) -> None:
        print(text, end=end, file=self.stream, flush=True)

    def __enter__(self) -> Progress:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()  # an interrupted run still ends its line on a terminal
