"""Rendered frames that explain themselves: a title strip above the road (scenario, case, time),
a legend strip below it (what each car colour means) and notices drawn over the road (a car that
left the episode, and why). Used by the demo's GIF and tools/play.py's window and recordings.

Text is drawn with Pillow's built-in font (Pillow comes with matplotlib), so the same frames come
out on every machine with the same Pillow.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from carlo_lite.render import DEFAULT_CAR_COLOR, ROLE_COLORS

STRIP_COLOR = (248, 248, 248)  # background of the title and legend strips
TEXT_COLOR = (20, 20, 20)
NOTICE_COLOR = (190, 30, 30)  # background of a notice over the road
NOTICE_TEXT_COLOR = (255, 255, 255)
FONT_PX = 13
STRIP_PX = 22  # height of the title strip and of each legend row
SWATCH_PX = 12  # side of a legend's colour square
NOTICE_SECONDS = 3.0  # how long a notice stays on screen

# what the car colours mean, by scenario family (the name before any version suffix)
ROLE_MEANINGS: dict[str, dict[str, str]] = {
    "halting_car": {
        "main_green": "follower (green)",
        "main_brown": "leader, may stop (brown)",
        "distractor": "other cars",
    },
    "double_merge": {
        "main_green": "main car (green)",
        "main_brown": "main car (brown)",
        "distractor": "other cars",
    },
    "left_turn": {
        "main_green": "turning car (green)",
        "main_brown": "oncoming cars (brown)",
        "distractor": "other cars",
    },
    "roundabout_entry": {
        "main_green": "entering car (green)",
        "main_brown": "circulating car (brown)",
        "distractor": "other cars",
    },
}
GENERIC_MEANINGS = {"main_green": "main car (green)", "main_brown": "main car (brown)"}
REMOVAL_REASONS = {"collided": "collided", "off_road": "left the road"}


@dataclass(frozen=True)
class Notice:
    """A line over the road from the frame of step `first` to `last` (inclusive)."""

    text: str
    first: int
    last: int


def _font() -> ImageFont.ImageFont:
    return ImageFont.load_default(size=FONT_PX)


def role_meaning(scenario: str, role: str) -> str:
    """What a car of `role` is in `scenario`, e.g. "leader, may stop (brown)"."""
    family = next((name for name in ROLE_MEANINGS if scenario.startswith(name)), None)
    return ROLE_MEANINGS.get(family, GENERIC_MEANINGS).get(role, role.replace("_", " "))


def legend_entries(scenario: str, roles: Sequence[str]) -> list[tuple[str, tuple[int, int, int]]]:
    """(label, colour) of each distinct role in `roles`, main cars first (each group in the
    order of `roles`), as the renderer draws them (carlo_lite.render.ROLE_COLORS)."""
    distinct = sorted(dict.fromkeys(roles), key=lambda role: not role.startswith("main"))
    return [
        (role_meaning(scenario, role), ROLE_COLORS.get(role, DEFAULT_CAR_COLOR))
        for role in distinct
    ]


def removal_notice(scenario: str, agent: str, info: dict) -> str:
    """The line shown when `agent` leaves the episode, e.g. "car_0, follower (green), left the
    episode: collided" ("another car" for a distractor); `info` is its step info (role,
    collided, off_road)."""
    role = str(info.get("role", ""))
    what = role_meaning(scenario, role) if role.startswith("main") else "another car"
    return f"{agent}, {what}, left the episode: {removal_reason(info)}"


def removal_reason(info: dict) -> str:
    """Why an agent left the episode, from its step info ("collided", "left the road")."""
    reasons = [text for key, text in REMOVAL_REASONS.items() if info.get(key)]
    return " and ".join(reasons) or "ended"


def _legend_rows(
    draw: ImageDraw.ImageDraw, entries: Sequence[tuple[str, tuple]], width: int
) -> list[list[tuple[str, tuple, int]]]:
    """The legend's entries laid out in rows that fit `width`: (label, colour, x) each."""
    font, rows, row, x = _font(), [], [], 6
    for label, color in entries:
        span = SWATCH_PX + 4 + int(draw.textlength(label, font=font)) + 16
        if row and x + span > width:
            rows.append(row)
            row, x = [], 6
        row.append((label, color, x))
        x += span
    return rows + ([row] if row else [])


def annotate(
    frame: np.ndarray,
    title: str,
    legend: Sequence[tuple[str, tuple[int, int, int]]],
    notices: Sequence[str] = (),
) -> np.ndarray:
    """`frame` (H, W, 3) uint8 with `title` in a strip above it, `legend` ((label, colour)
    pairs: a colour square and its label) in strips below it, and each of `notices` on a red
    box over the road's top-left corner. Returns a new (H + strips, W, 3) uint8 array."""
    height, width = frame.shape[:2]
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    rows = _legend_rows(probe, legend, width)
    top, bottom = STRIP_PX, STRIP_PX * len(rows)
    canvas = Image.new("RGB", (width, top + height + bottom), STRIP_COLOR)
    canvas.paste(Image.fromarray(np.ascontiguousarray(frame[..., :3])), (0, top))
    draw, font = ImageDraw.Draw(canvas), _font()
    draw.text((6, (STRIP_PX - FONT_PX) // 2), title, fill=TEXT_COLOR, font=font)
    for k, row in enumerate(rows):
        y = top + height + k * STRIP_PX
        for label, color, x in row:
            square = (x, y + (STRIP_PX - SWATCH_PX) // 2)
            draw.rectangle(
                [square, (square[0] + SWATCH_PX - 1, square[1] + SWATCH_PX - 1)],
                fill=tuple(color),
                outline=TEXT_COLOR,
            )
            draw.text(
                (x + SWATCH_PX + 4, y + (STRIP_PX - FONT_PX) // 2),
                label,
                fill=TEXT_COLOR,
                font=font,
            )
    for k, text in enumerate(notices):
        y = top + 4 + k * (FONT_PX + 8)
        right = 6 + int(draw.textlength(text, font=font)) + 8
        draw.rectangle([(4, y), (right, y + FONT_PX + 5)], fill=NOTICE_COLOR)
        draw.text((8, y + 2), text, fill=NOTICE_TEXT_COLOR, font=font)
    return np.asarray(canvas, dtype=np.uint8).copy()


def active_notices(notices: Sequence[Notice], step: int) -> list[str]:
    """The texts of the notices shown at `step`."""
    return [notice.text for notice in notices if notice.first <= step <= notice.last]
