"""Takes the README's screenshot: an untrained network learning on the planar arm, as a projector shows it.

    .venv/bin/python docs/images/screenshot.py [docs/images/lab.png] [--robot planar]

Needs Debian's chromium (`make browser`) and the dev extra (playwright).
"""

import argparse
import tempfile
import time

from playwright import sync_api

from app.__main__ import WATCHING_SPEED
from app.server import LabApp


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default="docs/images/lab.png")
    parser.add_argument("--robot", default="planar")
    parser.add_argument("--width", type=int, default=1366)
    parser.add_argument("--height", type=int, default=768)
    args = parser.parse_args()
    tmp = tempfile.mkdtemp()
    app = LabApp(port=0, robot=args.robot, notebook=f"{tmp}/notebook.db", recordings=f"{tmp}/rec", record=False,
                 speed=WATCHING_SPEED)
    try:
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path="/usr/bin/chromium", headless=True)
            page = browser.new_page(viewport={"width": args.width, "height": args.height})
            page.goto(app.url)
            sync_api.expect(page.get_by_role("tab", name="Train")).to_be_visible(timeout=60_000)
            time.sleep(6)  # the scene and the meshes
            page.mouse.click(288, 100)  # closes chromium's "software WebGL" notice, top left
            page.get_by_role("button", name="Reset").click()  # an untrained network, off the goal
            time.sleep(2)
            page.get_by_role("button", name="Start").click()  # ... learning, at the app's watching speed
            time.sleep(7)
            page.screenshot(path=args.out)
            browser.close()
    finally:
        app.stop()


if __name__ == "__main__":
    main()
