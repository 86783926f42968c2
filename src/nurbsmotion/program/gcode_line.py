"""One G-code line as it runs: its evaluated words sorted by kind, and where it is."""

from __future__ import annotations

from dataclasses import dataclass, field

from nurbsmotion.program.gcode_words import Word
from nurbsmotion.program.model import SourceRef


@dataclass
class GcodeLine:
    """One line being run: where it is, its evaluated words sorted by kind."""

    file: str
    number: int
    text: str
    g_words: list[Word] = field(default_factory=list)
    m_words: list[Word] = field(default_factory=list)
    words: dict[str, Word] = field(default_factory=dict)  # the words left for the motion
    claimed: dict[str, Word] = field(default_factory=dict)  # used by G4, G10, G28, G43, G64, M61, ...

    @property
    def where(self) -> str:
        return f"{self.file}:{self.number}"

    def at(self, word: Word | str | None) -> str:
        return f"{self.where}: {word}" if word else self.where

    @property
    def source(self) -> SourceRef:
        return SourceRef(self.file, self.number, self.text.strip())

    def g(self, code: int) -> Word | None:
        return next((w for w in self.g_words if round(w.value * 10) == code), None)

    def claim(self, letters: str) -> dict[str, Word]:
        got = {k: self.words.pop(k) for k in letters if k in self.words}
        self.claimed.update(got)
        return got


