"""Invalid input, reported as file, line, dotted field path and what was expected."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Problem:
    """One thing wrong with an input file."""

    file: str
    line: int | None
    field: str
    message: str

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}" if self.line else self.file
        field = f" {self.field}:" if self.field else ""
        return f"{where}:{field} {self.message}"


class MissionError(Exception):
    """The mission (or a file it names) is invalid; exit code 2."""

    def __init__(self, problems: list[Problem]) -> None:
        self.problems = problems
        super().__init__("\n".join(str(p) for p in problems))


def utf8_text(raw: bytes, file: str) -> str:
    """``raw`` as UTF-8 text; else a problem at the file's own line and column."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        column = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        message = f"not a UTF-8 text file (byte 0x{raw[exc.start]:02x} at column {column})"
        raise MissionError([Problem(file, line, "", message)]) from None
