"""Pictures of a game state for people: the GIF of a trained team, TensorBoard's evaluation image and
the docs' map picture; and another game's own frames with a caption (:func:`captioned`).

The game's own ``render_rgb`` is a bare array of coloured cells for the RL faces; this draws with
Pillow what a viewer needs to follow an episode: the grid, obstacles (dark grey), traps (red, crossed),
chests full (gold) and emptied (a hollow gold frame), each agent as a disc of its colour with its
number (a ring once it is done, where it ended), each agent's trail so far in its colour, and a
caption under the grid.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from dqn_transfer.envs.game import AGENT_COLOURS, COLOURS
from dqn_transfer.envs.maps import GridMap

WHITE, INK = (255, 255, 255), (30, 30, 30)
CHEST_EDGE = (150, 100, 0)
CAPTION_BACKGROUND = (250, 250, 250)
# Where each of m agents sharing a cell stands, as fractions of the cell (so every number stays visible).
SHARED_CELL_SPOTS = {1: [(0.5, 0.5)], 2: [(0.3, 0.5), (0.7, 0.5)], 3: [(0.3, 0.3), (0.7, 0.3), (0.5, 0.72)]}
QUARTERS = [(0.3, 0.3), (0.7, 0.3), (0.3, 0.7), (0.7, 0.7)]


@lru_cache(maxsize=8)
def font(size: int) -> ImageFont.FreeTypeFont:
    """Pillow's own scalable font (no system font needed) at ``size`` pixels."""
    loaded = ImageFont.load_default(size=size)
    if not isinstance(loaded, ImageFont.FreeTypeFont):  # Pillow built without FreeType: no scalable font
        raise RuntimeError("drawing needs Pillow with FreeType support (its scalable default font)")
    return loaded


def agent_colour(agent: int) -> tuple[int, int, int]:
    return tuple(int(v) for v in AGENT_COLOURS[agent % len(AGENT_COLOURS)])  # type: ignore[return-value]


