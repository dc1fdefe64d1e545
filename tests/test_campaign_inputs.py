"""A bad-input campaign: hostile or absurd plans and grids, configuration and run files, and
the inputs of ``evaluate``, each run through the command line as a user would.

Every case builds its input in ``tmp_path`` and states its outcome: a refusal (exit status
2, one ``segloc: error:`` line naming the file and saying what is wrong) or a success whose
output is checked. None may give a traceback, another exit status, a hang, a wrong success,
a lost output or an overwrite nobody asked for. Hostile sizes stay bounded: a grid of
20,000 × 20,000 cells is a header of a few bytes, refused before any pixel is read; a file
whose entities, clones or block references would expand to billions is refused by counting.
"""

from __future__ import annotations

import json
import os
import struct
import sys
import zlib
from collections.abc import Callable
from pathlib import Path

import ezdxf
import numpy as np
import pytest
import yaml
from conftest import HALL
from PIL import Image
from test_cli import ESTIMATE_HEADER, SURVEY_HEADER, assert_one_line_error, run_cli
from test_grids import GOOD

from segloc_cli import __version__
from segloc_cli.io.maps import read_map

# --- what the process opens ----------------------------------------------------------------

_OPENED: list[str] | None = None
"""Paths opened while a case watches (``watching_opens``); None when none watches."""


def _audit(event: str, args: tuple) -> None:
    if _OPENED is not None and event == "open" and isinstance(args[0], str | bytes | Path):
        _OPENED.append(os.fsdecode(args[0]))


sys.addaudithook(_audit)


def run_watching_opens(capsys, *args) -> tuple[object, list[str]]:
    """``run_cli`` that also returns every path the process opened meanwhile."""
    global _OPENED
    _OPENED = []
    try:
        result = run_cli(capsys, *args)
        return result, list(_OPENED)
    finally:
        _OPENED = None


def refused(result, path: Path, *fragments: str) -> None:
    """Exit 2 with one line naming ``path`` first (and perhaps its rows) and holding
    ``fragments``."""
    line = assert_one_line_error(result, *fragments)
    named = f"segloc: error: {path}"
    assert line.startswith((f"{named}: ", f"{named}, row")), f"{path} is not named first: {line}"


# =========================================================================================
# 1. Plans and grids that are hostile or absurd
# =========================================================================================

SVG_OPEN = (
    '<svg xmlns="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink" '
    'width="10mm" height="10mm" viewBox="0 0 10 10">'
)
WALL = '<line x1="0" y1="0" x2="5" y2="0"/>'
"""One wall 5 user units long: 5 m with ``--scale 1``."""


def _svg(body: str, doctype: str = "") -> str:
    return f'<?xml version="1.0"?>\n{doctype}{SVG_OPEN}{body}</svg>\n'


def _laughs(levels: int = 9) -> str:
    entities = ['<!ENTITY a0 "lol">']
    entities += [f'<!ENTITY a{i} "{f"&a{i - 1};" * 10}">' for i in range(1, levels + 1)]
    return f"<!DOCTYPE svg [{''.join(entities)}]>\n"


def _use_laughs(levels: int = 9) -> str:
    groups = [f'<g id="u0">{WALL}</g>']
    groups += [
        f'<g id="u{i}">{f"<use href={chr(34)}#u{i - 1}{chr(34)}/>" * 10}</g>'
        for i in range(1, levels + 1)
    ]
    return f'<defs>{"".join(groups)}</defs><use href="#u{levels}"/>'


def _use_chain(length: int) -> str:
    groups = [f'<g id="c0">{WALL}</g>']
    groups += [f'<g id="c{i}"><use href="#c{i - 1}"/></g>' for i in range(1, length)]
    return f'<defs>{"".join(groups)}</defs><use href="#c{length - 1}"/>'


def _nested(depth: int) -> str:
    return "<g>" * depth + WALL + "</g>" * depth


SECRET = "SECRET"
"""Stands for the path of a file beside the drawing that no case may open."""

