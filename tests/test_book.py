"""The book (`make book`): links between the README, docs/ and the notebooks become links
between their pages, other files they name are copied beside them, headings get GitHub's
anchors. The browser check of a built book is `scripts/check_book.py` (`make book-check`)."""
import json
import re

import pytest

from ncs_lite import book
from ncs_lite.book import book_url, github_slug, page_of, rewrite_links

PAGES = {"index.html", "docs/results.html", "docs/teaching.html", "docs/HISTORY.html",
         "notebooks/01_environments.html", "notebooks/04_dslate_training_robogym.html"}


def test_pages_keep_the_repository_layout():
    assert page_of("README.md") == "index.html"
    assert page_of("docs/teaching.md") == "docs/teaching.html"
    assert page_of("notebooks/01_environments.ipynb") == "notebooks/01_environments.html"
    assert page_of("figures/07_baselines/comparison.png") is None
    assert page_of("docs/sub/x.md") is None and page_of("ncs_lite/README.md") is None


@pytest.mark.parametrize("source, url, expected", [
    ("README.md", "docs/results.md", ("docs/results.html", None)),
    ("README.md", "docs/results.md#seeds_reducedjson", ("docs/results.html#seeds_reducedjson", None)),
    ("README.md", "notebooks/01_environments.ipynb", ("notebooks/01_environments.html", None)),
    ("docs/results.md", "HISTORY.md", ("HISTORY.html", None)),
    ("docs/teaching.md", "../README.md#quick-start", ("../index.html#quick-start", None)),
    ("docs/teaching.md", "../notebooks/01_environments.ipynb", ("../notebooks/01_environments.html", None)),
    ("notebooks/01_environments.ipynb", "../docs/teaching.md", ("../docs/teaching.html", None)),
    # files that are not pages keep their url and are copied beside the pages
    ("README.md", "figures/07_baselines/comparison.png",
     ("figures/07_baselines/comparison.png", "figures/07_baselines/comparison.png")),
    ("docs/results.md", "../figures/tables/clusters.json", ("../figures/tables/clusters.json", "figures/tables/clusters.json")),
    ("README.md", "docs/./recipe.md", ("docs/recipe.md", "docs/recipe.md")),       # no page in this book: a file
    # what is not the repository's stays as written
    ("README.md", "#results-at-a-glance", ("#results-at-a-glance", None)),
    ("README.md", "https://arxiv.org/abs/2303.11373", ("https://arxiv.org/abs/2303.11373", None)),
    ("README.md", "mailto:someone@example.com", ("mailto:someone@example.com", None)),
    ("README.md", "data:image/png;base64,AAAA", ("data:image/png;base64,AAAA", None)),
    ("docs/teaching.md", "../../elsewhere.md", ("../../elsewhere.md", None)),
    ("README.md", "/etc/passwd", ("/etc/passwd", None)),
])
def test_book_url(source, url, expected):
    assert book_url(url, source, PAGES) == expected


def test_rewrite_links_in_html():
    text = ('<p><a href="docs/results.md#notebook-times">times</a> <img src="figures/a&amp;b.png" alt="x">'
            '<a href="https://example.com/?a=1&amp;b=2">out</a> <a class="anchor-link" href="#Setup">¶</a></p>')
    out, copies = rewrite_links(text, "README.md", PAGES)
    assert 'href="docs/results.html#notebook-times"' in out
    assert 'src="figures/a&amp;b.png"' in out and copies == {"figures/a&b.png"}
    assert 'href="https://example.com/?a=1&amp;b=2"' in out and 'href="#Setup"' in out


@pytest.mark.parametrize("heading, slug", [
    ("Notebook times", "notebook-times"),
    ("`seeds_reduced.json`", "seeds_reducedjson"),
    ("`variants/slot_position_attention/seeds_reduced.json`", "variantsslot_position_attentionseeds_reducedjson"),
    ("Results at a glance", "results-at-a-glance"),
    ("How the kit differs from the paper", "how-the-kit-differs-from-the-paper"),
    ("2. Run, then (re)save: 95 % done", "2-run-then-resave-95--done"),
])
def test_headings_get_githubs_anchors(heading, slug):
    assert github_slug(heading) == slug


