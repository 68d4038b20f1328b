"""A fast marker smeared into a streak during the exposure: from which speed, and which exposures are tried
(by the template matcher, matcher.py, and a marker's brightness pattern, luma.py)."""

STREAK_MIN_SPEED = 4.0  # px per frame from which a marker may be smeared into a streak
STREAK_EXPOSURES = (0.5, 1.0)  # exposures tried, in frames
