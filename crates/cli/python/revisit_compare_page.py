"""Writes the comparison page of `revisit bench compare`: one self-contained HTML file.

Usage: revisit_compare_page.py COMPARE_JSON INDEX_HTML

The page holds a table of the methods (a failed method is marked, with its reason), the
cross-visit error histograms of every method on one axis, the matching-time plot of the scaling
benchmark when compare.json carries it, and a 3D view of each method's points coloured by visit.
plotly.js is embedded from the plotly package, so the page works offline.
"""

import html
import json
import sys

import numpy as np
import plotly.graph_objects as go
import plotly.offline

# Visit colours (a point several visits saw is drawn in SHARED).
PALETTE = ["#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#9a6324"]
SHARED = "#000000"
CONFIG = {"displaylogo": False, "responsive": True}


def cell(value, digits=2):
    return "-" if value is None else f"{value:.{digits}f}"


def worst(values):
    """The largest magnitude among a method's per-visit figures, or None."""
    known = [abs(v) for v in values.values() if v is not None]
    return max(known) if known else None


def table(comparison):
    methods = comparison["methods"]
    revisit = next((m["median_px"] for m in methods if m["method"] == "revisit"), None)
    rows = []
    for m in methods:
        failed = m["failure"] is not None
        ratio = "-"
        if revisit and m["median_px"] is not None and m["method"] != "revisit":
            ratio = f"{m['median_px'] / revisit:.1f}x"
        status = f"FAILED: {html.escape(m['failure'])}" if failed else "ok"
        scale_error = worst(m["visit_scale_rel_error"])
        scale = "-" if scale_error is None else f"{100 * scale_error:.2f}%"
        rows.append(
            f"<tr class=\"{'failed' if failed else 'ok'}\"><td><b>{html.escape(m['method'])}</b><br>"
            f"<small>{html.escape(m['about'])}</small></td>"
            f"<td>{cell(m['median_px'])}</td><td>{cell(m['mean_px'])}</td><td>{ratio}</td>"
            f"<td>{m['clicks_scored']}/{m['clicks']}</td><td>{m['sessions_merged']}/{m['sessions']}</td>"
            f"<td>{scale}</td><td>{cell(worst(m['visit_rotation_deg']))}</td>"
            f"<td>{cell(m['seconds'], 1)}</td><td>{status}</td></tr>"
        )
    header = (
        "<tr><th>method</th><th>median px</th><th>mean px</th><th>median / revisit</th>"
        "<th>clicks scored</th><th>visits in one model</th>"
        "<th title=\"the worst visit's scale against its model's, by the truth's cameras\">visit scale error</th>"
        "<th title=\"the worst visit's median camera rotation error\">rotation error, deg</th>"
        "<th>seconds</th><th>status</th></tr>"
    )
    return f"<table id=\"methods\">{header}{''.join(rows)}</table>"


def histograms(comparison):
    figure = go.Figure()
    all_errors = [e for m in comparison["methods"] for e in m["errors_px"] if e > 0]
    if not all_errors:
        return "<p>No method scored a click.</p>"
    bins = np.logspace(np.log10(min(all_errors)), np.log10(max(all_errors)), 40)
    centres = np.sqrt(bins[:-1] * bins[1:])
    for m in comparison["methods"]:
        errors = [e for e in m["errors_px"] if e > 0]
        if errors:
            counts, _ = np.histogram(errors, bins=bins)
            figure.add_trace(go.Scatter(x=centres, y=counts, mode="lines", line_shape="hvh", name=m["method"]))
    figure.update_layout(
        xaxis={"type": "log", "title": "cross-visit reprojection error (px, log scale)"},
        yaxis={"title": "clicks"},
        height=420,
        margin={"t": 30},
    )
    return figure.to_html(full_html=False, include_plotlyjs=False, div_id="histograms", config=CONFIG)


