"""Text for the terminal: what a file says (a checkpoint's card, a config string, a path, an error naming them)
printed with its control characters escaped, so that no escape sequence in a damaged or hostile file reaches the
terminal raw."""

from __future__ import annotations


def printable(text: str) -> str:
    """`text` with every non-printable character (control characters, ANSI escapes, bidirectional overrides, line
    breaks) written as Python writes it in a string literal (`\\x1b`, `\\n`, `\\u202e`); printable text, non-ASCII
    letters included, unchanged."""
    text = str(text)
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)


def shortened(text: str, limit: int) -> str:
    """`text`, or its first `limit` characters and how many more there are."""
    return text if len(text) <= limit else f"{text[:limit]} ... ({len(text) - limit:,} more characters)"
