"""Reading the bout report's HTML back: its elements (tag, attributes, text) and its SVG charts."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from html.parser import HTMLParser

VOID = {"meta", "br", "link", "img", "input", "hr", "col", "source", "wbr"}


@dataclass
class Element:
    tag: str
    attrs: dict[str, str]
    text: str = ""
    children: list[Element] = field(default_factory=list)

    def find_all(self, tag: str | None = None, **attrs: str) -> list[Element]:
        """Descendants with that tag (None = any) whose attributes (``data_x`` = ``data-x``) equal ``attrs``."""
        want = {k.replace("_", "-"): v for k, v in attrs.items()}
        out = []
        for c in self.children:
            if (tag is None or c.tag == tag) and all(c.attrs.get(k) == v for k, v in want.items()):
                out.append(c)
            out += c.find_all(tag, **attrs)
        return out


class _Parser(HTMLParser):
    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.root = Element("#root", {})
        self.stack = [self.root]

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        el = Element(tag, {k: v or "" for k, v in attrs})
        self.stack[-1].children.append(el)
        if tag not in VOID:
            self.stack.append(el)

    def handle_startendtag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.stack[-1].children.append(Element(tag, {k: v or "" for k, v in attrs}))

    def handle_endtag(self, tag: str) -> None:
        for k in range(len(self.stack) - 1, 0, -1):
            if self.stack[k].tag == tag:
                del self.stack[k:]
                return

    def handle_data(self, data: str) -> None:
        for el in self.stack:
            el.text += data


def parse(html: str) -> Element:
    p = _Parser()
    p.feed(html)
    p.close()
    return p.root


def svgs(html: str) -> list[ET.Element]:
    """Every inline ``<svg>`` parsed as XML (so each must be well-formed)."""
    return [ET.fromstring(m) for m in re.findall(r"<svg\b.*?</svg>", html, flags=re.S)]


def number(text: str) -> float | str | None:
    """A table cell back as a number, a word, or None for the dash of a missing value."""
    t = text.strip()
    if t == "—":
        return None
    try:
        return float(t)
    except ValueError:
        return t
