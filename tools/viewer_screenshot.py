"""A page written by ``rmpfusion-view`` opened in headless Chromium, screenshotted, and its JavaScript errors listed.

    python tools/viewer_screenshot.py viewer.html docs/figures/viewer_franka.png

Needs Debian's ``chromium`` and ``chromium-driver`` (``apt-get install chromium chromium-driver``) and selenium
(the dev extra). WebGL runs on SwiftShader, Chromium's software renderer, so no GPU is needed. The tests use the
same function (tests/test_viewer.py), so what they check is what this tool shows.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path

CHROMEDRIVER = "/usr/bin/chromedriver"


def browser_missing() -> str | None:
    """Why a browser test cannot run here (None when it can)."""
    if not Path(CHROMEDRIVER).is_file() or shutil.which("chromium") is None:
        return f"no chromium or {CHROMEDRIVER} (apt-get install chromium chromium-driver)"
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install -e '.[dev]')"
    return None


def screenshot(
    html: str | Path, png: str | Path, size: tuple[int, int] = (1200, 900), wait_s: float = 60.0, at_end: bool = False
) -> list[dict]:
    """Open ``html`` in headless Chromium, wait until plotly drew its WebGL scene (moved to the last frame of the
    time slider with ``at_end``), save a screenshot to ``png`` and return the browser log's entries of level
    SEVERE (JavaScript errors)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    for a in (
        "--headless=new",
        "--no-sandbox",
        "--disable-dev-shm-usage",
        "--enable-unsafe-swiftshader",
        "--use-angle=swiftshader",
        f"--window-size={size[0]},{size[1]}",
    ):
        opts.add_argument(a)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    try:
        driver.get(Path(html).resolve().as_uri())
        drawn = "return !!(window.Plotly && document.querySelector('.gl-container canvas'))"
        deadline = time.time() + wait_s
        while not driver.execute_script(drawn) and time.time() < deadline:
            time.sleep(0.5)
        if at_end:
            driver.execute_script(
                "const gd = document.querySelector('.plotly-graph-div'); const f = gd._transitionData._frames;"
                "Plotly.animate(gd, [f[f.length - 1].name], {frame: {duration: 0, redraw: true}, mode: 'immediate'});"
                "const s = gd.layout.sliders;"
                "if (s && s.length) Plotly.relayout(gd, {'sliders[0].active': f.length - 1});"
            )
        time.sleep(2.0)  # the first WebGL frame after the canvas appears
        driver.save_screenshot(str(png))
        return [e for e in driver.get_log("browser") if e.get("level") == "SEVERE"]
    finally:
        driver.quit()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("html", type=Path)
    ap.add_argument("png", type=Path)
    ap.add_argument("--size", type=int, nargs=2, default=(1200, 900), metavar=("WIDTH", "HEIGHT"))
    ap.add_argument("--at-end", action="store_true", help="show the time slider's last frame")
    a = ap.parse_args(argv)
    if (why := browser_missing()) is not None:
        print(f"error: {why}", file=sys.stderr)
        return 2
    errors = screenshot(a.html, a.png, tuple(a.size), at_end=a.at_end)
    for e in errors:
        print(f"javascript error: {e['message']}", file=sys.stderr)
    print(f"wrote {a.png}")
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
