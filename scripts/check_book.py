"""Open every page of the book (`make book`, build/book/) in headless Chromium, as a reader would.

    .venv/bin/python scripts/check_book.py [build/book]        (make book-check)

The site is served on 127.0.0.1 and each page must load with every image drawn
(`naturalWidth > 0`), no console error, and every internal link landing: its file is in
the site and its #anchor is an element of that page. Prints one line a page, then a
verdict; exits 1 on any problem, 2 when selenium or Chromium is missing (`scripts/browser.py`).
"""
from __future__ import annotations

import functools
import http.server
import sys
import threading
import time
from pathlib import Path
from urllib.parse import unquote, urldefrag, urlsplit

sys.path.insert(0, str(Path(__file__).resolve().parent))
from browser import chrome, console_errors, free_port  # noqa: E402

REPO = Path(__file__).resolve().parents[1]

PAGE_FACTS = """
const imgs = [...document.images].map(i => [i.getAttribute('src').slice(0, 80), i.complete, i.naturalWidth]);
const links = [...document.querySelectorAll('a[href]')].map(a => a.href);
const ids = [...document.querySelectorAll('[id]')].map(e => e.id)
  .concat([...document.querySelectorAll('a[name]')].map(a => a.name));
return {imgs, links, ids, title: document.title, ready: document.readyState};
"""


class Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def serve(folder: Path):
    port = free_port()
    server = http.server.ThreadingHTTPServer(("127.0.0.1", port), functools.partial(Quiet, directory=str(folder)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, f"http://127.0.0.1:{port}/"


def page_facts(driver, url: str) -> dict:
    driver.get(url)
    deadline = time.time() + 20
    while True:                          # images decode after `load` on a slow machine
        facts = driver.execute_script(PAGE_FACTS)
        if facts["ready"] == "complete" and all(done for _, done, _ in facts["imgs"]) or time.time() > deadline:
            return facts
        time.sleep(0.2)


def ids_of(facts: dict, page: str) -> set[str]:
    """The ids of a loaded page. A browser looks a #fragment up as written, then decoded
    (nbconvert writes its headings' ids percent-encoded: "00-%C2%B7-..."), so both count."""
    return set(facts.get(page, {}).get("ids", []))


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    folder = Path(argv[0] if argv else REPO / "build" / "book").resolve()
    if not (folder / "index.html").is_file():
        print(f"check_book: no book at {folder} (no index.html); `make book` builds it")
        return 2
    pages = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*.html"))
    server, base = serve(folder)
    driver = chrome()
    problems, facts, n_imgs, n_links = [], {}, 0, 0
    try:
        for page in pages:
            f = facts[page] = page_facts(driver, base + page)
            bad_imgs = [src for src, done, width in f["imgs"] if not (done and width > 0)]
            errors = console_errors(driver)
            n_imgs += len(f["imgs"])
            problems += [f"{page}: image not drawn: {src}" for src in bad_imgs]
            problems += [f"{page}: console error: {e}" for e in errors]
            print(f"{page}: {len(f['imgs'])} images ({len(bad_imgs)} not drawn), {len(f['links'])} links, "
                  f"{len(errors)} console errors")
    finally:
        driver.quit()
        server.shutdown()
    for page, f in facts.items():
        for link in f["links"]:
            if not link.startswith(base):
                continue                                  # another site: not the book's to check
            n_links += 1
            target, fragment = urldefrag(link)
            path = unquote(urlsplit(target).path)[1:] or "index.html"
            if path.endswith("/"):
                path += "index.html"
            if not (folder / path).is_file():
                problems.append(f"{page}: broken link {link[len(base):]} (no {path} in the book)")
            elif fragment and path.endswith(".html") and not {fragment, unquote(fragment)} & ids_of(facts, path):
                problems.append(f"{page}: broken link {link[len(base):]} (no #{unquote(fragment)} in {path})")
    for p in problems:
        print("PROBLEM", p)
    verdict = (f"book-check: {len(pages)} pages, {n_imgs} images, {n_links} internal links: "
               + ("every page loads, every image is drawn, no broken link, no console error"
                  if not problems else f"{len(problems)} problems"))
    print(verdict)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
