"""`lesions.md`: the lesion conditions of a report side by side, against the order the 1-D theory predicts.

The theory (`hippo_nav.theory.lesions`, docs/theory.md): Bayesian fusion of the grid modules gives the place
field `σ = (Σ_m 1/σ_m²)^(−1/2)` over the modules still active, so every lesion widens it and losing the sharpest
(dorsal, k = 4) widens it most: σ_dorsal lost > σ_intermediate lost > σ_ventral lost > σ_intact for the
default module widths. Per condition (the runs of every seed): the measured place-bump width, the theory's
width from the same runs' module widths (`theory_sigma_rad`), the path-integration error (the place code
against its odometry) and the place code's ATE against the ground truth, each as mean ± 95 % CI (n). Then the
order of the measured widths against the theory's, and which neighbours in that order the confidence
intervals separate. Conditions are compared within runs whose other axes are equal.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

from hippo_nav.report.collect import LESION_MODULES, RunRow
from hippo_nav.report.tables import Group, Stats, stats

CONDITION_ORDER = ("none", *LESION_MODULES)
COLUMNS = (
    ("place_sigma_rad", "place bump σ (rad)", 4),
    ("theory_sigma_rad", "1-D theory σ from the module widths (rad)", 4),
    ("pi_error_2d_m", "path-integration error (m)", 3),
    ("ate_2d_neural_m", "place code ATE 2-D vs ground truth (m)", 3),
)


def lesion_comparison(rows: Sequence[RunRow], keys: Sequence[str]) -> str | None:
    """The Markdown of lesions.md, or None when the runs do not differ in lesions."""
    if "lesion" not in keys:
        return None
    others = [k for k in keys if k not in ("lesion", "seed")]
    parts: dict[str, list[RunRow]] = {}
    for row in rows:
        if row.status == "done":
            parts.setdefault(Group({k: row.axes.get(k) for k in others}, []).label(), []).append(row)
    sections = []
    for label, part in parts.items():
        conditions = sorted({str(r.axes.get("lesion")) for r in part}, key=_rank)
        if len(conditions) < 2:
            continue
        sections.append(_section(label, part, conditions))
    if not sections:
        return None
    return "# Lesions against the 1-D theory\n\n" + "\n".join(sections)


def _rank(condition: str) -> tuple[int, str]:
    return (
        (CONDITION_ORDER.index(condition), "")
        if condition in CONDITION_ORDER
        else (len(CONDITION_ORDER), condition)
    )


def _section(label: str, part: Sequence[RunRow], conditions: list[str]) -> str:
    by: dict[str, dict[str, Stats]] = {
        c: {
            name: stats([r.values.get(name) for r in part if r.axes.get("lesion") == c])
            for name, _, _ in COLUMNS
        }
        for c in conditions
    }
    lines = [f"## {label}" if label != "all runs" else "## All runs", ""]
    head = ["lesion", *(title for _, title, _ in COLUMNS)]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for c in conditions:
        lines.append("| " + " | ".join([c, *(by[c][name].text(d) for name, _, d in COLUMNS)]) + " |")
    lines.append("")
    measured = _order(by, "place_sigma_rad")
    theory = _order(by, "theory_sigma_rad")
    if measured:
        lines.append(f"- Measured place-bump width, widest first: {' > '.join(measured)}.")
    if theory:
        lines.append(f"- The 1-D theory's order from the same runs' module widths: {' > '.join(theory)}.")
    if measured and theory:
        verdict = "matches" if measured == theory else "differs from"
        lines.append(f"- The measured order {verdict} the theory's.")
        separated = []
        for wider, narrower in itertools.pairwise(measured):
            a, b = by[wider]["place_sigma_rad"], by[narrower]["place_sigma_rad"]
            if a.mean is not None and b.mean is not None and a.ci95 is not None and b.ci95 is not None:
                apart = a.mean - a.ci95 > b.mean + b.ci95
                separated.append(f"{wider} > {narrower}: {'separated' if apart else 'overlapping'}")
        if separated:
            lines.append(
                f"- 95 % confidence intervals of neighbours in the measured order: {'; '.join(separated)}."
            )
    pi = _order(by, "pi_error_2d_m")
    if pi:
        lines.append(f"- Path-integration error, largest first: {' > '.join(pi)}.")
    return "\n".join(lines) + "\n"


def _order(by: dict[str, dict[str, Stats]], name: str) -> list[str]:
    means = {c: s[name].mean for c, s in by.items()}
    if any(m is None for m in means.values()):
        return []
    return sorted(means, key=lambda c: -float(means[c] or 0.0))
