"""Checks shared by the tests of the folders the commands write."""

from pathlib import Path


def _references(page: Path) -> list[str]:
    """Every href and src of an HTML page, which must parse."""
    from html.parser import HTMLParser

    found = []

    class Refs(HTMLParser):
        def handle_starttag(self, tag, attrs):
            found.extend(v for k, v in attrs if k in ("href", "src") and v)

    parser = Refs()
    parser.feed(page.read_text())
    parser.close()
    return found


def check_folder(folder: Path) -> None:
    """report.html references only files that exist (pictures are embedded), and no written file
    names a temporary `.partial` folder."""
    refs = _references(folder / "report.html")
    assert any(r.startswith("data:image/png;base64,") for r in refs)
    for r in refs:
        assert r.startswith("data:image/png;base64,") or (folder / r).is_file(), r
    for f in folder.rglob("*"):
        if f.suffix in (".json", ".md", ".html", ".csv", ".txt"):
            assert ".partial" not in f.read_text(), f
