"""masknet show and --html: offline views."""

from __future__ import annotations

from masknet.cli import main


def test_show_and_html_write_offline_views(tmp_path, small_masknet_weights, pair_files, capsys):
    template, source, _ = pair_files
    view = tmp_path / "view.html"
    assert main(["show", str(template), str(source), "-o", str(view)]) == 0
    page = view.read_text()
    assert '"name":"template"' in page and '"name":"source"' in page
    assert (tmp_path / "view.png").stat().st_size > 10_000
    out, html = tmp_path / "moved.xyz", tmp_path / "reg.html"
    args = ["register", str(template), str(source), "-o", str(out), "--html", str(html)]
    assert main([*args, "--weights", str(small_masknet_weights)]) == 0
    page = html.read_text()
    for layer in ("template", "source as given", "registered", "inliers"):
        assert f'"name":"{layer}"' in page
    assert (tmp_path / "reg.png").exists()
