"""Screenshots of the built site with headless Chromium (Debian's ``chromium`` package).

    python docs/screenshot.py [HTML_DIR] [--install]

Writes ``screenshots/landing.png`` (the README tour), ``screenshots/gallery_fem_cantilever.png`` (an example
with its figure) and ``screenshots/equations.png`` (rendered math) under HTML_DIR's parent
(``docs/_build/screenshots`` by default; build artefacts, not in git). ``--install`` runs
``apt-get install -y chromium`` when no Chromium is found (needs root). Pages are loaded from ``file://``
URLs; MathJax is served from the site itself, so nothing is fetched from the network.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from pathlib import Path

PAGES = {  # screenshot name -> (page of the built site, window height in px: the gallery page down to its figure)
    "landing": ("index.html", 1600),
    "gallery_fem_cantilever": ("_generated/gallery/fem_cantilever.html", 2600),
    "equations": ("equations.html", 1600),
}


def find_chromium() -> str | None:
    """Path of a Chromium executable, or None."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def install_chromium() -> str | None:
    """``apt-get install -y chromium`` as root; the executable, or None where that is not possible."""
    if os.geteuid() != 0 or not shutil.which("apt-get"):
        return None
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    subprocess.run(["apt-get", "update", "-qq"], check=False, env=env, capture_output=True)
    subprocess.run(["apt-get", "install", "-y", "-qq", "chromium"], check=False, env=env, capture_output=True)
    return find_chromium()


def screenshot(chromium: str, page: Path, png: Path, size=(1280, 1600), budget_ms: int = 8000) -> Path:
    """One page to a PNG; ``budget_ms`` of virtual time lets MathJax typeset before the capture."""
    png.parent.mkdir(parents=True, exist_ok=True)
    cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
           "--allow-file-access-from-files", f"--window-size={size[0]},{size[1]}",
           f"--virtual-time-budget={budget_ms}", f"--screenshot={png}", page.resolve().as_uri()]
    result = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=120)
    if not png.exists() or png.stat().st_size == 0:
        raise RuntimeError(f"chromium wrote no screenshot of {page}: {result.stderr.strip()[-500:]}")
    return png


def take_all(html_dir: Path, out_dir: Path | None = None, install: bool = False) -> dict[str, Path]:
    """Screenshots of every page of ``PAGES``; raises RuntimeError where there is no Chromium."""
    chromium = find_chromium() or (install_chromium() if install else None)
    if chromium is None:
        raise RuntimeError("no Chromium: install Debian's package with 'apt-get install -y chromium' (root), "
                           "or run with --install")
    out_dir = out_dir or html_dir.parent / "screenshots"
    return {name: screenshot(chromium, html_dir / page, out_dir / f"{name}.png", size=(1280, height))
            for name, (page, height) in PAGES.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("html_dir", nargs="?", type=Path, default=Path(__file__).parent / "_build" / "html")
    parser.add_argument("--install", action="store_true", help="apt-get install chromium if missing (root)")
    args = parser.parse_args(argv)
    try:
        shots = take_all(args.html_dir, install=args.install)
    except RuntimeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for path in shots.values():
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
