"""``vmesh render``: pictures and the HTML page for a synthetic and a real case."""

import numpy as np
import pytest

from vmesh.cli import main
from vmesh.render import PICTURES

PNG = b"\x89PNG\r\n\x1a\n"


def check_pictures(folder, size=(1000, 750)):
    """Every picture exists, is a PNG of the asked size and is no blank image."""
    from PIL import Image

    for name in PICTURES:
        path = folder / "pictures" / f"{name}.png"
        assert path.is_file(), name
        assert path.read_bytes()[:8] == PNG and path.stat().st_size > 10_000, name
        img = np.asarray(Image.open(path).convert("RGB"), float)
        if name != "quality":
            assert img.shape[:2] == (size[1], size[0]), name
        non_white = (img < 245).any(axis=2).mean()
        assert 0.02 < non_white < 0.9, (name, non_white)  # something drawn, not all one colour
        assert img.std() > 10, name
    html = (folder / "report.html").read_text()
    for name in PICTURES:
        assert f"pictures/{name}.png" in html
    for table in ("Counts", "Quality (scaled Jacobian)", "Elements per label", "Boundary faces", "Filters"):
        assert f"<h2>{table}</h2>" in html
    assert not list(folder.rglob(".*partial*"))
    # staged and swapped in: no staging folder left, and not mkdtemp's private mode
    assert not list(folder.glob(".pictures*"))
    assert (folder / "pictures").stat().st_mode & 0o077


def test_render_synthetic(y_run, tmp_path, capsys):
    assert main(["render", str(y_run), "-o", str(tmp_path / "shots")]) == 0
    out = capsys.readouterr().out
    assert "report.html" in out
    check_pictures(tmp_path / "shots")


@pytest.mark.slow
def test_render_real(real_path, tmp_path, capsys):
    from vmesh.chain import FilterChain

    surface, skeleton = real_path("carotid_vmtk.vtp"), real_path("carotid_vmtk_centerline.vtp")
    run = tmp_path / "carotid"
    FilterChain.load("default").run(surface=surface, skeleton=skeleton, out_dir=run)
    assert (run / "meshlab" / "surface.ply").is_file()  # the run folder holds the input surface
    assert main(["render", str(run), "--size", "800x600", "-q"]) == 0
    check_pictures(run, size=(800, 600))
    assert "carotid_vmtk.vtp" in (run / "report.html").read_text()


def test_render_bad_input(tmp_path, capsys):
    assert main(["render", str(tmp_path / "nope")]) == 2
    assert capsys.readouterr().err.strip() == f"vmesh: error: {tmp_path / 'nope'}: run folder not found"
    assert main(["render", str(tmp_path), "--size", "big"]) == 2
    assert "--size 'big'" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
