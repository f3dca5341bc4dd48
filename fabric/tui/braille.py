"""A braille dot canvas for drawing lines in a terminal: 2 x 4 dots per character cell, one style per cell."""
from __future__ import annotations

import numpy as np
from rich.text import Text

__all__ = ["BrailleCanvas"]

# Dot (dx, dy) inside a cell -> its bit in the braille pattern (U+2800 + bits).
_DOT_BITS = np.array([[0x01, 0x08], [0x02, 0x10], [0x04, 0x20], [0x40, 0x80]], dtype=np.uint8)


class BrailleCanvas:
    """``width`` x ``height`` character cells, that is ``2 * width`` x ``4 * height`` dots; y grows downwards.

    Each cell keeps the style of the last thing drawn into it with the highest ``rank``, so a
    nozzle marker drawn last with a high rank stays visible over the lines under it."""

    def __init__(self, width: int, height: int) -> None:
        self.width, self.height = max(1, width), max(1, height)
        self.bits = np.zeros((self.height, self.width), dtype=np.uint8)
        self.styles: list[list[str]] = [[""] * self.width for _ in range(self.height)]
        self.ranks = np.zeros((self.height, self.width), dtype=np.int16)
        self.marks: dict[tuple[int, int], tuple[str, str]] = {}

    @property
    def size_px(self) -> tuple[int, int]:
        return 2 * self.width, 4 * self.height

    def dots(self, x_px: np.ndarray, y_px: np.ndarray, style: str = "", rank: int = 0) -> None:
        """Set the dots at integer pixel coordinates (out-of-range dots are dropped)."""
        x = np.asarray(x_px, dtype=np.int64)
        y = np.asarray(y_px, dtype=np.int64)
        w_px, h_px = self.size_px
        keep = (x >= 0) & (x < w_px) & (y >= 0) & (y < h_px)
        x, y = x[keep], y[keep]
        cx, cy = x // 2, y // 4
        np.bitwise_or.at(self.bits, (cy, cx), _DOT_BITS[y % 4, x % 2])
        for row, col in set(zip(cy.tolist(), cx.tolist(), strict=True)):
            if rank >= self.ranks[row, col]:
                self.ranks[row, col] = rank
                self.styles[row][col] = style

    def lines(self, x0: np.ndarray, y0: np.ndarray, x1: np.ndarray, y1: np.ndarray, style: str = "",
              rank: int = 0) -> None:
        """Draw segments (pixel coordinates, floats allowed), sampled twice per pixel of length; dots are
        the pixels the samples fall in (floor of x + 0.5: ``np.rint`` rounds halves to even, which
        would skip every other pixel along a line through half-pixel coordinates)."""
        x0, y0, x1, y1 = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (x0, y0, x1, y1))
        if not len(x0):
            return
        steps = (2 * np.maximum(np.abs(x1 - x0), np.abs(y1 - y0))).astype(np.int64) + 2
        seg = np.repeat(np.arange(len(x0)), steps)
        start = np.repeat(np.cumsum(steps) - steps, steps)
        t = (np.arange(int(steps.sum())) - start) / np.maximum(steps[seg] - 1, 1)
        xs = np.floor(x0[seg] + (x1[seg] - x0[seg]) * t + 0.5)
        ys = np.floor(y0[seg] + (y1[seg] - y0[seg]) * t + 0.5)
        self.dots(xs, ys, style, rank)

    def mark(self, x_px: float, y_px: float, char: str, style: str) -> None:
        """Put a whole character (e.g. the nozzle) in the cell holding this pixel."""
        col, row = int(x_px) // 2, int(y_px) // 4
        if 0 <= col < self.width and 0 <= row < self.height:
            self.marks[(row, col)] = (char, style)

    def rows(self) -> list[Text]:
        """One rich Text per character row."""
        out = []
        for row in range(self.height):
            text = Text(no_wrap=True, overflow="crop")
            for col in range(self.width):
                if (row, col) in self.marks:
                    char, style = self.marks[(row, col)]
                    text.append(char, style)
                else:
                    text.append(chr(0x2800 + int(self.bits[row, col])), self.styles[row][col] or None)
            out.append(text)
        return out

    def render(self) -> Text:
        return Text("\n", no_wrap=True).join(self.rows())
