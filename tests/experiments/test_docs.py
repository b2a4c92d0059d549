"""Generated blocks between markers in hand-written pages (experiments.docs)."""
import pytest
from hypothesis import given
from hypothesis import strategies as st

from incipient_slip.experiments.docs import DocsError, markers, new_page, replace_blocks, write_blocks

PAGE = """# Title

Hand-written prose before.

<!-- BEGIN table -->
old table
<!-- END table -->

Prose between, naming `slip reproduce x`.

<!-- BEGIN other -->
kept as is
<!-- END other -->
"""


def test_only_the_text_between_a_blocks_markers_changes():
    text = replace_blocks(PAGE, {"table": "| a |\n|---|\n| 1 |"})
    assert text == PAGE.replace("old table", "| a |\n|---|\n| 1 |")


def test_a_block_without_markers_in_the_page_is_an_error_naming_page_and_block():
    with pytest.raises(DocsError, match=r"docs/x.md: .*'<!-- BEGIN missing -->'.*'missing'"):
        replace_blocks(PAGE, {"missing": "x"}, where="docs/x.md")


def test_markers_twice_or_out_of_order_are_errors():
    begin, end = markers("table")
    with pytest.raises(DocsError):
        replace_blocks(PAGE + f"\n{begin}\n{end}\n", {"table": "x"})
    with pytest.raises(DocsError, match="comes before"):
        replace_blocks(f"{end}\n{begin}\n", {"table": "x"})


@given(st.text(alphabet=st.characters(blacklist_characters="<>", blacklist_categories=("Cs",)), max_size=80))
def test_writing_a_block_twice_gives_the_same_page(body):
    once = replace_blocks(PAGE, {"table": body})
    assert replace_blocks(once, {"table": body}) == once
    assert once.startswith("# Title\n\nHand-written prose before.\n") and once.endswith(PAGE[PAGE.index("\nProse between"):])


def test_a_new_page_holds_every_block_and_can_be_rewritten(tmp_path):
    path = write_blocks(tmp_path / "sub" / "page.md", {"a": "one", "b": "two"}, title="T")
    assert path.read_text() == new_page("T", {"a": "one", "b": "two"})
    write_blocks(path, {"b": "three"})
    assert "one" in path.read_text() and "three" in path.read_text() and "two" not in path.read_text()
