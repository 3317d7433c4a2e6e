"""The gallery: ``examples/*.py`` executed by myst-nb as notebooks, with their figures and videos.

The examples are jupytext percent scripts whose text cells are Markdown (``# %% [markdown]``), so they are
read with jupytext and executed by myst-nb (sphinx-gallery would parse those cells as reStructuredText).
Each example becomes ``_generated/gallery/NAME.ipynb``: its docstring as the title and introduction, its
cells unchanged, a hidden first cell that sets ``PHYSAR_EXAMPLE_QUICK`` (unless ``PHYSAR_DOCS_FULL=1``)
and ``PHYSAR_EXAMPLE_OUT``, and after each code cell a hidden call of :func:`show_new` that displays the
figures the cell wrote (the examples save their figures to files and close them) and, for a video, its
first frame and a link to the file. A failing example fails the build (``nb_execution_raise_on_error``).
"""

from __future__ import annotations

import ast
import html
import io
import json
import os
import re
import shutil
from pathlib import Path

import jupytext
import nbformat
from physar_formats import write_if_changed

GALLERY = "gallery"  # folder under _generated/ and under the HTML output
THUMB = "thumbnail.png"  # an example's first picture, beside its videos
_seen: dict[Path, int] = {}
_ctx: dict[str, Path | str] = {}


def quick() -> bool:
    """Examples run in quick mode unless ``PHYSAR_DOCS_FULL=1``."""
    return os.environ.get("PHYSAR_DOCS_FULL") != "1"


def split_docstring(text: str) -> tuple[str, str]:
    """(module docstring, the rest of the script)."""
    tree = ast.parse(text)
    doc = ast.get_docstring(tree, clean=True) or ""
    if doc and isinstance(tree.body[0], ast.Expr):
        lines = text.splitlines(keepends=True)
        return doc, "".join(lines[tree.body[0].end_lineno:])
    return doc, text


def _markdown_doc(doc: str) -> str:
    """The docstring as Markdown: first line the title, ``literal`` as `literal`."""
    title, _, rest = doc.partition("\n")
    body = re.sub(r"``([^`]+)``", r"`\1`", rest.strip())
    return f"# {title.strip().rstrip('.')}\n\n{body}\n"


def example_notebook(script: Path, out_dir: Path, video_dir: Path, page_depth: int = 2) -> nbformat.NotebookNode:
    """The notebook of one example (no outputs: myst-nb executes it)."""
    doc, code = split_docstring(script.read_text())
    nb = jupytext.reads(code, fmt="py:percent")
    setup = "\n".join([
        "import os, sys",
        f"sys.path.insert(0, {str(Path(__file__).resolve().parent)!r})",
        f"os.environ['PHYSAR_EXAMPLE_OUT'] = {str(out_dir)!r}",
        *(["os.environ['PHYSAR_EXAMPLE_QUICK'] = '1'"] if quick() else ["os.environ.pop('PHYSAR_EXAMPLE_QUICK', None)"]),
        f"__file__ = {str(script.resolve())!r}",
        "import physar_gallery",
        f"physar_gallery.start({str(out_dir)!r}, {str(video_dir)!r}, {'../' * page_depth + GALLERY + '_files/' + script.stem!r})",
    ])
    cells = [nbformat.v4.new_markdown_cell(_markdown_doc(doc)),
             nbformat.v4.new_code_cell(setup, metadata={"tags": ["remove-cell"]})]
    for cell in nb.cells:
        if cell.cell_type == "code" and not cell.source.strip():
            continue
        cells.append(cell)
        if cell.cell_type == "code":
            cells.append(nbformat.v4.new_code_cell("physar_gallery.show_new()", metadata={"tags": ["remove-input"]}))
    if quick():
        cells.append(nbformat.v4.new_markdown_cell(
            f"*Run here in quick mode (`PHYSAR_EXAMPLE_QUICK=1`); `python examples/{script.name}` runs the full "
            "size.*"))
    out = nbformat.v4.new_notebook(cells=cells)
    out.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    out.metadata["language_info"] = {"name": "python"}
    for i, cell in enumerate(out.cells):  # stable ids: an unchanged example gives an unchanged file
        cell["id"] = f"cell-{i}"
    return out


