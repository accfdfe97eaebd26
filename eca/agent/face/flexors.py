"""The flexor set: the face's whole state is one ordered vector of these pseudo-muscles.

Perlin's ResponsiveFace had twelve (turn, nod, tilt, sayAh, sayOo, blink, lids, brows, lookX, lookY,
smile, sneer); we split the ones that have a left and right side and add the few mouth shapes the
lip-sync visemes need (spread, closure, fricative) plus the brow knit angry and worried faces need.
Every value lies in [-1, 1]: full contraction, relaxed 0, full extension.
"""

from __future__ import annotations

FLEXOR_NAMES: tuple[str, ...] = (
    "turn",  # head yaw, +1 = toward the agent's right
    "nod",  # head pitch, +1 = chin up
    "tilt",  # head roll, +1 = toward the agent's right shoulder
    "look_x",  # eye yaw, +1 = the agent's right at the configured maximum angle
    "look_y",  # eye pitch, +1 = up
    "blink_l",  # 1 = left lid fully closed
    "blink_r",
    "lids_l",  # upper lid: +1 wide open (surprise), -1 half-closed (bored, arrogant)
    "lids_r",
    "brow_l",  # +1 raised, -1 lowered
    "brow_r",
    "brows_knit",  # +1 inner brows drawn together and down (anger, worry)
    "smile_l",  # +1 mouth corner up and out, -1 down (sad)
    "smile_r",
    "sneer_l",  # +1 upper lip raised on that side
    "sneer_r",
    "say_ah",  # jaw open
    "say_oo",  # lips rounded
    "say_ee",  # lips spread
    "say_mm",  # lips pressed together (m, b, p)
    "say_ff",  # lower lip to upper teeth, narrow gap (f, v, s)
)

FLEXOR_INDEX: dict[str, int] = {name: i for i, name in enumerate(FLEXOR_NAMES)}
N_FLEXORS = len(FLEXOR_NAMES)