# name → (the SVG's text, SECRET where the file's path goes; expected: an int, the segments
# read, or a phrase of the refusal)
SVG_CASES: dict[str, tuple[str, int | str]] = {
    "billion laughs": (_svg(f"<desc>&a9;</desc>{WALL}", _laughs()), "declares the entity a0"),
    "quadratic blow-up": (
        _svg(
            f"<desc>{'&big;' * 2000}</desc>{WALL}",
            f'<!DOCTYPE svg [<!ENTITY big "{"x" * 50_000}">]>\n',
        ),
        "declares the entity big in its DOCTYPE; segloc expands no XML entities",
    ),
    "one harmless entity": (
        _svg('<line x1="0" y1="0" x2="&n;" y2="0"/>', '<!DOCTYPE svg [<!ENTITY n "5">]>\n'),
        "declares the entity n",
    ),
    "XXE system path": (
        _svg(f"<desc>&x;</desc>{WALL}", f'<!DOCTYPE svg [<!ENTITY x SYSTEM "{SECRET}">]>\n'),
        f"declares the external entity x ({SECRET}), a reference to another file",
    ),
    "XXE file URL": (
        _svg(f"<desc>&x;</desc>{WALL}", f'<!DOCTYPE svg [<!ENTITY x SYSTEM "file://{SECRET}">]>\n'),
        "declares the external entity x (file://",
    ),
    "XXE /etc/passwd": (
        _svg(f"<desc>&x;</desc>{WALL}", '<!DOCTYPE svg [<!ENTITY x SYSTEM "/etc/passwd">]>\n'),
        "declares the external entity x (/etc/passwd)",
    ),
    "XXE public id": (
        _svg(
            f"<desc>&x;</desc>{WALL}",
            f'<!DOCTYPE svg [<!ENTITY x PUBLIC "-//X//Y" "{SECRET}">]>\n',
        ),
        "declares the external entity x",
    ),
    "XXE parameter entity": (
        _svg(WALL, f'<!DOCTYPE svg [<!ENTITY % p SYSTEM "{SECRET}"> %p;]>\n'),
        "declares the external entity p",
    ),
    "external DTD is not fetched": (
        _svg(WALL, f'<!DOCTYPE svg SYSTEM "{SECRET}">\n'),
        1,
    ),
    "the SVG 1.1 DOCTYPE of drawing programs": (
        _svg(
            WALL,
            '<!DOCTYPE svg PUBLIC "-//W3C//DTD SVG 1.1//EN" '
            '"http://www.w3.org/Graphics/SVG/1.1/DTD/svg11.dtd">\n',
        ),
        1,
    ),
    "XInclude is not followed": (
        _svg(
            f'<xi:include xmlns:xi="http://www.w3.org/2001/XInclude" href="{SECRET}" '
            f'parse="text"/>{WALL}'
        ),
        1,
    ),
    "image is not loaded": (_svg(f'<image href="{SECRET}" width="5" height="5"/>{WALL}'), 1),
    "use of another file is not followed": (_svg(f'<use href="{SECRET}#w"/>{WALL}'), 1),
    "CSS import is not fetched": (_svg(f"<style>@import url({SECRET});</style>{WALL}"), 1),
    "use of itself": (
        _svg(f'<g id="a">{WALL}<use xlink:href="#a"/></g>'),
        "a <use> of #a places #a inside itself (#a → #a)",
    ),
    "uses of each other": (
        _svg(
            f'<defs><g id="a"><use href="#b"/></g><g id="b"><use href="#a"/></g></defs>'
            f'{WALL}<use href="#a"/>'
        ),
        "places #a inside itself (#a → #b → #a)",
    ),
    "use laughs": (_svg(_use_laughs()), "places more than 250,000 elements once every <use>"),
    "use chain too deep": (_svg(_use_chain(300)), "elements nest more than 256 levels deep"),
    "use chain within bounds": (_svg(_use_chain(100)), 1),
    "groups 100,000 deep": (_svg(_nested(100_000)), "elements nest more than 256 levels deep"),
    "groups 200 deep": (_svg(_nested(200)), 1),
    "use of an id the drawing lacks": (_svg(f'<use href="#nowhere"/>{WALL}'), 1),
    "two elements with one id": (_svg(f'<g id="w">{WALL}</g><g id="w">{WALL}</g>'), 2),
    "empty file": ("", "not an SVG drawing: not well-formed XML"),
    "binary bytes": ("\x00\x01\x02svg", "not an SVG drawing: not well-formed XML"),
}


@pytest.mark.parametrize("case", sorted(SVG_CASES))
def test_svg(case, tmp_path, capsys):
    text, expected = SVG_CASES[case]
    secret = tmp_path / "secret.txt"
    secret.write_text('<line x1="0" y1="0" x2="9" y2="0"/>\n')
    path, out = tmp_path / "plan.svg", tmp_path / "m.json"
    path.write_text(text.replace(SECRET, str(secret)), encoding="utf-8")
    args = ["map", "import", path, "--out", out, "--scale", "1"]
    result, opened = run_watching_opens(capsys, *args)
    assert str(secret) not in opened, "a file other than the drawing was read"
    if isinstance(expected, int):
        assert result.code == 0, result.err
        assert len(read_map(out)) == expected
    else:
        refused(result, path, expected.replace(SECRET, str(secret)))
        assert not out.exists()


def test_svg_in_utf16_is_read(tmp_path, capsys):
    path = tmp_path / "plan.svg"
    path.write_bytes(_svg(WALL).replace('"1.0"?', '"1.0" encoding="UTF-16"?').encode("utf-16"))
    result = run_cli(capsys, "map", "import", path, "--out", tmp_path / "m.json", "--scale", "1")
    assert result.code == 0, result.err
    assert read_map(tmp_path / "m.json").tolist() == [[0.0, 0.0, 5.0, 0.0]]


def _dxf() -> ezdxf.document.Drawing:
    doc = ezdxf.new("R2010")
    doc.header["$INSUNITS"] = 6
    return doc


def _self_insert(doc) -> None:
    block = doc.blocks.new("SELF")
    block.add_line((0, 0), (1, 0))
    block.add_blockref("SELF", (2, 0))
    doc.modelspace().add_blockref("SELF", (0, 0))


def _cycle(names: tuple[str, ...]) -> Callable:
    def draw(doc) -> None:
        blocks = [doc.blocks.new(name) for name in names]
        blocks[0].add_line((0, 0), (1, 0))
        for block, following in zip(blocks, [*names[1:], names[0]], strict=True):
            block.add_blockref(following, (0, 1))
        doc.modelspace().add_blockref(names[0], (0, 0))

    return draw


def _unplaced_cycle(doc) -> None:
    block = doc.blocks.new("LOOP")
    block.add_blockref("LOOP", (1, 0))
    doc.modelspace().add_line((0, 0), (2, 0))


def _chain(length: int) -> Callable:
    """Blocks L0 … L(length−1), each holding a reference to the one before; L0 a wall."""

    def draw(doc) -> None:
        for i in range(length):
            block = doc.blocks.new(f"L{i}")
            if i == 0:
                block.add_line((0, 0), (1, 0))
            else:
                block.add_blockref(f"L{i - 1}", (0, 0))
        doc.modelspace().add_blockref(f"L{length - 1}", (0, 0))

    return draw


def _reused_deeper(doc) -> None:
    """A 12-level chain placed once directly (within bounds) and once from 6 levels down."""
    _chain(12)(doc)
    for i in range(6):
        block = doc.blocks.new(f"OUTER{i}")
        block.add_blockref("L11" if i == 0 else f"OUTER{i - 1}", (0, 5))
    doc.modelspace().add_blockref("OUTER5", (0, 0))


def _fan(doc) -> None:
    for i in range(10):
        block = doc.blocks.new(f"F{i}")
        if i == 0:
            block.add_line((0, 0), (1, 0))
        else:
            for k in range(10):
                block.add_blockref(f"F{i - 1}", (k * 2.0 * 10**i, 0))
    doc.modelspace().add_blockref("F9", (0, 0))


def _array(rows: int, columns: int) -> Callable:
    def draw(doc) -> None:
        doc.blocks.new("COLUMN").add_line((0, 0), (0.5, 0))
        ref = doc.modelspace().add_blockref("COLUMN", (0, 0))
        ref.dxf.row_count, ref.dxf.column_count = rows, columns
        ref.dxf.row_spacing, ref.dxf.column_spacing = 3.0, 4.0

    return draw


