"""Reading the order-selection figure (``stabilization_plot``) back: the markers of each order, the chosen row."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET

SVG = "{http://www.w3.org/2000/svg}"


def parse_svg(text: str) -> ET.Element:
    """The first ``<svg>`` element of an SVG file or an HTML page (text) as XML (raises on bad XML)."""
    start = text.index("<svg")
    return ET.fromstring(text[start:text.index("</svg>", start) + len("</svg>")])


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def order_markers(root: ET.Element) -> dict[int, dict[str, int]]:
    """Per K: circles (resonant modes) and triangles (rigid bodies) in the groups of class ``stab-K<K>``."""
    out: dict[int, dict[str, int]] = {}
    for g in root.iter():
        if _local(g.tag) != "g":
            continue
        m = re.match(r"stab-K(\d+)\b", g.get("class", ""))
        if not m:
            continue
        k = int(m.group(1))
        d = out.setdefault(k, {"circles": 0, "triangles": 0, "chosen": 0})
        kind = "triangles" if "rigid" in g.get("class", "").split() else "circles"
        shape = "path" if kind == "triangles" else "circle"
        d[kind] += sum(1 for e in g.iter() if _local(e.tag) == shape)
        d["chosen"] += int("chosen" in g.get("class", "").split())
    return out


def texts(root: ET.Element) -> list[str]:
    return ["".join(e.itertext()) for e in root.iter() if _local(e.tag) == "text"]


def assert_figure_matches_table(root: ET.Element, rows: list[dict]) -> int:
    """Every order row's fitted modes are drawn (one circle per resonant mode, one triangle per rigid body, in the
    row's group), nothing else is, and exactly the accepted row is marked as chosen. Returns the chosen K."""
    markers = order_markers(root)
    chosen = [int(r["K"]) for r in rows if r["accepted"]]
    assert len(chosen) == 1
    for row in rows:
        k = int(row["K"])
        resonant = sum(1 for m in row["modes"] if (m["natural_frequency_hz"] or 0.0) > 0.0)
        rigid = len(row["modes"]) - resonant
        got = markers.get(k, {"circles": 0, "triangles": 0, "chosen": 0})
        assert (got["circles"], got["triangles"]) == (resonant, rigid), (k, got, row["modes"])
        assert bool(got["chosen"]) == (k == chosen[0]), (k, got)
    assert set(markers) <= {int(r["K"]) for r in rows}
    assert f"K = {chosen[0]} (chosen)" in texts(root)
    return chosen[0]
