"""A contact sheet of one episode, laid out as an appendix figure: a title, one column per chosen step (its number
above it), one row per kind of panel (the viewer camera, each view the policy saw, a slot encoder's masks of one
camera), each row named on the left, on white."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

GAP = 4
LABEL_WIDTH = 96  # the row names' column
TITLE_HEIGHT = 34  # two lines of title
HEADER_HEIGHT = 16  # the step numbers above the columns
INK = (20, 20, 20)
PAPER = (255, 255, 255)


def sheet_steps(steps: int, count: int, deciding: int | None = None) -> list[int]:
    """``count`` frames spread evenly over an episode of ``steps`` actions, from the reset (0) to the end (steps);
    fewer where the episode is shorter than that. A ``deciding`` step (a Near Miss's closest approach, a Drop's
    lost grasp) takes the place of the nearest frame between the first and the last, so the sheet shows what
    decided the class."""
    if count < 2:
        raise ValueError(f"gallery.sheet_frames must be at least 2 (the first and the last), got {count}")
    chosen = sorted({int(k) for k in np.round(np.linspace(0, steps, count))})
    if deciding is None or deciding in chosen:
        return chosen
    if not 0 <= deciding <= steps:
        raise ValueError(f"deciding step {deciding} is outside the episode's steps 0..{steps}")
    inner = chosen[1:-1]
    if inner:
        chosen.remove(min(inner, key=lambda k: (abs(k - deciding), k)))
    return sorted([*chosen, deciding])


@dataclass(frozen=True)
class Layout:
    width: int
    height: int
    cell: int
    origins: dict[tuple[int, int], tuple[int, int]]  # (row, column) -> the top-left pixel of its cell


def layout(rows: int, columns: int, cell: int) -> Layout:
    """Where each (row, column) cell of a sheet goes, and the sheet's size."""
    if rows < 1 or columns < 1 or cell < 1:
        raise ValueError(f"a sheet needs rows, columns and a cell size, got {rows}, {columns}, {cell}")
    origins = {(r, c): (LABEL_WIDTH + GAP + c * (cell + GAP), TITLE_HEIGHT + HEADER_HEIGHT + r * (cell + GAP))
               for r in range(rows) for c in range(columns)}
    width = LABEL_WIDTH + GAP + columns * (cell + GAP)
    height = TITLE_HEIGHT + HEADER_HEIGHT + rows * (cell + GAP)
    return Layout(width, height, cell, origins)


def contact_sheet(title: list[str], row_names: list[str], steps: list[int], panels: list[list[np.ndarray]],
                  cell: int):
    """``panels[r][c]``: row r's image at ``steps[c]`` (any square size: scaled to ``cell``, nearest neighbour
    where it is enlarged so the policy's pixels stay visible) -> a PIL image."""
    from PIL import Image, ImageDraw

    from .overlay import FONT_SIZE, _font

    if len(panels) != len(row_names) or any(len(row) != len(steps) for row in panels):
        raise ValueError(f"{len(row_names)} rows x {len(steps)} steps of panels expected, got "
                         f"{[len(row) for row in panels]}")
    grid = layout(len(row_names), len(steps), cell)
    sheet = Image.new("RGB", (grid.width, grid.height), PAPER)
    draw = ImageDraw.Draw(sheet)
    font = _font()
    for i, line in enumerate(title[:2]):
        draw.text((GAP, GAP + i * (FONT_SIZE + 4)), line, fill=INK, font=font)
    for c, step in enumerate(steps):
        x, y = grid.origins[0, c]
        draw.text((x, y - HEADER_HEIGHT + 2), f"step {step}", fill=INK, font=font)
    for r, name in enumerate(row_names):
        x, y = grid.origins[r, 0]
        words, line, lines = name.split(" "), "", []
        for word in words:  # the name wrapped to the label column
            longer = f"{line} {word}".strip()
            if line and draw.textlength(longer, font=font) > LABEL_WIDTH - GAP:
                lines.append(line)
                line = word
            else:
                line = longer
        lines.append(line)
        for j, text in enumerate(lines):
            draw.text((GAP, y + j * (FONT_SIZE + 3)), text, fill=INK, font=font)
        for c in range(len(steps)):
            image = Image.fromarray(np.ascontiguousarray(panels[r][c]))
            resample = Image.Resampling.NEAREST if image.width <= cell else Image.Resampling.LANCZOS
            sheet.paste(image.resize((cell, cell), resample), grid.origins[r, c])
    return sheet