def _cycle_through_array(doc) -> None:
    block = doc.blocks.new("GRID")
    block.add_line((0, 0), (1, 0))
    ref = block.add_blockref("GRID", (0, 5))
    ref.dxf.row_count, ref.dxf.row_spacing = 2, 1.0
    doc.modelspace().add_blockref("GRID", (0, 0))


# name → (what draws the drawing, then: segments read or a phrase of the refusal)
DXF_CASES: dict[str, tuple[Callable, int | str]] = {
    "block inserting itself": (
        _self_insert,
        "block SELF holds a reference to itself (SELF → SELF)",
    ),
    "two blocks inserting each other": (_cycle(("A", "B")), "(A → B → A)"),
    "three blocks in a ring": (_cycle(("A", "B", "C")), "(A → B → C → A)"),
    "a ring through an array": (_cycle_through_array, "block GRID holds a reference to itself"),
    "a ring no reference reaches": (_unplaced_cycle, 1),
    "100 levels of blocks": (_chain(100), "block references nest more than 16 levels deep"),
    "16 levels of blocks": (_chain(16), 1),
    "17 levels of blocks": (_chain(17), "nest more than 16 levels deep"),
    "a block placed deeper than it was first met": (_reused_deeper, "nest more than 16 levels"),
    "10^9 entities through ten levels of tens": (_fan, "place more than 250,000 entities"),
    "a 30,000 × 30,000 array": (_array(30_000, 30_000), "place more than 250,000 entities"),
    "a 2 × 3 array is six copies": (_array(2, 3), 6),
}


@pytest.mark.parametrize("case", sorted(DXF_CASES))
def test_dxf(case, tmp_path, capsys):
    draw, expected = DXF_CASES[case]
    doc = _dxf()
    draw(doc)
    path, out = tmp_path / "plan.dxf", tmp_path / "m.json"
    doc.saveas(path)
    result = run_cli(capsys, "map", "import", path, "--out", out)
    if isinstance(expected, int):
        assert result.code == 0, result.err
        assert len(read_map(out)) == expected
    else:
        refused(result, path, expected)
        assert not out.exists()


def test_a_dxf_array_places_every_copy_where_it_is_drawn(tmp_path, capsys):
    doc = _dxf()
    _array(2, 3)(doc)
    doc.saveas(tmp_path / "plan.dxf")
    assert (
        run_cli(capsys, "map", "import", tmp_path / "plan.dxf", "--out", tmp_path / "m.json").code
        == 0
    )
    starts = sorted(map(tuple, read_map(tmp_path / "m.json")[:, :2].tolist()))
    assert starts == [(x, y) for x in (0.0, 4.0, 8.0) for y in (0.0, 3.0)]


# --- nav2 grids ----------------------------------------------------------------------------

GOOD_HEADER = {**GOOD, "resolution": 0.1}  # test_grids' header, at 10 cm cells

ROOM = np.full((40, 40), 254, dtype=np.uint8)
ROOM[5, 5:35] = ROOM[34, 5:35] = ROOM[5:35, 5] = ROOM[5:35, 34] = 0
"""A 3 m square room in 10 cm cells: four walls."""


