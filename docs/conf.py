"""
Sphinx configuration of the sb3-trlsd docs.

Why Sphinx, reST and autodoc: Stable-Baselines3 and sb3-contrib write their docs this way (reST pages,
one page per algorithm, the parameters rendered by autodoc from the class docstring's ``:param:`` lines),
and this package's docstrings already follow SB3's reST convention. One source of truth for a parameter:
the docstring next to the code, never a copy in a page. Build with warnings as errors
(``sphinx-build -W --keep-going -b html docs docs/_build/html``); ``tests/test_docs_site.py`` does.
"""

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
# The library and the envs of this checkout, not of whatever copy is installed (the envs' package lives in
# the checkout's envs/ folder).
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "envs"))
sys.path.insert(0, str(DOCS / "_ext"))

from sb3_trlsd.version import __version__  # noqa: E402

project = "sb3-trlsd"
author = "sb3-trlsd developers"
copyright = "sb3-trlsd developers"
version = release = __version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "trlsd_docs",  # docs/_ext/trlsd_docs.py: tables read from the results' JSON files
]

# Single backticks are code, as in the package's docstrings and in Markdown.
default_role = "literal"
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"members": True, "show-inheritance": True}
# Not pages: the results, the figures' sources, the scripts beside the pages, the build.
exclude_patterns = ["_build", "results", "figures", "*.py", "**/*.py"]
suppress_warnings = ["config.cache"]
# The docstrings write a set's size as in the paper, |Xi_tau|, and a change's size as |theta_new - theta|:
# plain text, not reST substitutions. Each such name stands for itself.
PLAIN_BARS = ("Xi", "Xi_tau", "theta_new", "theta_new - theta", "y_new - y")
rst_epilog = "\n".join(f".. |{name}| replace:: \\|{name}\\|" for name in PLAIN_BARS)

try:
    import sphinx_rtd_theme  # noqa: F401

    html_theme = "sphinx_rtd_theme"
except ImportError:  # the default theme builds the same pages
    html_theme = "alabaster"
html_title = f"sb3-trlsd {release}"
