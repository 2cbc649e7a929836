"""Sphinx configuration of the documentation site (Sphinx + furo + MyST).

Build (``bash scripts/docs.sh`` does all of it, warnings as errors)::

    python docs/gen_env_pages.py --check        # the env pages are up to date
    sphinx-build -W --keep-going -b html docs docs/_build/html
    sphinx-build -W --keep-going -b linkcheck docs docs/_build/linkcheck
    python scripts/check_docs_pages.py          # links, anchors, images, JS errors in Chromium

The pages are the markdown files of ``docs/`` as they are on GitHub: ``index.md`` (the landing
page), every ``docs/[a-z]*.md`` (a glob in index.md's toctree: a new page is picked up; a page
named otherwise fails the build as "not included in any toctree"), ``docs/README.md`` and
``docs/figures/*.md``, the env pages ``docs/envs/`` (written by ``docs/gen_env_pages.py``) and
the API reference ``docs/api/`` (autodoc, from the docstrings).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

from docutils import nodes
from sphinx import addnodes
from sphinx.application import Sphinx
from sphinx.transforms import SphinxTransform

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
# autodoc imports the packages from this checkout (an editable install would too).
sys.path.insert(0, str(ROOT))
# Importing platoon_env with no compiled kernel cached prints a note; not in a docs build.
os.environ.setdefault("PLATOON_ENV_QUIET", "1")

project = "platoon_env"
author = "platoon_env contributors"
copyright = "platoon_env contributors"
release = version = "0.1.0"
try:  # the version of the package being documented, when it imports (it does in the build)
    from platoon_env import __version__ as release

    version = release
except ImportError:  # pragma: no cover - conf.py read without the package installed
    pass

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",  # the docstrings' Google-style "Args:" / "Returns:" sections
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "**/.ipynb_checkpoints"]
templates_path: list[str] = []

# --- MyST -------------------------------------------------------------------------------------
# No syntax extensions are needed: the pages are GitHub-flavoured markdown (tables, fenced code,
# raw HTML comments). Heading anchors make the pages' "page.md#a-heading" links resolve, with
# GitHub's slugs, at every heading level the pages link to.
myst_enable_extensions: list[str] = []
myst_heading_anchors = 6

# --- autodoc ----------------------------------------------------------------------------------
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
# Defaults as written in the source (``path=PUBLISHED``), not their values at import: a value
# such as a path inside the checkout would publish the building machine's absolute path.
autodoc_preserve_defaults = True
# A method without a docstring of its own is not given its base class's: those of Gymnasium's
# and PettingZoo's base classes are written for their own sites (their RST does not build here),
# and the page would describe the base, not this package.
autodoc_inherit_docstrings = False
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False

# --- HTML -------------------------------------------------------------------------------------
html_theme = "furo"
html_title = f"platoon_env {release}"
html_static_path = ["_static"]
# A favicon of the site's own: without one the browser asks for /favicon.ico, a 404 that
# scripts/check_docs_pages.py would report as a console error.
html_favicon = "_static/favicon.svg"
html_show_sourcelink = False
html_copy_source = False  # no _sources/ copies of the markdown in the site
# The API pages' "on this page" lists name members without their class (``reset``, not
# ``PlatoonParallelEnv.reset``).
toc_object_entries_show_parents = "hide"

# --- linkcheck --------------------------------------------------------------------------------
# CI may have no network: every external URL is skipped. The builder reports the references
# inside the site as "unchecked"; those are checked by the -W html build (MyST warns on a
# missing page, file or #anchor) and, in the built HTML, by scripts/check_docs_pages.py.
linkcheck_ignore = [r"https?://.*"]
linkcheck_anchors = True

# No warning category is suppressed: a page that does not build cleanly fails the build (-W).
suppress_warnings: list[str] = []


class RepositoryLinks(SphinxTransform):
    """Links from a page to a file of the repository outside ``docs/``.

    On GitHub the pages link to repository files (``../README.md``, ``../models/README.md``,
    ``../examples/x.py``); the site holds only ``docs/``. MyST turns such a link into a
    reference to a document it cannot find (a ``.md`` file) or to a target it cannot resolve,
    and warns. This transform, run on each page after parsing, gives them a sensible target:

    * the top-level ``README.md``: the site's landing page (it plays the README's part here);
    * any other file of the repository: a download link (Sphinx copies the file into the site,
      ``_downloads/``), so the link opens the file as on GitHub;
    * a folder (``figures/``, in ``docs/`` or not): its name as plain text, no link (a site has
      no folder listings).

    A link to a path that does not exist is left alone, so MyST's warning fails the build: it
    is a broken link.
    """

    default_priority = 500

    def apply(self, **kwargs: Any) -> None:
        for node in list(self.document.findall(addnodes.pending_xref)):
            if node.get("reftype") != "myst":
                continue
            target = self._outside_target(node)
            if target is None:
                continue
            if target == ROOT / "README.md":
                node["reftarget"] = self.config.root_doc
                node["refdomain"] = "doc"
                node["reftargetid"] = None
            elif target.is_file():
                here = (DOCS / self.env.docname).parent
                rel = os.path.relpath(target, here)
                download = addnodes.download_reference(
                    "",
                    "",
                    *node.children,
                    refdomain=None,
                    reftype="myst",
                    reftarget=rel,
                    refdoc=self.env.docname,
                    refexplicit=True,
                )
                download["classes"] = [*node.get("classes", []), "download"]
                node.replace_self(download)
            elif target.is_dir():
                node.replace_self(nodes.inline("", "", *node.children))

    def _outside_target(self, node: addnodes.pending_xref) -> Path | None:
        """The repository path outside ``docs/`` that ``node`` links to, or None."""
        target = str(node.get("reftarget") or "")
        if node.get("refdomain") == "doc" and os.path.isabs(target):
            # MyST resolved a markdown link outside the source folder to an absolute
            # "docname" (the path without its suffix).
            candidates = [Path(target + suffix) for suffix in self.config.source_suffix]
            path = next((p for p in candidates if p.is_file()), Path(target))
        elif not node.get("refdomain") and target and "://" not in target:
            here = (DOCS / self.env.docname).parent
            path = (here / target.split("#", 1)[0]).resolve()
        else:
            return None
        path = path.resolve()
        if not path.exists() or not path.is_relative_to(ROOT):
            return None
        if path.is_relative_to(DOCS) and not path.is_dir():
            return None  # a page or an image of the site: Sphinx and MyST handle it
        return path


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_transform(RepositoryLinks)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
