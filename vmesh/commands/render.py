"""``vmesh render``: pictures of a finished run folder and a one-page HTML report.

Examples
--------
::

    vmesh render out/y                  # out/y/pictures/*.png and out/y/report.html
    vmesh render out/y -o shots --size 800x600
"""

from __future__ import annotations

from ..cli import EXTRA_COMMANDS
from ..errors import ParameterError

HELP = "render a run folder (surface, skeleton, blocks, mesh, clipped mesh, labels, quality) to PNGs and an HTML report"


def add_arguments(p) -> None:
    p.add_argument("run_dir", metavar="DIR", help="a finished run folder (vmesh run ... -o DIR)")
    p.add_argument("-o", "--out", metavar="DIR", help="write pictures/ and report.html here (default: DIR)")
    p.add_argument("--size", default="1000x750", metavar="WxH", help="picture size in pixels (default 1000x750)")
    p.add_argument("--no-html", action="store_true", help="pictures only")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")


def _size(text: str) -> tuple[int, int]:
    w, sep, h = text.lower().partition("x")
    try:
        size = (int(w), int(h))
    except ValueError:
        size = (0, 0)
    if not sep or not (16 <= size[0] <= 8000 and 16 <= size[1] <= 8000):
        raise ParameterError(f"--size {text!r}: expected WxH in pixels, e.g. 1000x750")
    return size


def run(args) -> int:
    from ..render import render_run

    size = _size(args.size)
    out = render_run(args.run_dir, args.out, size=size, html=not args.no_html)
    if not args.quiet:
        for name, path in out.items():
            print(f"{name:<10} {path} ({path.stat().st_size // 1024} KB)")
    return 0


EXTRA_COMMANDS["render"] = (add_arguments, run, HELP)