def draw_state(
    grid_map: GridMap,
    positions: np.ndarray,
    live: np.ndarray,
    chest_full: np.ndarray,
    trails: Sequence[np.ndarray] = (),
    caption: Sequence[str] = (),
    cell_px: int = 40,
) -> Image.Image:
    """One picture of a game state.

    ``positions [K, 2]`` (row, col) of every agent, ``live [K]``, ``chest_full [k]`` (chests in the
    map's row-major order), ``trails``: per agent the ``[T, 2]`` cells it has stood on so far, oldest
    first; ``caption``: lines of text under the grid.
    """
    n = grid_map.size
    text = font(max(10, cell_px * 3 // 10 + 2))
    image = Image.new("RGB", (n * cell_px, n * cell_px + caption_height(caption, text)), CAPTION_BACKGROUND)
    draw = ImageDraw.Draw(image)
    _draw_cells(draw, grid_map, chest_full, cell_px)
    for agent, trail in enumerate(trails):
        _draw_trail(draw, trail, agent, len(trails), cell_px)
    _draw_agents(draw, positions, live, cell_px)
    _write_caption(draw, n * cell_px, caption, text)
    return image


def caption_height(caption: Sequence[str], text: ImageFont.FreeTypeFont) -> int:
    """The pixels ``caption``'s lines take under a picture in the font ``text`` (0 for no caption).

    :param caption: the lines.
    :param text: their font.
    """
    return len(caption) * (int(text.size) + 4) + 6 if caption else 0


def _write_caption(draw: ImageDraw.ImageDraw, top: int, caption: Sequence[str], text: ImageFont.FreeTypeFont) -> None:
    for i, line in enumerate(caption):
        draw.text((4, top + 3 + i * (int(text.size) + 4)), line, fill=INK, font=text)


def captioned(picture: np.ndarray, caption: Sequence[str], text_px: int = 14) -> Image.Image:
    """An env's own RGB frame ``[H, W, 3]`` (another game's, drawn by its ``render()``) with ``caption``'s
    lines under it, as the treasure hunt's pictures have theirs.

    :param picture: the frame, uint8.
    :param caption: lines of text under it.
    :param text_px: the font's size in pixels.
    """
    text = font(text_px)
    height, width = picture.shape[:2]
    image = Image.new("RGB", (width, height + caption_height(caption, text)), CAPTION_BACKGROUND)
    image.paste(Image.fromarray(picture), (0, 0))
    _write_caption(ImageDraw.Draw(image), height, caption, text)
    return image


def _box(r: int, c: int, cell_px: int, inset: float) -> tuple[float, float, float, float]:
    pad = cell_px * inset
    return c * cell_px + pad, r * cell_px + pad, (c + 1) * cell_px - pad, (r + 1) * cell_px - pad


def _draw_cells(draw: ImageDraw.ImageDraw, grid_map: GridMap, chest_full: np.ndarray, cell_px: int) -> None:
    n = grid_map.size
    draw.rectangle((0, 0, n * cell_px - 1, n * cell_px - 1), fill=COLOURS["free"])
    for r, c in grid_map.obstacles:
        draw.rectangle(_box(r, c, cell_px, 0), fill=COLOURS["obstacle"])
    for r, c in grid_map.traps:
        draw.rectangle(_box(r, c, cell_px, 0), fill=COLOURS["trap"])
        x0, y0, x1, y1 = _box(r, c, cell_px, 0.25)
        width = max(2, cell_px // 12)
        draw.line((x0, y0, x1, y1), fill=INK, width=width)
        draw.line((x0, y1, x1, y0), fill=INK, width=width)
    edge = max(2, cell_px // 14)
    for chest, (r, c) in enumerate(grid_map.chests):
        full = bool(chest_full[chest])
        draw.rectangle(
            _box(r, c, cell_px, 0.12),
            fill=COLOURS["chest_full"] if full else COLOURS["free"],
            outline=CHEST_EDGE,
            width=edge,
        )
    for i in range(n + 1):  # grid lines
        draw.line((0, i * cell_px, n * cell_px, i * cell_px), fill=COLOURS["grid"])
        draw.line((i * cell_px, 0, i * cell_px, n * cell_px), fill=COLOURS["grid"])


def _draw_trail(draw: ImageDraw.ImageDraw, trail: np.ndarray, agent: int, team: int, cell_px: int) -> None:
    """Segments between consecutive cells, shifted a little per agent so that shared paths stay apart.
    A jump (an obstacle sent the agent back to its start) and a stay draw nothing."""
    shift = (agent - (team - 1) / 2) * cell_px / 8
    centres = (trail[:, ::-1] * cell_px + (cell_px / 2 + shift)).tolist()  # (x, y) of each cell's centre
    moves = (np.abs(np.diff(trail, axis=0)).sum(axis=1) == 1).tolist()  # to a neighbouring cell
    colour, width = agent_colour(agent), max(2, cell_px // 10)
    for i in np.flatnonzero(moves).tolist():
        draw.line((*centres[i], *centres[i + 1]), fill=colour, width=width)


def _draw_agents(draw: ImageDraw.ImageDraw, positions: np.ndarray, live: np.ndarray, cell_px: int) -> None:
    """Live agents as filled discs with their number in white, done ones as rings with a coloured number."""
    by_cell: dict[tuple[int, int], list[int]] = {}
    for agent, (r, c) in enumerate(positions.tolist()):
        by_cell.setdefault((r, c), []).append(agent)
    for (r, c), agents in by_cell.items():
        spots = SHARED_CELL_SPOTS.get(len(agents), QUARTERS * 3)
        radius = cell_px * (0.36 if len(agents) == 1 else 0.22)
        label = font(max(9, int(radius * 1.2)))
        for agent, (fx, fy) in zip(agents, spots):
            x, y = (c + fx) * cell_px, (r + fy) * cell_px
            colour = agent_colour(agent)
            disc = (x - radius, y - radius, x + radius, y + radius)
            if live[agent]:
                draw.ellipse(disc, fill=colour, outline=WHITE, width=max(1, cell_px // 20))
            else:
                draw.ellipse(disc, fill=WHITE, outline=colour, width=max(2, cell_px // 12))
            draw.text((x, y), str(agent), fill=WHITE if live[agent] else colour, font=label, anchor="mm")
