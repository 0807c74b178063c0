"""Take the README's TensorBoard screenshot (``docs/tensorboard.png``) of a running TensorBoard.

Needs Playwright (``pip install playwright``) and a Chromium (Debian: ``apt-get install chromium``)::

    sb3-trlsd train --algo trlsd --env TRLSD/SharedDynamicsMaze-v0 -conf zoo_configs/continuous.yml \\
        -f logs/ --tensorboard-log runs/ --seed 0 --log-interval 1
    tensorboard --logdir runs/ --port 6006 &
    python docs/tensorboard_screenshot.py --url http://127.0.0.1:6006 --out docs/tensorboard.png
"""

from __future__ import annotations

import argparse

from playwright.sync_api import sync_playwright

TAG_FILTER = "pictures|train/|reward/ci"  # the picture of the task and the algorithm's own scalars


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--url", default="http://127.0.0.1:6006", help="TensorBoard's address")
    parser.add_argument("--out", default="docs/tensorboard.png", help="PNG to write")
    parser.add_argument("--chromium", default="/usr/bin/chromium", help="Chromium executable")
    args = parser.parse_args()
    with sync_playwright() as playwright:
        # Without WebGL, TensorBoard draws its charts in SVG, which headless Chromium renders.
        browser = playwright.chromium.launch(
            executable_path=args.chromium, args=["--no-sandbox", "--disable-webgl", "--disable-3d-apis"]
        )
        page = browser.new_page(viewport={"width": 1500, "height": 1040})
        page.goto(f"{args.url}/#timeseries")
        page.wait_for_timeout(6000)
        for close in page.get_by_role("button", name="Close").all():  # the settings side panel
            close.click(timeout=1000)
        page.get_by_role("combobox", name="Filter tags (regex)").fill(TAG_FILTER)
        page.keyboard.press("Escape")
        page.wait_for_timeout(3000)
        page.screenshot(path=args.out)
        browser.close()
    print(f"screenshot written to {args.out}")


if __name__ == "__main__":
    main()
