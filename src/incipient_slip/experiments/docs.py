"""Generated blocks in hand-written docs pages: markdown between `<!-- BEGIN name -->` and
`<!-- END name -->`.

A page keeps its prose; an experiment's `render()` returns {name: markdown} and only the text
between that name's markers changes. A block without markers in an existing page is an error
(the page's author decides where numbers go); markers without a block stay as they are.
"""
from __future__ import annotations

from pathlib import Path


class DocsError(ValueError):
    """A page lacks the markers of a block, or has them out of order or twice."""


def markers(name: str) -> tuple[str, str]:
    """Return the begin and end marker lines of block `name`."""
    return f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"


def replace_blocks(text: str, blocks: dict[str, str], where: str = "page") -> str:
    """Return `text` with every block of `blocks` put between its markers."""
    for name, body in blocks.items():
        begin, end = markers(name)
        if text.count(begin) != 1 or text.count(end) != 1:
            raise DocsError(f"{where}: needs exactly one '{begin}' and one '{end}' for the "
                            f"generated block {name!r} (found {text.count(begin)} and {text.count(end)})")
        head, rest = text.split(begin, 1)
        if end not in rest:
            raise DocsError(f"{where}: '{end}' comes before '{begin}'")
        tail = rest.split(end, 1)[1]
        text = f"{head}{begin}\n{body.strip(chr(10))}\n{end}{tail}"
    return text


def new_page(title: str, blocks: dict[str, str]) -> str:
    """Return a page holding only `blocks` (each between its markers), for runs without docs."""
    parts = [f"# {title}", ""]
    for name, body in blocks.items():
        begin, end = markers(name)
        parts += [begin, body.strip("\n"), end, ""]
    return "\n".join(parts)


def write_blocks(path: Path, blocks: dict[str, str], title: str = "") -> Path:
    """Write `blocks` into the page at `path` (a new page with `title` if there is none)."""
    path = Path(path)
    if path.exists():
        text = replace_blocks(path.read_text(), blocks, where=str(path))
    else:
        text = new_page(title or path.stem, blocks)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path
