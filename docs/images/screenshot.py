"""Takes the README's screenshot: the lab on a UR5, ten seconds into a run, in headless chromium.

    .venv/bin/python docs/images/screenshot.py [docs/images/lab.png] [--robot ur5]

Needs Debian's chromium (`make browser`) and the dev extra (playwright).
"""

import argparse
import tempfile
import time

from playwright import sync_api

from app.server import LabApp


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default="docs/images/lab.png")
    parser.add_argument("--robot", default="ur5")
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--height", type=int, default=620)
    args = parser.parse_args()
    tmp = tempfile.mkdtemp()
    app = LabApp(port=0, robot=args.robot, notebook=f"{tmp}/notebook.db", recordings=f"{tmp}/rec", record=False)
    try:
        with sync_api.sync_playwright() as p:
            browser = p.chromium.launch(executable_path="/usr/bin/chromium", headless=True)
            page = browser.new_page(viewport={"width": args.width, "height": args.height})
            page.goto(app.url)
            sync_api.expect(page.get_by_role("tab", name="Train")).to_be_visible(timeout=60_000)
            time.sleep(6)  # the scene and the meshes
            page.mouse.click(288, 100)  # closes chromium's "software WebGL" notice, top left
            page.get_by_role("button", name="Start").click()
            time.sleep(10)
            page.screenshot(path=args.out)
            browser.close()
    finally:
        app.stop()


if __name__ == "__main__":
    main()
