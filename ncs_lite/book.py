"""The book: one static HTML site of the README, docs/ and the executed notebooks (`make book`).

    python -m ncs_lite.book [--notebooks build/notebooks] [--out build/book]

Pages keep the repository's layout, so a relative link between two files stays a relative
link between their pages: README.md -> index.html, docs/X.md -> docs/X.html,
notebooks/NN_x.ipynb -> notebooks/NN_x.html. A notebook's page is the executed copy that
`make reproduce` wrote to build/notebooks/ (papermill), its figures inline and its formulas
as MathML (`latex_to_mathml`, which browsers draw without a script); a notebook not
executed yet gets a page without outputs that says so. Links to .md and .ipynb files become
links to their pages; other files the text names (figures/*.png) are copied beside the pages;
headings get GitHub's anchors, so `results.md#seeds_reducedjson` lands on its heading. Built
without network, and the pages load nothing from one (no MathJax or require.js from a CDN):
`scripts/check_book.py` (`make book-check`) opens every page in headless Chromium.
"""
from __future__ import annotations

import argparse
import html
import json
import posixpath
import re
import shutil
import sys
from collections import Counter
from pathlib import Path

import jinja2
import mistune
from latex2mathml.converter import convert

from .utils import NOTEBOOK_ENV_SUFFIX, REPO_DIR, relative_to_repo, split_notebook_run

DOCS = "docs"
EXECUTED = REPO_DIR / "build" / "notebooks"      # where `make reproduce` writes the executed copies
OUT = REPO_DIR / "build" / "book"
MAKES_THEM = "`make reproduce` (or papermill: `.venv/bin/python -m papermill --cwd notebooks -p preset ci " \
             "notebooks/NN_x.ipynb build/notebooks/NN_x.ipynb`)"

CSS = """body{font:16px/1.5 system-ui,sans-serif;margin:0;color:#1b1b1b}
main{max-width:60rem;margin:0 auto;padding:1rem 1.5rem 4rem}
nav.book{background:#f3f4f6;border-bottom:1px solid #d0d4d9;padding:.5rem 1.5rem;font:14px/1.6 system-ui,sans-serif}
nav.book a{margin-right:.9rem;white-space:nowrap;color:#0b57d0;text-decoration:underline}
nav.book p{margin:.2rem 0}
table{border-collapse:collapse;margin:1rem 0;font-size:14px}
th,td{border:1px solid #d0d4d9;padding:.25rem .5rem;vertical-align:top}
code{background:#f3f4f6;padding:0 .2rem;border-radius:3px}
pre{background:#f6f8fa;padding:.75rem;overflow:auto}
pre code{background:none;padding:0}
img{max-width:100%}"""

# the lab template without what it would fetch from a CDN (require.js, MathJax, widgets,
# mermaid), with no favicon request, and the book's navigation at the top of the body
NOTEBOOK_TEMPLATE = """{%- extends 'index.html.j2' -%}
{%- block html_head_js -%}<link rel="icon" href="data:,">{%- endblock html_head_js -%}
{% block jupyter_widgets %}{% endblock jupyter_widgets %}
{%- block html_head_js_mathjax -%}{%- endblock html_head_js_mathjax -%}
{%- block html_head_js_mermaidjs -%}{%- endblock html_head_js_mermaidjs -%}
{%- block html_head_css -%}<style>{{ resources.book_css }}</style>{%- endblock html_head_css -%}
{% block body_header %}{{ super() }}{{ resources.book_nav }}{% endblock body_header %}
"""


# ---------------------------------------------------------------------------- formulas
# $$...$$ (display) and $...$ (inline, no space inside the dollars, as Jupyter reads them), outside code
_CODE = re.compile(r"(```.*?```|`[^`\n]*`)", re.S)
_DISPLAY = re.compile(r"\$\$(.+?)\$\$", re.S)
_INLINE = re.compile(r"(?<![\\$\w])\$(?=\S)([^$\n]+?)(?<=\S)\$(?![\w$])")


def latex_to_mathml(markdown: str) -> str:
    """`markdown` with its LaTeX formulas replaced by MathML (latex2mathml), code left alone:
    the book loads nothing from a CDN, so MathJax cannot typeset them in the browser."""
    def formulas(text: str) -> str:
        text = _DISPLAY.sub(lambda m: convert(m.group(1).strip(), display="block"), text)
        return _INLINE.sub(lambda m: convert(m.group(1)), text)

    parts = _CODE.split(markdown)       # odd parts are code spans and fences
    return "".join(part if i % 2 else formulas(part) for i, part in enumerate(parts))