def _png_header(columns: int, rows: int) -> bytes:
    """A PNG whose header says ``columns`` × ``rows`` grey pixels, with a few bytes of data."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    ihdr = struct.pack(">IIBBBBB", columns, rows, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64))


def _image(pixels, fmt: str = "PNG") -> Callable[[Path], None]:
    def write(path: Path) -> None:
        Image.fromarray(np.asarray(pixels, dtype=np.uint8)).save(path, format=fmt)

    return write


def _bytes(data: bytes) -> Callable[[Path], None]:
    return lambda path: path.write_bytes(data)


def _truncated_png(path: Path) -> None:
    _image(ROOM)(path)
    path.write_bytes(path.read_bytes()[:-40])


def _aliases(levels: int = 9) -> list[str]:
    """YAML lines whose last anchor nests 10^levels items through aliases."""
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, levels + 1)]
    return lines


def _yaml_text(header: dict, before: list[str] = ()) -> str:
    return "\n".join([*before, yaml.safe_dump(header)])


# name → (YAML text, what writes grid.png, expected: segments read or a phrase of the refusal;
# a phrase starting "@" names the image rather than the YAML)
GRID_CASES: dict[str, tuple[str, Callable | None, int | str]] = {
    "1 × 1 occupied": (
        _yaml_text(GOOD_HEADER),
        _image([[0]]),
        "1 occupied cells in grid.png (1 × 1 cells of 0.1 m) make no wall",
    ),
    "1 × 1 free": (
        _yaml_text(GOOD_HEADER),
        _image([[254]]),
        "no occupied cells in grid.png (1 × 1",
    ),
    "1 × 1 cell of 10 m": (
        _yaml_text({**GOOD_HEADER, "resolution": 10.0}),
        _image([[0]]),
        "1 occupied cells in grid.png (1 × 1 cells of 10 m)",
    ),
    "a row of 4 cells of 1 m": (
        _yaml_text({**GOOD_HEADER, "resolution": 1.0}),
        _image([[0, 0, 0, 0]]),
        1,
    ),
    "the room": (_yaml_text(GOOD_HEADER), _image(ROOM), 4),
    "20,000 × 20,000 PGM": (
        _yaml_text(GOOD_HEADER),
        _bytes(b"P5\n20000 20000\n255\n" + b"\0" * 64),
        "@image is 20000 × 20000 pixels, more than 100,000,000 cells",
    ),
    "20,000 × 20,000 PNG": (
        _yaml_text(GOOD_HEADER),
        _bytes(_png_header(20_000, 20_000)),
        "@image is 20000 × 20000 pixels, more than 100,000,000 cells",
    ),
    "10,000 × 10,001 PGM": (
        _yaml_text(GOOD_HEADER),
        _bytes(b"P5\n10000 10001\n255\n" + b"\0" * 64),
        "@image is 10000 × 10001 pixels, more than 100,000,000 cells",
    ),
    "resolution NaN": (
        _yaml_text(GOOD_HEADER).replace("0.1", ".nan"),
        _image(ROOM),
        "`resolution` must be a finite number",
    ),
    "resolution inf": (
        _yaml_text(GOOD_HEADER).replace("0.1", ".inf"),
        _image(ROOM),
        "`resolution` must be a finite number",
    ),
    "resolution -inf": (
        _yaml_text(GOOD_HEADER).replace("0.1", "-.inf"),
        _image(ROOM),
        "`resolution` must be a finite number",
    ),
    "resolution 0": (
        _yaml_text({**GOOD_HEADER, "resolution": 0}),
        _image(ROOM),
        "`resolution` must be more than 0 m",
    ),
    "resolution negative": (
        _yaml_text({**GOOD_HEADER, "resolution": -0.05}),
        _image(ROOM),
        "`resolution` must be more than 0 m, got -0.05",
    ),
    "resolution 1e300": (
        _yaml_text({**GOOD_HEADER, "resolution": 1e300}),
        _image(ROOM),
        "its 40 × 40 cells of 1e+300 m from origin (0, 0) reach beyond ±1e+07 m; check `res",
    ),
    "resolution 1e-300": (
        _yaml_text({**GOOD_HEADER, "resolution": 1e-300}),
        _image(ROOM),
        "make no wall of 0.25 m or more; check resolution",
    ),
    "resolution as text holding a number": (
        _yaml_text({**GOOD_HEADER, "resolution": "0.1"}),
        _image(ROOM),
        4,
    ),
    "resolution as a word": (
        _yaml_text({**GOOD_HEADER, "resolution": "fine"}),
        _image(ROOM),
        "`resolution` must be a finite number, got 'fine'",
    ),
    "resolution true": (
        _yaml_text({**GOOD_HEADER, "resolution": True}),
        _image(ROOM),
        "`resolution` must be a finite number, got True",
    ),
    "resolution a list": (
        _yaml_text({**GOOD_HEADER, "resolution": [0.1]}),
        _image(ROOM),
        "`resolution` must be a finite number",
    ),
    "origin x NaN": (
        _yaml_text(GOOD_HEADER).replace("- 0.0\n", "- .nan\n", 1),
        _image(ROOM),
        "`origin` must be a finite number",
    ),
    "origin y inf": (
        _yaml_text({**GOOD_HEADER, "origin": [0.0, "inf", 0.0]}),
        _image(ROOM),
        "`origin` must be a finite number",
    ),
    "origin yaw NaN": (
        _yaml_text({**GOOD_HEADER, "origin": [0.0, 0.0, "nan"]}),
        _image(ROOM),
        "`origin` must be a finite number",
    ),
    "origin 1e308": (
        _yaml_text({**GOOD_HEADER, "origin": [1e308, 0.0, 0.0]}),
        _image(ROOM),
        "reach beyond ±1e+07 m; check `resolution` and `origin`",
    ),
    "origin yaw in degrees": (
        _yaml_text({**GOOD_HEADER, "origin": [0.0, 0.0, 90]}),
        _image(ROOM),
        "`origin` yaw must lie within ±12.57 rad, got 90; map_server takes radians",
    ),
    "origin yaw 1e300": (
        _yaml_text({**GOOD_HEADER, "origin": [0.0, 0.0, 1e300]}),
        _image(ROOM),
        "`origin` yaw must lie within",
    ),
    "origin as text": (
        _yaml_text({**GOOD_HEADER, "origin": "0, 0, 0"}),
        _image(ROOM),
        "`origin` must be [x, y, yaw], got '0, 0, 0'",
    ),
    "negate 0.5": (
        _yaml_text({**GOOD_HEADER, "negate": 0.5}),
        _image(ROOM),
        "`negate` must be 0 or 1, got 0.5",
    ),
    "image missing": (
        _yaml_text({**GOOD_HEADER, "image": "gone.png"}),
        None,
        "gone.png is not there; check `image`",
    ),
    "image is a folder": (
        _yaml_text({**GOOD_HEADER, "image": "."}),
        None,
        "@is a directory, expected a PGM or PNG image",
    ),
    "image is text": (
        _yaml_text(GOOD_HEADER),
        _bytes(b"walls: 4\n"),
        "@not a readable PGM or PNG image (its bytes are neither; named by grid.yaml)",
    ),
    "image is empty": (_yaml_text(GOOD_HEADER), _bytes(b""), "@not a readable PGM or PNG image"),
    "image is a JPEG": (
        _yaml_text(GOOD_HEADER),
        _image(ROOM, "JPEG"),
        "@not a readable PGM or PNG image",
    ),
    "image is a BMP": (
        _yaml_text(GOOD_HEADER),
        _image(ROOM, "BMP"),
        "@not a readable PGM or PNG image",
    ),
    "image is a PGM named .png": (_yaml_text(GOOD_HEADER), _image(ROOM, "PPM"), 4),
    "image cut short": (
        _yaml_text(GOOD_HEADER),
        _truncated_png,
        "@not a readable PGM or PNG image",
    ),
    "image is the YAML": (
        _yaml_text({**GOOD_HEADER, "image": "grid.yaml"}),
        None,
        "@not a readable PGM or PNG image",
    ),
    "image is /etc/passwd": (
        _yaml_text({**GOOD_HEADER, "image": "/etc/passwd"}),
        None,
        "not a readable PGM or PNG image",
    ),
    "image is /dev/zero": (
        _yaml_text({**GOOD_HEADER, "image": "/dev/zero"}),
        None,
        "is not a regular file",
    ),
    "YAML billion laughs in origin": (
        _yaml_text(
            {k: v for k, v in GOOD_HEADER.items() if k != "origin"}, [*_aliases(), "origin: *a9"]
        ),
        _image(ROOM),
        "`origin` must be [x, y, yaw], got [[[...], [...], [...], [...], ...]",
    ),
    "YAML billion laughs in image": (
        _yaml_text(
            {k: v for k, v in GOOD_HEADER.items() if k != "image"}, [*_aliases(), "image: *a9"]
        ),
        _image(ROOM),
        "`image` must name the map's image, got [[[...]",
    ),
    "YAML nested 10,000 deep": (
        "origin: " + "[" * 10_000 + "]" * 10_000 + "\n",
        None,
        "not a nav2 map YAML: nested too deep to read",
    ),
    "YAML over 1 MiB": (
        _yaml_text(GOOD_HEADER) + "#" * (1 << 20),
        _image(ROOM),
        "is over 1,048,576 bytes; not a nav2 map YAML",
    ),
    "YAML with a Python tag": (
        _yaml_text(GOOD_HEADER) + "x: !!python/object/apply:os.system ['true']\n",
        _image(ROOM),
        "not valid YAML at line",
    ),
    "YAML not text": ("\xff\xfe\x00bad", None, "not a text file; expected a nav2 map YAML"),
    "YAML empty": ("", None, "not a nav2 map YAML: expected the keys image"),
}


@pytest.mark.parametrize("case", sorted(GRID_CASES))
def test_grid(case, tmp_path, capsys):
    text, write_image, expected = GRID_CASES[case]
    if write_image is not None:
        write_image(tmp_path / "grid.png")
    path, out = tmp_path / "grid.yaml", tmp_path / "m.json"
    path.write_text(text, encoding="latin-1" if "\xff" in text else "utf-8")
    result = run_cli(capsys, "map", "import", path, "--out", out)
    if isinstance(expected, int):
        assert result.code == 0, result.err
        assert len(read_map(out)) == expected
    elif expected.startswith("@"):
        named = Path(yaml.safe_load(text)["image"]) if "image:" in text else None
        image = tmp_path / (named or "grid.png")
        refused(result, image, expected[1:])
        assert not out.exists()
    else:
        line = assert_one_line_error(result, expected)
        assert str(path) in line or "/etc/passwd" in line or "/dev/zero" in line, line
        assert not out.exists()


def test_a_grid_s_image_may_lie_anywhere_and_is_recorded(tmp_path, capsys):
    """An image outside the YAML's folder (an absolute path, or ``..``) is read, as
    map_server reads it; the map's source and the run file name it."""
    (tmp_path / "images").mkdir()
    (tmp_path / "maps").mkdir()
    image = tmp_path / "images" / "room.png"
    _image(ROOM)(image)
    for name, named in (("relative", "../images/room.png"), ("absolute", str(image))):
        path = tmp_path / "maps" / f"{name}.yaml"
        path.write_text(yaml.safe_dump({**GOOD_HEADER, "image": named}))
        out = tmp_path / "maps" / f"{name}.json"
        result = run_cli(capsys, "map", "import", path, "--out", out)
        assert result.code == 0, result.err
        assert len(read_map(out)) == 4
        source = json.loads(out.read_text())["source"]
        assert Path(source["image"]).resolve() == image
        assert "images/room.png" in (tmp_path / "maps" / f"{name}.run.toml").read_text()