def scaling(comparison):
    figures = comparison.get("scaling")
    if not figures:
        return "<p>No scaling figures given (<code>--scaling</code>, from <code>revisit bench matching --json</code>).</p>"
    strategies = figures.get("strategies", [])
    figure = go.Figure(
        go.Bar(x=[s["strategy"] for s in strategies], y=[s["matching_secs"] for s in strategies])
    )
    figure.update_layout(yaxis={"title": "matching time (s)", "type": "log"}, height=360, margin={"t": 30})
    return figure.to_html(full_html=False, include_plotlyjs=False, div_id="scaling", config=CONFIG)


def clouds(comparison):
    parts = []
    for index, m in enumerate(comparison["methods"]):
        cloud = m.get("cloud")
        if not cloud or not cloud["points"]:
            parts.append(f"<div class=\"cloud\"><h3>{html.escape(m['method'])}</h3><p>no model</p></div>")
            continue
        points = np.asarray(cloud["points"], dtype=float)
        visits = np.asarray(cloud["visit"])
        # A few stray points far off would shrink the rest to a dot: draw the bulk only.
        low, high = np.percentile(points, 2, axis=0), np.percentile(points, 98, axis=0)
        margin = 0.5 * (high - low)
        bulk = np.all((points >= low - margin) & (points <= high + margin), axis=1)
        points, visits = points[bulk], visits[bulk]
        figure = go.Figure()
        groups = [(v, name, PALETTE[v % len(PALETTE)]) for v, name in enumerate(cloud["sessions"])]
        for v, name, colour in groups + [(-1, "several visits", SHARED)]:
            chosen = points[visits == v]
            if len(chosen):
                figure.add_trace(
                    go.Scatter3d(
                        x=chosen[:, 0], y=chosen[:, 1], z=chosen[:, 2], mode="markers", name=name,
                        marker={"size": 2.5, "color": colour},
                    )
                )
        figure.update_layout(
            height=420, margin={"l": 0, "r": 0, "t": 0, "b": 0}, scene={"aspectmode": "data"},
            legend={"itemsizing": "constant", "x": 0, "y": 1},
        )
        plot = figure.to_html(full_html=False, include_plotlyjs=False, div_id=f"cloud-{index}", config=CONFIG)
        parts.append(f"<div class=\"cloud\"><h3>{html.escape(m['method'])}</h3>{plot}</div>")
    return "".join(parts)


STYLE = """
body { font-family: sans-serif; margin: 2em; color: #222; }
table { border-collapse: collapse; margin: 1em 0; }
td, th { border: 1px solid #bbb; padding: 4px 8px; text-align: right; vertical-align: top; }
td:first-child, td:last-child { text-align: left; }
tr.failed { background: #fdd; }
.clouds { display: grid; grid-template-columns: repeat(auto-fill, minmax(480px, 1fr)); gap: 1em; }
"""


def main():
    source, target = sys.argv[1], sys.argv[2]
    with open(source, encoding="utf-8") as f:
        comparison = json.load(f)
    published = ", ".join(f"{name} {px} px" for name, px in comparison["published_median_px"].items())
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>Revisit: joint against post-hoc</title>
<style>{STYLE}</style>
<script type="text/javascript">{plotly.offline.get_plotlyjs()}</script></head>
<body>
<h1>Joint reconstruction against post-hoc alignment</h1>
<p>Dataset <code>{html.escape(str(comparison['dataset']))}</code>, visits {html.escape(', '.join(comparison['sessions']))}.
Cross-visit reprojection error of the truth's clicks (the published protocol, at the click's depth).
Published on real reefs (median): {html.escape(published)}.</p>
{table(comparison)}
<h2>Cross-visit error per method</h2>
{histograms(comparison)}
<h2>Matching time (scaling benchmark)</h2>
{scaling(comparison)}
<h2>Points by visit</h2>
<p>A sample of each model's points (stray points far outside the bulk are not drawn); black: seen by several visits.</p>
<div class="clouds">{clouds(comparison)}</div>
</body></html>
"""
    with open(target, "w", encoding="utf-8") as f:
        f.write(page)


if __name__ == "__main__":
    main()
