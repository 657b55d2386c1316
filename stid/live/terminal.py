"""The live view on a terminal: a table redrawn in place; plain lines when piped.

On a terminal the table is rewritten where it stands (the cursor goes back up over
it), and a message (a logger's warning, an event) is printed above it, where it stays.
Piped, each update is a block of plain lines, each starting with the data's seconds,
so a log of them reads as a history.
"""

from __future__ import annotations

import shutil
import sys
import textwrap

from stid.live.estimator import Update


def _num(x: float) -> str:
    return f"{x:.4g}"


def render(up: Update) -> list[str]:
    """The lines of one update."""
    head = (f"stid live  {up.path}  {up.model}  {up.seconds:.0f} s of data ({up.driving_s:.0f} s fitted)"
            f"  update {up.seq}, {up.cpu_s:.2f} s CPU" + ("  [file finished]" if up.finished else ""))
    lines = [head]
    if up.params:
        lines.append(f"  {'parameter':<12}{'value':>12}  {'unit':<8}{'95%':>10}  target")
        for p in up.params:
            pct = f"±{p.percent:.1f}%" if p.percent is not None else "-"
            if p.target is None:
                aim = ""
            else:
                aim = f"≤ {p.target:g}%  " + ("reached" if p.met else "not yet")
            lines.append(f"  {p.name:<12}{_num(p.value):>12}  {p.unit:<8}{pct:>10}  {aim}")
        lines.append("  fit: " + "   ".join(f"{k} {v:.1f}%" for k, v in up.fit.items() if v == v)
                     + f"   (cornering stiffness per axle; targets from {up.targets_from})")
    for s in up.state:
        lines.append(f"  ! {s}")
    for s in up.lacking:
        lines.append(f"  still lacking: {s}")
    if up.diagnosis:
        lines.append(f"  {up.diagnosis}")
    if up.done:
        lines.append(f"  {up.done}")
    return lines


class TerminalView:
    def __init__(self, stream=None, tty: bool | None = None):
        self.stream = stream or sys.stdout
        self.tty = self.stream.isatty() if tty is None else tty
        self._drawn = 0  # lines of the table on screen (terminal only)
        self._last: Update | None = None

    def show(self, up: Update) -> None:
        self._last = up
        lines = render(up)
        if self.tty:
            width = shutil.get_terminal_size((100, 24)).columns
            # wrapped here, each piece a line the redraw counts (a line the terminal wraps itself
            # would break the redraw, and one cut short would lose its end: "the run is enough")
            lines = [piece for line in lines for piece in
                     (textwrap.wrap(line, width - 1, subsequent_indent=" " * (len(line) - len(line.lstrip()) + 4))
                      or [""])]
            self._erase()
            self.stream.write("\n".join(lines) + "\n")
            self._drawn = len(lines)
        else:
            stamp = f"[{up.seconds:6.1f} s]"
            self.stream.write("\n".join(f"{stamp} {line.strip()}" for line in lines) + "\n")
        self.stream.flush()

    def message(self, text: str) -> None:
        """A line that stays (above the table on a terminal)."""
        if self.tty:
            self._erase()
            self.stream.write(text + "\n")
            self._drawn = 0
            if self._last is not None:
                self.show(self._last)
                return
        else:
            # stamped as the updates are, in seconds of data (of the last update: the line came after
            # it): a clock time among them read as another kind of number
            seconds = self._last.seconds if self._last is not None else 0.0
            self.stream.write(f"[{seconds:6.1f} s] {text}\n")
        self.stream.flush()

    def _erase(self) -> None:
        if self._drawn:
            # up to the table's first line, then clear to the end of the screen
            self.stream.write(f"\x1b[{self._drawn}F\x1b[J")