# =========================================================================================
# 2. Configuration files and run files
# =========================================================================================

PLAN_SVG = _svg('<rect x="0" y="0" width="40" height="30"/><line x1="10" y1="0" x2="10" y2="20"/>')
"""A 4 m × 3 m room and a wall, in decimetres (``--scale 0.1``)."""


@pytest.fixture
def inputs(tmp_path, monkeypatch):
    """A plan, a survey and its estimates in a folder of their own, the working folder."""
    (tmp_path / "plan.svg").write_text(PLAN_SVG)
    (tmp_path / "other.svg").write_text(PLAN_SVG.replace('width="40"', 'width="50"'))
    _write_survey(tmp_path / "survey.csv", [(1, 1.0, 0.0, 0.0, 0.0), (2, 2.0, 1.0, 1.0, 10.0)])
    _write_estimates(tmp_path / "est.csv", [_row(1, 1.0, -0.01), _row(2, 2.0, 0.98)])
    monkeypatch.chdir(tmp_path)
    return tmp_path


EVALUATE = ["evaluate", "est.csv", "--survey", "survey.csv"]
IMPORT = ["map", "import", "plan.svg", "--out", "m.json", "--scale", "0.1"]
LOCALIZE = ["localize", str(HALL / "log.mcap"), "--map", str(HALL / "map.json"), "--out", "e.csv"]