def test_markdown_headings_carry_their_anchor_once():
    out = book.markdown_html("# Results\n\n## `clusters.json`\n\n## Setup\n\n## Setup\n\n| a | b |\n|---|---|\n| 1 | 2 |\n")
    assert '<h2 id="clustersjson"><code>clusters.json</code></h2>' in out
    assert '<h2 id="setup">' in out and '<h2 id="setup-1">' in out
    assert "<table>" in out


def test_every_link_of_the_readme_and_docs_lands_in_the_book():
    """Every relative link the README and docs/ hold is a page of the book or a file that is
    copied into it (tests the real texts, without building)."""
    root = book.REPO_DIR
    sources = ["README.md"] + [f"docs/{p.name}" for p in sorted((root / "docs").glob("*.md"))]
    pages = {book.page_of(s) for s in sources}
    pages |= {f"notebooks/{p.stem}.html" for p in (root / "notebooks").glob("[0-9][0-9]_*.ipynb")}
    for source in sources:
        html = book.markdown_html((root / source).read_text(encoding="utf-8"))
        _, copies = rewrite_links(html, source, pages)
        missing = [c for c in copies if not (root / c).is_file()]
        assert not missing, f"{source} links to {missing}, which is not a file of the repository"


def test_each_envs_run_of_a_notebook_has_its_title():
    assert book.run_title("04_dslate_training") == "04_dslate_training"
    assert book.run_title("04_dslate_training_robogym") == "04_dslate_training (robogym)"
    assert book.run_title("07_baselines_stacking") == "07_baselines (stacking)"


def test_the_book_lists_each_envs_executed_copies(tmp_path):
    """`make reproduce`'s executed copies <name>_robogym and <name>_stacking each get a page and a
    line in the menu; a copy without a master notebook gets none."""
    executed = tmp_path / "executed"
    executed.mkdir()
    empty = json.dumps({"cells": [], "metadata": {}, "nbformat": 4, "nbformat_minor": 4})
    for stem in ("04_dslate_training", "04_dslate_training_robogym", "04_dslate_training_stacking", "99_gone_stacking"):
        (executed / f"{stem}.ipynb").write_text(empty)
    made = book.build(tmp_path / "book", executed)
    assert {"notebooks/04_dslate_training_robogym.html", "notebooks/04_dslate_training_stacking.html"} <= set(made)
    assert not any("99_gone" in page for page in made)
    index = (tmp_path / "book" / "index.html").read_text()
    assert "04_dslate_training (robogym)" in index and "04_dslate_training (stacking)" in index


def test_make_book_without_executed_notebooks_says_which_command_makes_them(tmp_path, capsys):
    assert book.main(["--notebooks", str(tmp_path / "none"), "--out", str(tmp_path / "book")]) == 2
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and "make reproduce" in out and "no executed notebooks" in out
    assert not (tmp_path / "book").exists()


def test_executed_note_names_the_parameters(tmp_path):
    nb = tmp_path / "01_environments.ipynb"
    nb.write_text(json.dumps({"metadata": {"papermill": {"parameters": {"preset": "ci"}}}, "cells": []}))
    assert "preset=ci" in book.executed_note(nb, "01_environments")
    assert "make reproduce" in book.executed_note(None, "01_environments")


def test_formulas_become_mathml_and_code_stays_as_written():
    from ncs_lite.book import latex_to_mathml

    out = latex_to_mathml("Loss $$L = x^2$$ and inline $\\tau$, not `$HOME` nor $ 5 and $6.")
    assert out.count("<math") == 2 and 'display="block"' in out
    assert "`$HOME`" in out and "$ 5 and $6." in out            # code and plain dollars untouched
    assert latex_to_mathml("```\n$$x$$\n```") == "```\n$$x$$\n```"


def test_notebook_formulas_reach_the_page_as_mathml():
    from ncs_lite.book import notebook_page
    from ncs_lite.utils import REPO_DIR

    page = notebook_page(REPO_DIR / "notebooks" / "07_baselines.ipynb", "07")
    blocks = re.findall(r"<math [^>]*>", page)
    assert len(blocks) == 3 and all('display="block"' in b for b in blocks)        # IQL's (1)-(3)
    assert "</msub>" in page                                                    # nested, not torn apart
    assert "$$L_V" not in page
