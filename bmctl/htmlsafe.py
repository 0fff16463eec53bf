"""HTML built so that no input can inject markup: every value is escaped when it is rendered.

The one way bmctl writes HTML (the campaign report, any other page): a page is a trusted
template (a literal in the code) whose ``{placeholders}`` are filled by :func:`render`, which
escapes every value (``&``, ``<``, ``>``, ``"``, ``'``) after formatting it -- text from a
database, a file name, a number, an exception message alike. Only :class:`Markup`, which
this module's builders return, is inserted as it is, so markup can only come from the code's
own templates. Attribute values are quoted in the templates and escaped by :func:`render`,
so a value cannot leave its attribute (``onerror=`` stays text).

Examples
--------
>>> render("<p>{who} milled at {rpm:g} rpm</p>", who='<script>alert(1)</script>', rpm=300.0)
Markup('<p>&lt;script&gt;alert(1)&lt;/script&gt; milled at 300 rpm</p>')
>>> render('<img alt="{alt}">', alt='x" onerror="alert(1)')
Markup('<img alt="x&quot; onerror=&quot;alert(1)">')
>>> table(["id", "note"], [[1, "<b>bold</b>"]])
Markup('<table><thead><tr><th>id</th><th>note</th></tr></thead><tbody><tr><td>1</td><td>&lt;b&gt;bold&lt;/b&gt;</td></tr></tbody></table>')
"""

from __future__ import annotations

import base64
import html as _html
import string
from typing import Iterable, Sequence

__all__ = ["Markup", "escape", "render", "join", "table", "png_figure"]


class Markup(str):
    """HTML that this module built from a trusted template; inserted by :func:`render` as it is."""

    def __repr__(self) -> str:
        return f"Markup({str.__repr__(self)})"


def escape(value) -> Markup:
    """``value`` as HTML text: :class:`Markup` as it is, anything else ``str()``-ed and escaped.

    Parameters
    ----------
    value : object
        Text, a number or any object (its ``str``).

    Examples
    --------
    >>> escape("a < b & 'c'")
    Markup('a &lt; b &amp; &#x27;c&#x27;')
    """
    if isinstance(value, Markup):
        return value
    return Markup(_html.escape(str(value), quote=True))


class _Escaping(string.Formatter):
    def format_field(self, value, format_spec):
        if isinstance(value, Markup) and not format_spec:
            return value
        return escape(format(value, format_spec))

    def convert_field(self, value, conversion):
        out = super().convert_field(value, conversion)
        return out if conversion is None else str(out)  # !r / !s: the text of the value, escaped


_FORMATTER = _Escaping()


def render(template: str, /, **values) -> Markup:
    """Fill a trusted ``template`` (``str.format`` syntax) with ``values``, each escaped.

    Parameters
    ----------
    template : str
        HTML written in the code (never text from input).
    **values
        The placeholders' values; :class:`Markup` is inserted as it is, everything else is
        formatted with the placeholder's format spec and then escaped.
    """
    return Markup(_FORMATTER.vformat(template, (), values))


def join(parts: Iterable, sep: str = "") -> Markup:
    """The escaped ``parts`` joined by ``sep`` (trusted markup, e.g. ``"<br>"``).

    Parameters
    ----------
    parts : iterable
        Values (escaped) or :class:`Markup`.
    sep : str, optional
        Separator written in the code.
    """
    return Markup(sep.join(escape(p) for p in parts))


def table(header: Sequence, rows: Iterable[Sequence]) -> Markup:
    """An HTML table; every header and cell value is escaped.

    Parameters
    ----------
    header : sequence
        Column titles.
    rows : iterable of sequences
        Cell values (text, numbers or :class:`Markup`).
    """
    head = join(render("<th>{x}</th>", x=x) for x in header)
    body = join(render("<tr>{cells}</tr>", cells=join(render("<td>{x}</td>", x=x) for x in r)) for r in rows)
    return render("<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>", head=head, body=body)


def png_figure(png: bytes, caption: str) -> Markup:
    """A ``<figure>`` with an embedded PNG (base64) and its escaped caption as ``alt`` and caption.

    Parameters
    ----------
    png : bytes
        The PNG file's bytes.
    caption : str
        Text (escaped).
    """
    data = base64.b64encode(bytes(png)).decode("ascii")
    return render('<figure><img alt="{cap}" src="data:image/png;base64,{data}"><figcaption>{cap}</figcaption>'
                  "</figure>", cap=caption, data=data)