def start(out_dir: str, video_dir: str, video_href: str) -> None:
    """Called by the hidden first cell: a fresh output folder, and where videos are copied and linked."""
    shutil.rmtree(out_dir, ignore_errors=True)
    Path(out_dir).mkdir(parents=True)
    _seen.clear()
    _ctx.update(out=Path(out_dir), videos=Path(video_dir), href=video_href)
    (Path(video_dir) / THUMB).unlink(missing_ok=True)


def _first_frame_png(path: Path) -> bytes:
    import av
    from PIL import Image

    with av.open(str(path)) as container:
        frame = next(container.decode(video=0))
    buf = io.BytesIO()
    Image.fromarray(frame.to_ndarray(format="rgb24")).save(buf, format="PNG")
    return buf.getvalue()


def show_new() -> None:
    """Display the PNG figures and MP4 videos that the last cell wrote into the example's output folder."""
    from IPython.display import HTML, Image, display

    out = _ctx["out"]
    for path in sorted(out.glob("*")):
        stamp = path.stat().st_mtime_ns
        if _seen.get(path) == stamp or path.suffix.lower() not in (".png", ".mp4"):
            continue
        _seen[path] = stamp
        videos = Path(_ctx["videos"])
        videos.mkdir(parents=True, exist_ok=True)
        if path.suffix.lower() == ".png":
            data = path.read_bytes()
            display(Image(data=data))
        else:
            shutil.copy2(path, videos / path.name)
            data = _first_frame_png(path)
            display(Image(data=data))
            href = html.escape(f"{_ctx['href']}/{path.name}")
            display(HTML(f'<p>First frame of <a href="{href}">{html.escape(path.name)}</a> (MP4).</p>'))
        if not (videos / THUMB).exists():  # the example's first picture: its thumbnail in the gallery index
            (videos / THUMB).write_bytes(data)


def index_page(titles: dict[str, tuple[str, str]]) -> str:
    """The gallery index: one row per example (its first picture, title, summary). The thumbnails are
    written when the examples run and copied with the videos (html_extra_path)."""
    lines = ["# Gallery", "",
             "Each example in `examples/` runs top to bottom with `python examples/NAME.py` and opens as a notebook "
             "through jupytext; `tests/examples/` checks its numbers against independent references. The pages "
             "below are those scripts executed when the documentation was built"
             + (" (quick mode, `PHYSAR_EXAMPLE_QUICK=1`)." if quick() else "."), "",
             "| | example | what it shows |", "|---|---|---|"]
    for name, (title, summary) in titles.items():
        thumb = f'<img src="../../{GALLERY}_files/{name}/{THUMB}" alt="" style="width: 200px; max-width: none">'
        lines.append(f"| {thumb} | [{title}]({name}.ipynb) | {summary.replace('|', chr(92) + '|')} |")
    lines += ["", "```{toctree}", ":hidden:", "", *titles, "```", ""]
    return "\n".join(lines)


def write_gallery(src: Path, examples: Path, build: Path) -> list[Path]:
    """Write the example notebooks and the index into ``src/_generated/gallery``."""
    gallery = src / "_generated" / GALLERY
    titles = {}
    pages = []
    for script in sorted(examples.glob("*.py")):
        nb = example_notebook(script, build / "gallery_out" / script.stem,
                              build / "gallery_extra" / f"{GALLERY}_files" / script.stem)
        pages.append(gallery / f"{script.stem}.ipynb")
        write_if_changed(pages[-1], json.dumps(nb, indent=1, sort_keys=True) + "\n")
        doc, _ = split_docstring(script.read_text())
        title, _, rest = doc.partition("\n")
        summary = " ".join(rest.strip().split("\n\n")[0].split())
        titles[script.stem] = (title.strip().rstrip("."), re.sub(r"``([^`]+)``", r"`\1`", summary))
    write_if_changed(gallery / "index.md", index_page(titles))
    return pages


def _generate(app) -> None:
    src = Path(app.srcdir)
    write_gallery(src, src.parent / "examples", Path(app.confdir) / "_build")  # html_extra_path is there


def setup(app):
    app.connect("builder-inited", _generate)
    return {"parallel_read_safe": True, "version": "1"}