# ---------------------------------------------------------------------------- links
def github_slug(text: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped (letters, digits,
    `_`, `-` and spaces kept), spaces as `-`. "`seeds_reduced.json`" -> "seeds_reducedjson"."""
    return re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")


def page_of(path: str) -> str | None:
    """The page (site path) of a repository file, None for a file that is not a page."""
    if path == "README.md":
        return "index.html"
    if path.startswith(f"{DOCS}/") and path.endswith(".md") and path.count("/") == 1:
        return path[:-3] + ".html"
    if path.startswith("notebooks/") and path.endswith(".ipynb") and path.count("/") == 1:
        return path[:-6] + ".html"
    return None


_EXTERNAL = re.compile(r"^([a-zA-Z][a-zA-Z0-9+.-]*:|//)")    # http:, mailto:, data:, //host


def book_url(url: str, source: str, pages: set[str]) -> tuple[str, str | None]:
    """(url in the site, repository file to copy beside the pages or None) for `url` as
    written in the repository file `source` (posix, from the repo root: "docs/teaching.md").

    External urls and in-page anchors stay as they are. A file with a page in `pages` (site
    paths) becomes a link to that page, its #anchor kept; any other file of the repository
    keeps its relative url and is named for copying. A url that leaves the repository stays."""
    if not url or url.startswith("#") or _EXTERNAL.match(url):
        return url, None
    path, sep, fragment = url.partition("#")
    here = page_of(source) or source
    target = posixpath.normpath(posixpath.join(posixpath.dirname(source), path))
    if target == ".." or target.startswith("../") or target.startswith("/"):
        return url, None
    page = page_of(target)
    if page is not None and page in pages:
        rel = posixpath.relpath(page, posixpath.dirname(here) or ".")
        return rel + sep + fragment, None
    rel = posixpath.relpath(target, posixpath.dirname(here) or ".")
    return rel + sep + fragment, target


_ATTR = re.compile(r'(\s(?:href|src)=")([^"]*)(")')


def rewrite_links(text: str, source: str, pages: set[str]) -> tuple[str, set[str]]:
    """`text` (HTML made from the repository file `source`) with every href and src through
    `book_url`; and the repository files the links name that must be copied beside it."""
    copies = set()

    def one(m):
        url, copy = book_url(html.unescape(m.group(2)), source, pages)
        if copy:
            copies.add(copy)
        return m.group(1) + html.escape(url, quote=True) + m.group(3)
    return _ATTR.sub(one, text), copies


# ---------------------------------------------------------------------------- pages
def nav(page: str, pages: list[tuple[str, str]], note: str = "") -> str:
    """The bar at the top of every page: links to every page (relative to `page`)."""
    here = posixpath.dirname(page) or "."
    links = " ".join(f'<a href="{html.escape(posixpath.relpath(p, here))}">{html.escape(title)}</a>'
                     for p, title in pages)
    return f'<nav class="book"><p>{links}</p>{f"<p>{note}</p>" if note else ""}</nav>'


def markdown_html(text: str) -> str:
    """Markdown -> HTML (mistune, the renderer nbconvert uses), headings with GitHub's anchors."""
    seen: Counter = Counter()

    class Renderer(mistune.HTMLRenderer):
        def heading(self, text, level, **attrs):
            slug = github_slug(html.unescape(re.sub(r"<[^>]+>", "", text)))
            n, seen[slug] = seen[slug], seen[slug] + 1
            anchor = slug if n == 0 else f"{slug}-{n}"
            return f'<h{level} id="{anchor}">{text}</h{level}>\n'

    render = mistune.create_markdown(renderer=Renderer(escape=False), plugins=["table", "strikethrough"])
    return render(latex_to_mathml(text))


NAV = "<!--book-nav-->"    # where a page's navigation goes once its links are rewritten


def markdown_page(text: str, title: str) -> str:
    return (f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">\n'
            f'<link rel="icon" href="data:,">\n<title>{html.escape(title)} · ncs-lite</title>\n'
            f"<style>{CSS}</style>\n</head>\n<body>\n{NAV}\n<main>\n{markdown_html(text)}</main>\n"
            f"</body>\n</html>\n")


def notebook_page(nb_path: Path, title: str) -> str:
    """The nbconvert (lab template) HTML of a notebook, its output images inline, formulas as
    MathML, nothing from a CDN."""
    # local: nbconvert and nbformat take about 2 s to import; only notebook pages need them
    import nbformat
    from nbconvert import HTMLExporter

    exporter = HTMLExporter(template_name="lab", extra_loaders=[jinja2.DictLoader({"book.html.j2": NOTEBOOK_TEMPLATE})],
                            template_file="book.html.j2")
    # outputs' images are inline data already; embed_images (for markdown <img>, which the
    # notebooks do not use) would re-parse each inline tag alone and break MathML apart
    nb = nbformat.read(nb_path, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "markdown":
            cell.source = latex_to_mathml(cell.source)
    body, _ = exporter.from_notebook_node(nb, resources={"metadata": {"name": title, "path": str(nb_path.parent)},
                                                         "book_nav": NAV, "book_css": CSS})
    return body


def title_of(text: str, fallback: str) -> str:
    m = re.search(r"^#\s+(.+)$", text, re.M)
    return re.sub(r"[`*]", "", m.group(1)).strip() if m else fallback


def executed_note(nb_path: Path | None, name: str) -> str:
    if nb_path is None:
        return (f"Not executed in this build: no outputs. {MAKES_THEM} writes "
                f"<code>build/notebooks/{html.escape(name)}.ipynb</code>.")
    meta = json.loads(nb_path.read_text(encoding="utf-8")).get("metadata", {}).get("papermill", {})
    params = meta.get("parameters") or {}
    shown = ", ".join(f"{k}={v}" for k, v in params.items()) or "the notebook's own parameters"
    return f"Executed by papermill ({html.escape(shown)}): the outputs below are that run's."


def run_title(stem: str) -> str:
    """A notebook's name in the book's menu: "04_dslate_training", or for its run on another env
    "04_dslate_training (robogym)", "04_dslate_training (stacking)"."""
    name, env = split_notebook_run(stem)
    return stem if env == "block-rearrange" else f"{name} ({NOTEBOOK_ENV_SUFFIX[env].lstrip('_')})"


def build(out: Path = OUT, executed: Path = EXECUTED) -> dict[str, str]:
    """Write the site into `out`; return {page: what it was made from}. FileNotFoundError
    (one line naming the command that makes them) when `executed` holds no executed notebook."""
    masters = sorted((REPO_DIR / "notebooks").glob("[0-9][0-9]_*.ipynb"))
    have = {p.stem: p for p in sorted(Path(executed).glob("[0-9][0-9]_*.ipynb"))}
    if not any(m.stem in have for m in masters):
        raise FileNotFoundError(f"no executed notebooks in {relative_to_repo(executed)}/: {MAKES_THEM} writes them")
    notebooks = [(f"notebooks/{m.stem}.html", m.stem, have.get(m.stem)) for m in masters]
    # the runs of notebooks 04-07 on the other envs: <name>_robogym, <name>_stacking (`utils.notebook_run`)
    runs = {stem: split_notebook_run(stem) for stem in have}
    notebooks += [(f"notebooks/{stem}.html", stem, p) for stem, p in have.items()
                  if runs[stem][1] != "block-rearrange" and runs[stem][0] in {m.stem for m in masters}]
    docs = sorted((REPO_DIR / DOCS).glob("*.md"))
    texts = {"README.md": (REPO_DIR / "README.md").read_text(encoding="utf-8")}
    texts.update({f"{DOCS}/{d.name}": d.read_text(encoding="utf-8") for d in docs})
    listed = [("index.html", "ncs-lite")] + [(page_of(s), title_of(t, s)) for s, t in texts.items() if s != "README.md"]
    listed += [(page, run_title(stem)) for page, stem, _ in notebooks]
    pages = {p for p, _ in listed}

    if out == REPO_DIR or out in REPO_DIR.parents or (out.is_dir() and any(out.iterdir())
                                                      and not (out / "index.html").is_file()):
        raise ValueError(f"--out {out} is not a book's folder (it holds other files); pass a new or empty folder")
    if out.exists():
        shutil.rmtree(out)                     # the previous book: a page dropped since goes too
    made, copies = {}, set()
    for source, text in texts.items():
        page = page_of(source)
        body, found = rewrite_links(markdown_page(text, title_of(text, source)), source, pages)
        _write(out / page, body.replace(NAV, nav(page, listed), 1))
        made[page], copies = source, copies | found
    for page, stem, nb_path in notebooks:
        source = f"notebooks/{stem}.ipynb"
        body, found = rewrite_links(notebook_page(nb_path or REPO_DIR / source, stem.replace("_", " ")), source, pages)
        _write(out / page, body.replace(NAV, nav(page, listed, executed_note(nb_path, stem)), 1))
        made[page], copies = relative_to_repo(nb_path or REPO_DIR / source), copies | found
    for path in sorted(copies):
        src = REPO_DIR / path
        if src.is_file():
            (out / path).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, out / path)
        else:
            print(f"book: {path} is linked but is not a file of the repository; the link stays broken")
    return made


def _write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ncs_lite.book", description=__doc__.split("\n")[0])
    parser.add_argument("--notebooks", type=Path, default=EXECUTED,
                        help="the executed notebooks (default: build/notebooks/, written by `make reproduce`)")
    parser.add_argument("--out", type=Path, default=OUT, help="the site's folder (default: build/book/)")
    args = parser.parse_args(argv)
    try:
        made = build(args.out.resolve(), args.notebooks.resolve())
    except (FileNotFoundError, ValueError) as e:
        print(f"make book: {e}")
        return 2
    missing = [p for p, src in made.items() if p.startswith("notebooks/") and src.startswith("notebooks/")]
    executed = sum(p.startswith("notebooks/") for p in made) - len(missing)
    print(f"book: {len(made)} pages in {relative_to_repo(args.out)}/ ({executed} executed notebooks"
          + (f"; not executed yet, shown without outputs: {', '.join(Path(p).stem for p in missing)}" if missing else "")
          + f"); open {relative_to_repo(args.out)}/index.html")
    return 0


if __name__ == "__main__":
    sys.exit(main())
