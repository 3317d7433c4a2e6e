"""Pages taken from the repository's Markdown files at build time: the README (landing page) and the
benchmark results, with their links to each other turned into links between the pages."""

from __future__ import annotations

from pathlib import Path

from physar_formats import write_if_changed

# (source in the repository, generated page, links to rewrite); readme.md is included by index.md, so its
# links are relative to docs/
PAGES = (("README.md", "readme.md", {"](benchmarks/RESULTS.md)": "](_generated/benchmarks.md)"}),
         ("benchmarks/RESULTS.md", "benchmarks.md", {}))


def write_pages(src: Path, repo: Path) -> None:
    """Copy each page into ``src/_generated`` with its links rewritten."""
    for source, page, links in PAGES:
        text = (repo / source).read_text()
        for old, new in links.items():
            text = text.replace(old, new)
        write_if_changed(src / "_generated" / page, text)


def _generate(app) -> None:
    write_pages(Path(app.srcdir), Path(app.srcdir).parent)


def setup(app):
    app.connect("builder-inited", _generate)
    return {"parallel_read_safe": True, "version": "1"}
