"""`hippo-nav figures` writes the theory figures (paper figures 1–3) as decodable, non-blank PNG files."""

from __future__ import annotations

import cv2
import numpy as np
from hippo_nav.cli import main

EXPECTED = {"fig1_derivation.png", "fig2_lesion_expansion.png", "fig3_alignment.png"}


def test_figures_command_writes_decodable_images(tmp_path, capsys):
    out = tmp_path / "figures"  # does not exist yet: the command must create it
    assert main(["figures", "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == f"wrote {', '.join(sorted(EXPECTED))} into {out}"
    assert {p.name for p in out.iterdir()} == EXPECTED
    for path in sorted(out.iterdir()):
        assert path.stat().st_size > 10_000, f"{path.name} is suspiciously small"
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        assert image is not None, f"{path.name} does not decode as an image"
        height, width, _ = image.shape
        assert height >= 600 and width >= 600
        # Not blank: many distinct colours (curves in several colours, text) and a real spread of intensity.
        colours = np.unique(image.reshape(-1, 3), axis=0)
        assert len(colours) > 50, f"{path.name} has only {len(colours)} colours"
        assert image.std() > 10.0
        # Plotted ink covers a fair part of the canvas, not just a frame.
        ink = np.any(image < 200, axis=2).mean()
        assert ink > 0.02, f"{path.name}: only {ink:.1%} of the pixels are drawn"


def test_an_empty_out_is_refused_not_taken_for_the_default(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["figures", "--out", ""]) == 2
    assert "--out is empty" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()