# name → (command, TOML text, phrases of the refusal)
CONFIG_REFUSALS: dict[str, tuple[list[str], str, tuple[str, ...]]] = {
    "unknown key": (
        EVALUATE,
        "[evaluate]\nonly_ok = true\n",
        ("unknown key 'only_ok'", "did you mean 'only-ok'?"),
    ),
    "unknown key of another command": (
        EVALUATE,
        "[evaluate]\ngrid-m = 1.0\n",
        ("unknown key 'grid-m' in [evaluate]",),
    ),
    "text for a number": (
        EVALUATE,
        '[evaluate]\ntolerance-ms = "50"\n',
        ("key 'tolerance-ms' takes a number, not the text '50'",),
    ),
    "text for a count": (
        LOCALIZE,
        '[localize]\niterations = "6"\n',
        ("key 'iterations' takes a number, not the text '6'",),
    ),
    "text for the SVG scale": (
        [*IMPORT[:3], "--out", "m.json"],
        '[map.import]\nscale = "0.1"\n',
        ("key 'scale' takes a number",),
    ),
    "number for text": (
        IMPORT,
        "[map.import]\norigin = 5\n",
        ("key 'origin' takes text in quotes, not 5",),
    ),
    "number for a path": (
        LOCALIZE,
        "[localize]\ninitial = 5\n",
        ("key 'initial' takes a path in quotes, not 5",),
    ),
    "list for a flag": (
        EVALUATE,
        "[evaluate]\nonly-ok = [true]\n",
        ("key 'only-ok' is a flag: give true or false",),
    ),
    "text for a flag": (EVALUATE, '[evaluate]\nonly-ok = "true"\n', ("key 'only-ok' is a flag",)),
    "number for a flag": (EVALUATE, "[evaluate]\nonly-ok = 1\n", ("key 'only-ok' is a flag",)),
    "flag for a number": (
        EVALUATE,
        "[evaluate]\ntolerance-ms = true\n",
        ("key 'tolerance-ms' takes a value, not true",),
    ),
    "table for a number": (
        EVALUATE,
        "[evaluate]\ntolerance-ms = {ms = 50}\n",
        ("key 'tolerance-ms' takes one value, not a dict",),
    ),
    "list for a number": (
        LOCALIZE,
        "[localize]\ngrid-m = [1.0, 2.0]\n",
        ("key 'grid-m' takes one value, not a list",),
    ),
    "date for a number": (
        EVALUATE,
        "[evaluate]\ntolerance-ms = 1979-05-27\n",
        ("key 'tolerance-ms'",),
    ),
    "fraction for a count": (
        LOCALIZE,
        "[localize]\niterations = 6.5\n",
        ("key 'iterations' takes a whole number",),
    ),
    "count out of range": (
        LOCALIZE,
        "[localize]\niterations = 0\n",
        ("key 'iterations'", "0 is not in the range"),
    ),
    "count beyond int64": (
        LOCALIZE,
        "[localize]\niterations = 99999999999999999999\n",
        ("key 'iterations'",),
    ),
    "negative tolerance": (
        EVALUATE,
        "[evaluate]\ntolerance-ms = -1\n",
        ("key 'tolerance-ms'", "-1"),
    ),
    "ratio above 1": (LOCALIZE, "[localize]\nratio = 1.5\n", ("key 'ratio'", "1.5")),
    "NaN": (LOCALIZE, "[localize]\ngrid-m = nan\n", ("key 'grid-m'", "not a finite number")),
    "infinity": (EVALUATE, "[evaluate]\ntolerance-ms = inf\n", ("key 'tolerance-ms'",)),
    "tuning setting out of bounds": (
        LOCALIZE,
        "[localize]\nsearch-cell-m = -0.05\n",
        ("key 'search-cell-m'",),
    ),
    "unknown choice": (
        LOCALIZE,
        '[localize]\nvote = "median"\n',
        ("key 'vote'", "'median' is not one of"),
    ),
    "number for a choice": (
        LOCALIZE,
        "[localize]\nvote = 1\n",
        ("key 'vote'", "'1' is not one of"),
    ),
    "force in a file": (
        EVALUATE,
        "[evaluate]\nforce = true\n",
        ("key 'force' is not read from a file; give --force",),
    ),
    "misspelt table": (
        EVALUATE,
        "[evaluation]\nonly-ok = true\n",
        ("table [evaluation] names no segloc command",),
    ),
    "key outside a table": (EVALUATE, "only-ok = true\n", ("key 'only-ok' is outside any table",)),
    "not TOML": (EVALUATE, "[evaluate\n", ("is not valid TOML",)),
    "over 1 MiB": (EVALUATE, "[evaluate]\n" + "#" * (1 << 20) + "\n", ("is over 1,048,576 bytes",)),
    "run file of another command": (
        EVALUATE,
        f'[map.import]\nscale = 0.1\n[run]\nsegloc = "{__version__}"\n'
        'command = "segloc map import"\n',
        ("is the run file of `segloc map import`, not of `segloc evaluate`",),
    ),
    "run file of evaluate given to localize": (
        LOCALIZE,
        f'[evaluate]\nonly-ok = true\n[run]\nsegloc = "{__version__}"\n'
        'command = "segloc evaluate"\n',
        ("is the run file of `segloc evaluate`, not of `segloc localize`",),
    ),
}


@pytest.mark.parametrize("case", sorted(CONFIG_REFUSALS))
def test_config_refusal(case, inputs, capsys):
    command, text, fragments = CONFIG_REFUSALS[case]
    (inputs / "c.toml").write_text(text, encoding="utf-8")
    result = run_cli(capsys, *command, "--config", "c.toml")
    refused(result, Path("c.toml"), *fragments)
    assert not (inputs / "m.json").exists() and not (inputs / "e.csv").exists()


def test_a_run_file_repeats_an_import_and_says_when_the_plan_differs(inputs, capsys):
    assert run_cli(capsys, *IMPORT).code == 0
    again = ["map", "import", "plan.svg", "--config", "m.run.toml", "--out", "again.json"]
    result = run_cli(capsys, *again)
    assert result.code == 0 and "warning" not in result.err, result.err
    assert np.array_equal(read_map(inputs / "again.json"), read_map(inputs / "m.json"))
    other = ["map", "import", "other.svg", "--config", "m.run.toml", "--out", "other.json"]
    result = run_cli(capsys, *other)
    assert result.code == 0
    assert (
        "segloc: warning: other.svg is not the PLAN.dxf|PLAN.svg|GRID.yaml that m.run.toml "
        "records (its sha256 differs): this run does not repeat that one" in result.err
    )
    (inputs / "plan.svg").write_text(PLAN_SVG.replace('height="30"', 'height="35"'))
    result = run_cli(
        capsys, "map", "import", "plan.svg", "--config", "m.run.toml", "--out", "c.json"
    )
    assert result.code == 0 and "plan.svg is not the PLAN" in result.err


def test_a_run_file_naming_a_missing_survey_is_one_line(inputs, capsys):
    assert run_cli(capsys, *EVALUATE, "--out", "t.md").code == 0
    (inputs / "runs").mkdir()
    (inputs / "t.run.toml").rename(inputs / "runs" / "t.run.toml")
    result = run_cli(capsys, "evaluate", "est.csv", "--config", "runs/t.run.toml")
    refused(result, Path("runs/survey.csv"), "file not found; check the path")


def test_a_run_file_naming_a_missing_map_is_one_line(inputs, capsys):
    (inputs / "old.run.toml").write_text(
        f'[localize]\nmap = "gone.json"\n[run]\nsegloc = "{__version__}"\n'
        'command = "segloc localize"\n'
    )
    args = ["localize", HALL / "log.mcap", "--config", "old.run.toml", "--out", "e.csv"]
    refused(run_cli(capsys, *args), Path("gone.json"), "file not found")
    assert not (inputs / "e.csv").exists()


