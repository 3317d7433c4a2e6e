"""Screenshots of the built site with headless Chromium (Debian's ``chromium`` and ``chromium-driver``), and
what the browser saw on each page: math typeset by MathJax, figures loaded, nothing fetched from elsewhere.

    python docs/screenshot.py [HTML_DIR]

Writes one PNG per page of :data:`PAGES` into ``docs/_build/screenshots/`` (build artefacts, not in git) and
prints a line per page. The pages are opened from ``file://`` URLs, as a reader opens the built site, and
the browser is driven by selenium through the system ``chromedriver``. Exit status 1 when a page shows a
problem (:meth:`PageReport.problems`), 2 when there is no Chromium or chromedriver (``apt-get install
chromium chromium-driver``; ``make env`` installs them when run as root).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

# screenshot name -> (page of the built site, what it must show: "math" typeset, a "figure" loaded)
PAGES = {
    "landing": ("index.html", ()),
    "gallery_fem_cantilever": ("_generated/gallery/fem_cantilever.html", ("figure",)),
    "gallery_artificial_damping": ("_generated/gallery/artificial_damping.html", ("figure",)),
    "api_integrators": ("_generated/api/physar.integrators.html", ("math",)),
    "api_fem": ("_generated/api/physar.fem.html", ("math",)),
    "equations": ("equations.html", ("math",)),
}
WIDTH, MAX_HEIGHT = 1280, 4000  # px: a page is captured whole, down to MAX_HEIGHT

# Run in the page once MathJax has typeset it (or at once on a page without MathJax): its maths, figures and
# the resources it loaded. Sphinx and MyST put every formula in an element of class "math"; MathJax 3 puts
# an <mjx-container> inside it, and an <mjx-merror> where the TeX does not parse.
_INSPECT = """
const done = arguments[arguments.length - 1];
const ready = (window.MathJax && MathJax.startup && MathJax.startup.promise) || Promise.resolve();
ready.then(() => document.fonts.ready).then(() => {
  const maths = [...document.querySelectorAll('.math')];
  const imgs = [...document.querySelectorAll('article img')];
  done({
    mathjax: !!(window.MathJax && MathJax.startup),
    math: maths.length,
    typeset: maths.filter(m => m.querySelector('mjx-container')).length,
    errors: document.querySelectorAll('mjx-merror').length,
    raw_tex: maths.filter(m => !m.querySelector('mjx-container') && /\\\\[(\\[]/.test(m.textContent)).length,
    first_math_top: Math.min(...maths.filter(m => m.querySelector('mjx-container'))
                                    .map(m => m.getBoundingClientRect().top + scrollY)),
    images: imgs.length,
    images_loaded: imgs.filter(i => i.complete && i.naturalWidth > 0).length,
    first_image_top: Math.min(...imgs.filter(i => i.complete && i.naturalWidth > 0)
                                    .map(i => i.getBoundingClientRect().top + scrollY)),
    text_chars: (document.querySelector('article') || document.body).innerText.length,
    resources: performance.getEntriesByType('resource').map(r => r.name).concat(
      [...document.querySelectorAll('[src],link[href]')].map(e => e.src || e.href)),
    height: document.documentElement.scrollHeight,
  });
}).catch(err => done({error: String(err)}));
"""


@dataclass
class PageReport:
    """What the browser saw on one page of the site, and its screenshot."""

    name: str
    png: Path
    math: int = 0  #: formulas on the page (elements of class "math")
    typeset: int = 0  #: formulas MathJax rendered (an <mjx-container> inside)
    errors: int = 0  #: MathJax errors (TeX that does not parse)
    images: int = 0  #: <img> in the page's article
    images_loaded: int = 0  #: of them, loaded with a non-zero size
    external: list[str] = field(default_factory=list)  #: resources from outside the site (network)
    colours: int = 0  #: distinct colours of the screenshot (a blank page has one or two)
    text_chars: int = 0  #: characters of text in the page's article
    height: int = 0  #: px of the page in the screenshot
    first_math_top: float = float("inf")  #: px from the top of the page to the first typeset formula
    first_image_top: float = float("inf")  #: px from the top of the page to the first loaded image
    expects: tuple[str, ...] = ()

    def problems(self) -> list[str]:
        """What is wrong with the page, as short phrases (empty when the page is fine)."""
        out = []
        if self.colours < 16:
            out.append(f"blank screenshot ({self.colours} colours)")
        if self.text_chars < 200:
            out.append(f"almost no text ({self.text_chars} characters)")
        if self.typeset < self.math:
            out.append(f"{self.math - self.typeset} of {self.math} formulas not typeset")
        if self.errors:
            out.append(f"{self.errors} MathJax errors")
        if "math" in self.expects and not self.first_math_top < self.height:
            out.append("no typeset math in the screenshot")
        if self.images_loaded < self.images:
            out.append(f"{self.images - self.images_loaded} of {self.images} images not loaded")
        if "figure" in self.expects and not self.first_image_top < self.height:
            out.append("no figure in the screenshot")
        if self.external:
            out.append(f"fetched from outside the site: {self.external[:3]}")
        return out


def find_browser() -> tuple[str, str] | None:
    """(Chromium executable, chromedriver executable), or None where either is missing."""
    chromium = next((p for n in ("chromium", "chromium-browser", "google-chrome") if (p := shutil.which(n))), None)
    driver = shutil.which("chromedriver")
    return (chromium, driver) if chromium and driver else None


def open_browser(browser: tuple[str, str]):
    """A headless Chromium driven by selenium (the caller quits it)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = browser[0]
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--hide-scrollbars",
                "--allow-file-access-from-files", f"--window-size={WIDTH},1000", "--force-device-scale-factor=1"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(browser[1]), options=opts)
    driver.set_script_timeout(60)
    driver.set_page_load_timeout(60)
    return driver


def colours(png: Path) -> int:
    """Distinct colours of an image (capped at 4096)."""
    from PIL import Image

    with Image.open(png) as im:
        return len(im.convert("RGB").getcolors(maxcolors=4096) or []) or 4096


def capture(driver, page: Path, png: Path, name: str = "", expects: tuple[str, ...] = ()) -> PageReport:
    """Open ``page`` (a file of the built site), wait for MathJax and the fonts, screenshot the whole page
    (up to :data:`MAX_HEIGHT`) into ``png`` and report what the page showed."""
    png.parent.mkdir(parents=True, exist_ok=True)
    driver.set_window_size(WIDTH, 1000)
    driver.get(page.resolve().as_uri())
    seen = driver.execute_async_script(_INSPECT)
    if "error" in seen:
        raise RuntimeError(f"{page}: {seen['error']}")
    driver.set_window_size(WIDTH, min(seen["height"], MAX_HEIGHT))
    driver.set_window_size(WIDTH, 2 * min(seen["height"], MAX_HEIGHT) - driver.execute_script(
        "return window.innerHeight"))  # the viewport, not the window, is the page's height
    time.sleep(0.3)
    driver.save_screenshot(str(png))
    external = sorted({u for u in seen["resources"] if u and not u.startswith(("file:", "data:", "blob:", "about:"))})
    height = driver.execute_script("return window.innerHeight")
    return PageReport(name or page.stem, png, seen["math"], seen["typeset"], seen["errors"], seen["images"],
                      seen["images_loaded"], external, colours(png), seen["text_chars"], height,
                      _top(seen["first_math_top"]), _top(seen["first_image_top"]), expects)


def _top(value) -> float:
    """A top from the page (JavaScript's Infinity arrives as None)."""
    return float("inf") if value is None else float(value)


def take_all(html_dir: Path, out_dir: Path | None = None, pages: dict | None = None) -> dict[str, PageReport]:
    """Screenshots of every page of :data:`PAGES` (or ``pages``); RuntimeError where there is no browser."""
    browser = find_browser()
    if browser is None:
        raise RuntimeError("no Chromium or chromedriver: apt-get install chromium chromium-driver (Debian)")
    out_dir = out_dir or html_dir.parent / "screenshots"
    driver = open_browser(browser)
    try:
        return {name: capture(driver, html_dir / page, out_dir / f"{name}.png", name, expects)
                for name, (page, expects) in (pages or PAGES).items()}
    finally:
        driver.quit()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("html_dir", nargs="?", type=Path, default=Path(__file__).parent / "_build" / "html")
    args = parser.parse_args(argv)
    try:
        reports = take_all(args.html_dir)
    except RuntimeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    bad = 0
    for r in reports.values():
        problems = r.problems()
        bad += bool(problems)
        print(f"{r.png}: {r.typeset}/{r.math} formulas typeset, {r.images_loaded}/{r.images} images, "
              f"{r.colours} colours" + (f"  PROBLEM: {'; '.join(problems)}" if problems else ""))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
