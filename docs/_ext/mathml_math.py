"""Equations rendered to MathML when the site is built, by latex2mathml, instead of by MathJax in the browser.

The browser draws MathML itself (MathML Core: Chromium 109+, Firefox, Safari), so a page needs no script for its
equations, fetches nothing when it is viewed (the site reads the same offline, from a file:// URL) and nothing is
downloaded when it is built. An equation that latex2mathml cannot convert is a build warning, which
``scripts/build_docs`` (``-W``) makes an error that names the page and the LaTeX.

``conf.py`` selects it with ``html_math_renderer = "mathml"``. As with Sphinx's MathJax renderer, a display block
holds one equation per paragraph, a multi-line one (``\\``) is aligned at ``&``, and a numbered one keeps its
``(n)`` and permalink.
"""

from __future__ import annotations

from typing import Any

from docutils import nodes
from latex2mathml.converter import convert
from sphinx.application import Sphinx
from sphinx.locale import _
from sphinx.util import logging
from sphinx.util.math import get_node_equation_number

logger = logging.getLogger(__name__)


def _mathml(latex: str, display: str, node: nodes.Node) -> str:
    try:
        return convert(latex, display=display)
    except Exception as err:  # latex2mathml raises its own exceptions and plain ones for malformed input
        logger.warning("cannot render this equation as MathML (%s: %s); write it in the LaTeX subset latex2mathml "
                       "converts: %s", type(err).__name__, err, latex, location=node)
        return f"<code>{latex}</code>"


def visit_math(self: Any, node: nodes.math) -> None:
    self.body.append(self.starttag(node, "span", "", CLASS="math notranslate nohighlight"))
    self.body.append(_mathml(node.astext(), "inline", node) + "</span>")
    raise nodes.SkipNode


def visit_displaymath(self: Any, node: nodes.math_block) -> None:
    self.body.append(self.starttag(node, "div", CLASS="math notranslate nohighlight"))
    if node["number"]:
        self.body.append(f'<span class="eqno">({get_node_equation_number(self, node)})')
        self.add_permalink_ref(node, _("Link to this equation"))
        self.body.append("</span>")
    for part in (part for part in node.astext().split("\n\n") if part.strip()):
        if r"\\" in part:  # several lines, aligned at & as Sphinx's MathJax renderer aligns them
            part = rf"\begin{{split}}{part}\end{{split}}"
        self.body.append(_mathml(part, "block", node))
    self.body.append("</div>\n")
    raise nodes.SkipNode


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_html_math_renderer("mathml", (visit_math, None), (visit_displaymath, None))
    return {"parallel_read_safe": True, "parallel_write_safe": True}