def test_the_run_file_of_an_evaluation_with_figures_repeats_its_table(inputs, capsys):
    """Its run file holds --map and --log but not --plots (an output): given back, the figures'
    inputs are left unread, with a warning, rather than refused as a misuse."""
    (inputs / "t.run.toml").write_text(
        '[evaluate]\nsurvey = "survey.csv"\nmap = "gone.json"\nlog = "gone.mcap"\n'
        f'[run]\nsegloc = "{__version__}"\ncommand = "segloc evaluate"\n'
    )
    result = run_cli(capsys, "evaluate", "est.csv", "--config", "t.run.toml", "--format", "json")
    assert result.code == 0, result.err
    assert json.loads(result.out)["summary"]["n_scored"] == 2
    assert (
        "--config sets --map, which serves the figures alone (--plots, --html): not read"
        in result.err
    )
    result = run_cli(capsys, *EVALUATE, "--map", "gone.json")
    assert_one_line_error(result, "--map and --log go with --plots")


def test_a_rerun_from_a_run_file_writes_no_view_it_was_not_asked_for(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    log, world = HALL / "log.mcap", HALL / "map.json"
    first = ["localize", log, "--map", world, "--out", "est.csv", "--mcap", "run.mcap"]
    assert run_cli(capsys, *first).code == 0
    text = (tmp_path / "est.run.toml").read_text()
    assert "mcap =" not in text and "run.mcap" not in text
    view = (tmp_path / "run.mcap").stat()
    again = ["localize", log, "--config", "est.run.toml", "--out", "est.csv", "--force"]
    result = run_cli(capsys, *again)
    assert result.code == 0 and "warning" not in result.err, result.err
    assert (tmp_path / "run.mcap").stat().st_mtime_ns == view.st_mtime_ns


def test_an_empty_configuration_sets_nothing_and_says_so(inputs, capsys):
    (inputs / "c.toml").write_text("")
    result = run_cli(capsys, *EVALUATE, "--config", "c.toml", "--format", "json")
    assert result.code == 0
    assert "c.toml has no [evaluate] table; nothing was set from it" in result.err


# =========================================================================================
# 3. The inputs of evaluate
# =========================================================================================


def _row(pose_id: int, time_s: float, x_m: float | str, y_m: float | str = "",
         theta_deg: float | str = "", status: str = "ok", **columns) -> dict:  # fmt: skip
    row = dict.fromkeys(ESTIMATE_HEADER.split(","), "")
    row |= {"pose_id": pose_id, "time_s": time_s, "x_m": x_m, "n_local_segments": 5}
    row |= {"runtime_ms": 1.0, "status": status, "window_scans": 1, "confidence": 0.95}
    row["y_m"] = 0.0 if y_m == "" and x_m != "" else y_m
    row["theta_deg"] = 0.0 if theta_deg == "" and x_m != "" else theta_deg
    return row | columns


def _write_estimates(path: Path, rows: list[dict], header: str = ESTIMATE_HEADER) -> None:
    names = header.split(",")
    lines = [header] + [",".join(str(row.get(n, "")) for n in names) for row in rows]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _write_survey(path: Path, rows: list[tuple]) -> None:
    lines = [SURVEY_HEADER] + [",".join(map(str, row)) for row in rows]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


TWO_POSES = [(1, 1.0, 0.0, 0.0, 0.0), (2, 2.0, 1.0, 1.0, 10.0)]
NO_POSE = {"x_m": "", "y_m": "", "theta_deg": "", "status": "too_few_segments"}

# name → (estimate rows, survey rows, extra options, then: the file refused ("est" or
# "survey") and its phrase, or None and a check of the JSON summary)
EVALUATE_CASES: dict[str, tuple] = {
    "header and no rows": ([], TWO_POSES, [], ("est", "has a header but no rows")),
    "header and no rows, relations": (
        [],
        TWO_POSES,
        ["--relations", "rel.txt"],
        ("est", "has a header but no rows"),
    ),
    "all NaN poses": (
        [_row(1, 1.0, **NO_POSE), _row(2, 2.0, **NO_POSE)],
        TWO_POSES,
        [],
        (None, {"n_scored": 0, "n_no_estimate": 2, "status_counts": {"too_few_segments": 2}}),
    ),
    "one pose NaN": (
        [_row(1, 1.0, 0.02), _row(2, 2.0, **NO_POSE)],
        TWO_POSES,
        [],
        (None, {"n_scored": 1, "n_no_estimate": 1, "n_failed": 1}),
    ),
    "empty statuses": (
        [_row(1, 1.0, 0.0, status=""), _row(2, 2.0, 1.0, 1.0, 10.0, status="")],
        TWO_POSES,
        [],
        (None, {"n_scored": 2, "status_counts": {"missing": 2}}),
    ),
    "duplicate survey pose ids": (
        [_row(1, 1.0, 0.0)],
        [(1, 1.0, 0, 0, 0), (1, 2.0, 0, 0, 0)],
        [],
        ("survey", "row 2: pose_id 1 repeats row 1; pose ids must be unique"),
    ),
    "duplicate survey times": (
        [_row(1, 1.0, 0.0)],
        [(1, 1.0, 0, 0, 0), (2, 1.0, 0, 0, 0)],
        [],
        ("survey", "rows 1 and 2: both have time 1.000 s"),
    ),
    "duplicate estimate times": (
        [_row(1, 1.0, 0.0), _row(2, 1.0, 0.5)],
        TWO_POSES,
        [],
        ("est", "rows 1 and 2: both have time 1.000 s, so a row at 1.000 s matches more than one"),
    ),
    "the same estimate row twice": (
        [_row(1, 1.0, 0.0), _row(1, 1.0, 0.0), _row(2, 2.0, 1.0)],
        TWO_POSES,
        [],
        ("est", "rows 1 and 2: both have time 1.000 s"),
    ),
    "no estimate time near a survey time": (
        [_row(1, 101.0, 0.0), _row(2, 102.0, 1.0)],
        TWO_POSES,
        [],
        (
            "survey",
            "no estimate lies within 0.05 s of any survey time",
            "are they of the same log?",
        ),
    ),
    "times 60 ms apart": (
        [_row(1, 1.06, 0.0), _row(2, 2.06, 1.0)],
        TWO_POSES,
        [],
        ("survey", "no estimate lies within 0.05 s"),
    ),
    "times 40 ms apart": (
        [_row(1, 1.04, 0.0), _row(2, 2.04, 1.0, 1.0, 10.0)],
        TWO_POSES,
        [],
        (None, {"n_scored": 2, "n_no_estimate": 0}),
    ),
    "one survey time unmatched": (
        [_row(1, 1.0, 0.0)],
        TWO_POSES,
        [],
        (None, {"n_surveyed": 2, "n_scored": 1, "n_no_estimate": 1}),
    ),
    "a survey of one row": (
        [_row(1, 1.0, -0.03), _row(2, 2.0, 1.0)],
        [(7, 1.0, 0.0, 0.0, 0.0)],
        [],
        (None, {"n_surveyed": 1, "n_scored": 1, "max": {"err_x_cm": 3.0}}),
    ),
    "a survey with no rows": ([_row(1, 1.0, 0.0)], [], [], ("survey", "table has no data rows")),
    "a position beyond 10^7 m": (
        [_row(1, 1.0, 1e300)],
        TWO_POSES,
        [],
        ("est", "row 1: column x_m is 1e+300, beyond ±1e+07 m"),
    ),
    "a runner-up beyond 10^7 m": (
        [_row(1, 1.0, 0.0, runner_up_y_m=-2e7)],
        TWO_POSES,
        [],
        ("est", "column runner_up_y_m is -2e+07"),
    ),
    "an infinite position": (
        [_row(1, 1.0, "inf")],
        TWO_POSES,
        [],
        ("est", "column x_m is 'inf'; expected a finite number"),
    ),
    "a NaN time": ([_row(1, "nan", 0.0)], TWO_POSES, [], ("est", "row 1: column time_s is 'nan'")),
    "an empty time": ([_row(1, "", 0.0)], TWO_POSES, [], ("est", "row 1: column time_s is empty")),
}


@pytest.mark.parametrize("case", sorted(EVALUATE_CASES))
def test_evaluate(case, tmp_path, capsys):
    rows, survey_rows, options, (refused_file, expected, *more) = EVALUATE_CASES[case]
    est, survey = tmp_path / "est.csv", tmp_path / "survey.csv"
    _write_estimates(est, rows)
    _write_survey(survey, survey_rows)
    (tmp_path / "rel.txt").write_text("1.0 2.0 1 1 0 0 0 0.1\n")
    options = [str(tmp_path / o) if o == "rel.txt" else o for o in options]
    if "--relations" not in options:
        options = ["--survey", survey, *options]
    result = run_cli(capsys, "evaluate", est, *options, "--format", "json")
    if refused_file is None:
        assert result.code == 0, result.err
        # Nothing on stderr but how the estimates were paired.
        assert [line for line in result.err.splitlines() if " paired within " not in line] == []
        summary = json.loads(result.out)["summary"]
        for key, value in expected.items():
            if isinstance(value, dict) and key in ("max", "RMS"):
                for column, number in value.items():
                    assert summary[key][column] == pytest.approx(number)
            else:
                assert summary[key] == value, (key, summary[key])
    else:
        refused(result, est if refused_file == "est" else survey, expected, *more)
        assert result.out == ""


@pytest.mark.parametrize("fmt", ["md", "csv", "latex"])
def test_poses_without_estimates_print_in_every_format(fmt, tmp_path, capsys):
    _write_estimates(tmp_path / "est.csv", [_row(1, 1.0, **NO_POSE), _row(2, 2.0, **NO_POSE)])
    _write_survey(tmp_path / "survey.csv", TWO_POSES)
    args = ["evaluate", tmp_path / "est.csv", "--survey", tmp_path / "survey.csv"]
    result = run_cli(capsys, *args, "--format", fmt)
    assert (
        result.code == 0
        and [line for line in result.err.splitlines() if "paired" not in line] == []
    )
    assert result.out.count("few") == 2 + (fmt != "csv")  # and once in the counts
    gated = run_cli(capsys, *args, "--fail-above-cm", "5")
    assert gated.code == 1
    assert gated.err.splitlines()[-1:] == [
        "segloc: gate: pose 1: status too_few_segments; pose 2: status too_few_segments"
    ]


def test_estimates_of_an_earlier_version_and_with_a_byte_order_mark_are_read(tmp_path, capsys):
    older = ESTIMATE_HEADER.removesuffix(",confidence,status,window_scans") + ",status"
    _write_estimates(tmp_path / "est.csv", [_row(1, 1.0, 0.0), _row(2, 2.0, 1.0, 1.0, 10.0)], older)
    text = (tmp_path / "est.csv").read_text()
    (tmp_path / "est.csv").write_text("\ufeff" + text, encoding="utf-8")
    _write_survey(tmp_path / "survey.csv", TWO_POSES)
    args = [
        "evaluate",
        tmp_path / "est.csv",
        "--survey",
        tmp_path / "survey.csv",
        "--format",
        "json",
    ]
    result = run_cli(capsys, *args)
    assert result.code == 0, result.err
    assert json.loads(result.out)["summary"]["n_scored"] == 2


def test_a_survey_of_one_tum_line_is_scored(tmp_path, capsys):
    _write_estimates(tmp_path / "est.csv", [_row(1, 1.0, 0.5)])
    (tmp_path / "survey.tum").write_text("1.0 0.5 0.0 0.0 0.0 0.0 0.0 1.0\n")
    args = [
        "evaluate",
        tmp_path / "est.csv",
        "--survey",
        tmp_path / "survey.tum",
        "--format",
        "json",
    ]
    result = run_cli(capsys, *args)
    assert result.code == 0, result.err
    summary = json.loads(result.out)["summary"]
    assert summary["n_scored"] == 1 and summary["max"]["err_x_cm"] == pytest.approx(0.0)


def test_an_estimates_folder_is_one_line(tmp_path, capsys):
    (tmp_path / "est.csv").mkdir()
    _write_survey(tmp_path / "survey.csv", TWO_POSES)
    result = run_cli(capsys, "evaluate", tmp_path / "est.csv", "--survey", tmp_path / "survey.csv")
    refused(result, tmp_path / "est.csv", "is a folder without metadata.yaml, not a ROS 2 bag")
