"""A crowd bead's highlight: where it sits from the bead's centre and how far it stands out of the bead's
body (crowd.highlight, crowd.highlight_contrast), learned while the bead's outline is seen all round it.
A smooth sphere's highlight stays at a fixed offset from its centre (the light and the view do not move
with it), so it centres the bead where its outline does not measure it, and confirms a bead carried by
the layer (MarkerTrack.confirm_carried)."""

from __future__ import annotations

import math

from . import crowd as crowd_rules
from .appearance import AppearanceModel
from .matcher import Match

CARRIED_AGREE_PX = 1.0  # a carried crowd marker's outline centre this near its carried position re-confirms it
HIGHLIGHT_ALPHA = 0.2  # share of a new measurement in a crowd bead's highlight offset (and contrast)
# Share of a crowd bead's own highlight contrast (learned with its offset) a highlight found must reach: the
# brightest point of a flat surface (the tool over a hidden bead) reaches its noise only (0.02-0.07 of it on the
# dense twin), a bead's own highlight, partly hidden or read across a neighbour's rim, 0.40-1.07.
HIGHLIGHT_CONTRAST_SHARE = 0.25
# A crowd bead's highlight is first looked for this far from its centre, in radii: anywhere on its body but
# its rim (a pixel's blur inside it: beyond, the bright sand or gap bleeds in, and a brightest point on
# the search's edge is no highlight).
HIGHLIGHT_FIRST_REACH = 0.8


class Highlight:
    def __init__(self, model: AppearanceModel):
        self.model = model
        self.offset: tuple | None = None  # the highlight - the bead's centre, px
        self.contrast: float | None = None  # how far the highlight stands out of the bead's body (crowd.py)

    def centre(self, frame_bgr, m: Match) -> bool:
        """A crowd match centred by its highlight where its outline does not measure it: the brightest
        point within half a radius of where this bead's highlight sits from the match's centre
        (crowd.highlight), less that offset (learned while its outline was seen all round it). A smooth
        sphere's highlight stays at a fixed offset from its centre (the light and the view do not move
        with it), and is its own: a neighbour's lies a bead's width away. So is measured a bead whose
        outline was not found (in a pressed layer the gaps between the beads close), and one whose
        outline's centre lies farther than CARRIED_AGREE_PX from where its highlight puts it (a
        neighbour's rim or a shadow pulled the outline: on the dense twin, of the 12 tracked frames
        where the two disagreed by more than 1 px, the highlight was the nearer the truth in 10, 0.27
        against 1.13 px median). Left as it is without a learned offset or a highlight there (held,
        when its outline was not found either). True when it moved m."""
        off = self.offset
        if off is None or m.rest:
            return False
        h = crowd_rules.highlight(frame_bgr, m.x + off[0], m.y + off[1], 0.5 * self.model.radius)
        if h is None or (m.outline and math.hypot(h[0] - off[0] - m.x, h[1] - off[1] - m.y) <= CARRIED_AGREE_PX):
            return False
        m.x, m.y = h[0] - off[0], h[1] - off[1]
        m.outline = m.used_centroid = m.lit = True
        return True

    def agree_px(self) -> float:
        """How far from where it was carried a crowd bead's highlight may put its centre (confirm_carried):
        so far that, were that centre the bead's, the highlight's search (half a radius around the carried
        place plus the offset) lay wholly on the bead's body, a pixel's blur inside its rim: the brightest
        point found there is then its own highlight, not the sand between the beads; never under
        CARRIED_AGREE_PX."""
        off = self.offset
        return max(CARRIED_AGREE_PX, self.model.radius - 1.0 - math.hypot(*off) - self.reach())

    def own(self, frame_bgr, h: tuple, searched: tuple, centre: tuple) -> bool:
        """A highlight `h` found by a search around `searched`, farther from where the bead was carried than
        agree_px allows, is this bead's own, the bead centred at `centre`: the search's accepted
        part (crowd.highlight takes no point within a pixel of its edge) lay on that bead's body, a pixel's
        blur inside its rim, so the sand between the beads was not searched; and it stands out of that body
        as this bead's own highlight does (stands_out, with its contrast learned)."""
        if self.contrast is None:
            return False
        reach = math.hypot(searched[0] - centre[0], searched[1] - centre[1]) + self.reach()
        return reach <= self.model.radius and self.stands_out(frame_bgr, h, centre)

    def stands_out(self, frame_bgr, h: tuple, centre: tuple) -> bool:
        """The highlight `h` stands out of the body of a bead centred at `centre` (crowd.highlight_contrast)
        by at least HIGHLIGHT_CONTRAST_SHARE of what this bead's own highlight did where its outline was seen
        all round it: the brightest point of the tool over a hidden bead stands out by its noise only (1-3
        grey levels on the dense twin, against 41-47 of the beads' own highlights beside it). True while no
        contrast is learned, or near the image's edge."""
        k = self.contrast
        if k is None:
            return True
        c = crowd_rules.highlight_contrast(frame_bgr, h[0], h[1], centre[0], centre[1], self.model.radius)
        return not math.isfinite(c) or c >= HIGHLIGHT_CONTRAST_SHARE * k

    def reach(self) -> float:
        """How far from where a carried crowd bead's highlight should be it is looked for (MarkerTrack.confirm_carried):
        half a radius, but no farther than keeps the search on the bead's body, a pixel's blur inside its rim,
        were the bead where it was carried (a bead whose highlight sits far from its centre, as in a slanted
        view, would otherwise reach its rim and the sand beyond, brighter than the highlight, and find none)."""
        return min(0.5 * self.model.radius, self.model.radius - 1.0 - math.hypot(*self.offset))

    def learn(self, frame_bgr, m: Match) -> None:
        """Where this crowd bead's highlight sits from its centre, from a frame that measured its outline
        all round it (a running mean)."""
        off = self.offset
        r = self.model.radius
        h = crowd_rules.highlight(frame_bgr, m.x + (off[0] if off else 0.0), m.y + (off[1] if off else 0.0),
                                  0.5 * r if off else HIGHLIGHT_FIRST_REACH * r)
        if h is None:
            return
        d = (h[0] - m.x, h[1] - m.y)
        self.offset = d if off is None else (off[0] + HIGHLIGHT_ALPHA * (d[0] - off[0]),
                                                       off[1] + HIGHLIGHT_ALPHA * (d[1] - off[1]))
        c = crowd_rules.highlight_contrast(frame_bgr, h[0], h[1], m.x, m.y, r)
        if math.isfinite(c):
            k = self.contrast
            self.contrast = c if k is None else k + HIGHLIGHT_ALPHA * (c - k)
