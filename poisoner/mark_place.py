"""Where a photo's mark went, as a viewer sees it, and why: the words ppd poison -v, the summary and
ppd preview print (issue 25). Out of poisoner/placement.py, which decides the place, so that both
placement and poisoner/shrink.py (round 3) build it without importing each other."""

from __future__ import annotations

from dataclasses import dataclass

from poisoner.orientation import position_words

# the per-file note's start when a mark's squares were cropped to fit (daemon/cli/poison_cmd.py counts it)
SHRUNK = "mark shrunk"

SOURCE_WORDS = {
    "masks": "from the subject mask: no subject pixel there",
    "estimated": "the plainest region of this photo (estimated from its detail)",
    "no-free-masks": "no region free of the subject mask: the least covered place, "
    "the mask's pixels left unwritten",
    "no-plain": "no plain region: the least detailed place, likely on the subject",
    "preferred": "the default place (nothing to judge on)",
    "masks-split": "from the subject mask: no place holds both squares, each in its own, no subject pixel",
    "estimated-split": "no plain place holds both squares: each in its own plainest place",
    "estimated-doubt-split": "the plain place for both squares showed faint texture, maybe part of the "
    "subject: each square in its own plain place",
}


@dataclass(frozen=True)
class MarkPlace:
    """Where a photo's mark went, as a viewer sees the photo, and why (ppd poison -v, preview).

    box: the mark's box (left, top, right, bottom) in display px of a `frame` (w, h) display frame;
    source: a SOURCE_WORDS key; free: False when no free region was found (the summary counts it)."""

    box: tuple[int, int, int, int]
    frame: tuple[int, int]
    source: str
    free: bool
    detail: float = 0.0
    subject: float | None = None
    orientation: int = 1
    anchor: tuple[int, int] = (0, 0)  # where the mark's path starts, display px (videos interpolate it)
    # round 3: (written side, full side) px of each square when no plain place held it whole and its
    # texture was cropped to fit one (poisoner.shrink); None: whole
    shrunk: tuple[int, int] | None = None
    # each square's box (display px) when they went to places of their own; () when stacked
    squares: tuple[tuple[int, int, int, int], ...] = ()

    @property
    def words(self) -> str:
        """`top-centre`; split squares: each one's (`top-right and bottom-centre`), not their box's
        middle, where neither is (a black-box review)."""
        if self.squares:
            return " and ".join(dict.fromkeys(position_words(b, *self.frame) for b in self.squares))
        return position_words(self.box, *self.frame)

    @property
    def why(self) -> str:
        return SOURCE_WORDS.get(self.source, self.source)

    def line(self) -> str:
        """`mark at the top-centre, within pixels (320,0)-(480,160) as shown (why)`: the box the
        squares lie in (they slide within it from photo to photo), not one square's."""
        turned = f", EXIF orientation {self.orientation}" if self.orientation != 1 else ""
        why = f"{self.why}; {self.shrunk_words}" if self.shrunk else self.why
        if self.squares:
            where = " and ".join(
                f"the {position_words(b, *self.frame)}, pixels ({b[0]},{b[1]})-({b[2]},{b[3]})"
                for b in self.squares
            )
            return f"mark in {len(self.squares)} squares, at {where} as shown{turned} ({why})"
        x0, y0, x1, y1 = self.box
        return f"mark at the {self.words}, within pixels ({x0},{y0})-({x1},{y1}) as shown{turned} ({why})"

    @property
    def shrunk_words(self) -> str:
        """`mark shrunk to 32 of 48 px (its squares cropped): ...` ('' when the mark is whole)."""
        if not self.shrunk:
            return ""
        side, full = self.shrunk
        return f"{SHRUNK} to {side} of {full} px (its squares cropped): no plain place holds it whole"

    def short(self) -> str | None:
        """The per-file note when the place is not free or the mark was shrunk (None otherwise)."""
        if self.free:
            return self.shrunk_words or None
        if self.source == "no-free-masks":
            return "mark partly on the subject mask (left unwritten there): no free region"
        return "mark on the subject: no plain region"
