"""mkdocs hook: drop the Sphinx role prefix (``:func:``, ``:mod:`` ...) the docstrings use.

The docstrings write :func:`name`; Markdown renders that as ``:func:`` followed by
the code ``name``. This keeps the code and removes the prefix from the HTML.
"""

import re

_ROLE = re.compile(r":(?:py:)?(?:func|mod|class|meth|attr|data|obj|exc|const|ref):(?=<code)")


def on_page_content(html, **kwargs):
    return _ROLE.sub("", html)
