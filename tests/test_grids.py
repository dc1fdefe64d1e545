"""nav2 occupancy grids as maps: pixels classified as map_server classifies them, cells
placed by origin (yaw too) and resolution, walls traced out of hand-made masks exactly,
maps exported and imported back within a cell, bad grids refused in one line, and scans
of a lab localized on the map that went through a 5 cm grid."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image
from test_cli import assert_one_line_error, run_cli
from test_plans import localization_errors, same_segments

from segloc_cli.errors import InputError
from segloc_cli.geometry import Pose2, point_segment_distances, transform_segments
from segloc_cli.io import grids
from segloc_cli.io.grids import occupied_cells, read_header, read_nav2, write_nav2
from segloc_cli.io.maps import read_map, write_map
from segloc_cli.maps.wall_tracing import _ring_order, line_cells, trace_walls
from segloc_cli.world import World

# A small lab, measured in whole centimetres (not on the 5 cm lattice): outer walls with a
# chamfered corner, a corridor wall with two doors, three rooms, a slanted partition and a
# bench, and two columns drawn as outlines.
LAB_M = np.array(
    [
        [0.00, 0.00, 12.46, 0.00],
        [12.46, 0.00, 12.46, 7.12],
        [12.46, 7.12, 10.65, 8.93],
        [10.65, 8.93, 0.00, 8.93],
        [0.00, 8.93, 0.00, 0.00],
        [0.00, 5.37, 3.18, 5.37],
        [4.07, 5.37, 8.81, 5.37],
        [9.73, 5.37, 12.46, 5.37],
        [3.62, 5.37, 3.62, 8.93],
        [7.94, 5.37, 7.94, 8.93],
        [5.83, 0.00, 5.83, 2.41],
        [5.83, 3.33, 5.83, 5.37],
        [8.21, 0.97, 10.38, 3.46],
        [1.12, 1.64, 2.87, 1.64],
        [2.12, 2.56, 2.47, 2.56],
        [2.47, 2.56, 2.47, 2.91],
        [2.47, 2.91, 2.12, 2.91],
        [2.12, 2.91, 2.12, 2.56],
        [10.21, 6.48, 10.56, 6.48],
        [10.56, 6.48, 10.56, 6.83],
        [10.56, 6.83, 10.21, 6.83],
        [10.21, 6.83, 10.21, 6.48],
    ]
)
LAB_AT = Pose2(3.27, -1.84, 0.0)
"""Where the lab stands in the world: off the lattice of any grid written."""


def lab(theta_rad: float = 0.0) -> np.ndarray:
    """The lab's walls in the world, turned by ``theta_rad`` about the world's origin."""
    return transform_segments(LAB_M, Pose2(LAB_AT.x, LAB_AT.y, theta_rad))


def endpoint_offsets_m(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of each endpoint of segments ``a`` (M, 4) from the nearest segment of ``b``."""
    return point_segment_distances(a.reshape(-1, 2), b).min(axis=1)


def write_grid(folder, pixels, name="grid", **header) -> object:
    """A nav2 map from a grey (or RGB/RGBA) pixel array, its YAML keys defaulting sensibly."""
    image = folder / f"{name}.png"
    Image.fromarray(np.asarray(pixels, dtype=np.uint8)).save(image)
    document = {
        "image": image.name,
        "resolution": 0.1,
        "origin": [0.0, 0.0, 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
    }
    document.update(header)
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


# --- pixels as map_server reads them ---------------------------------------------------------


def test_pixels_are_occupied_by_map_server_s_thresholds(tmp_path):
    # p = 1 - v/255: 89 → 0.651 (occupied, > 0.65), 90 → 0.647 (not).
    values = np.array([[0, 89, 90, 165, 166, 205, 254, 255]])
    path = write_grid(tmp_path, values)
    occupied = occupied_cells(read_header(path), path)
    assert occupied.tolist() == [[True, True, False, False, False, False, False, False]]
    # negate: p = v/255: 166 → 0.651 (occupied), 165 → 0.647 (not).
    path = write_grid(tmp_path, values, negate=1)
    occupied = occupied_cells(read_header(path), path)
    assert occupied.tolist() == [[False, False, False, False, True, True, True, True]]
    # scale mode occupies what trinary does; raw takes the value as percent: only 100.
    path = write_grid(tmp_path, values, mode="Scale")
    assert occupied_cells(read_header(path), path)[0, :3].tolist() == [True, True, False]
    path = write_grid(tmp_path, [[99, 100, 101, 0, 255]], mode="raw", negate=1)
    assert occupied_cells(read_header(path), path).tolist() == [[False, True, False] + [False] * 2]


def test_colour_and_transparency_count_as_map_server_counts_them(tmp_path):
    # The mean of R, G, B: (0, 0, 255) → 85 → p = 0.667, occupied; (0, 255, 255) → 170, not.
    rgb = [[[0, 0, 255], [0, 255, 255], [0, 0, 0]]]
    path = write_grid(tmp_path, rgb)
    assert occupied_cells(read_header(path), path).tolist() == [[True, False, True]]
    # A black pixel not fully opaque is unknown, never occupied.
    rgba = [[[0, 0, 0, 255], [0, 0, 0, 254], [0, 0, 0, 0], [255, 255, 255, 255]]]
    path = write_grid(tmp_path, rgba)
    assert occupied_cells(read_header(path), path).tolist() == [[True, False, False, False]]


def test_a_wall_of_cells_lands_where_origin_and_resolution_put_it(tmp_path):
    """A row of occupied cells (image row 2 of 10, columns 3 to 12) is one segment through
    their centres, turned by the origin's yaw about the origin."""
    pixels = np.full((10, 16), 254)
    pixels[2, 3:13] = 0
    x0, y0, yaw, res = 1.5, -2.0, 0.5, 0.04
    path = write_grid(tmp_path, pixels, resolution=res, origin=[x0, y0, yaw])
    plan = read_nav2(path)
    # Centres of cells (3, 7) and (12, 7), counting rows from the bottom.
    ends = np.array([[3.5, 7.5], [12.5, 7.5]]) * res
    turn = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    expected = (ends @ turn.T + [x0, y0]).reshape(4)
    assert plan.segments.shape == (1, 4)
    got = plan.segments[0]
    assert np.allclose(got, expected, atol=1e-12) or np.allclose(
        got[[2, 3, 0, 1]], expected, atol=1e-12
    )
    assert plan.source == {
        "format": "nav2",
        "plan": str(path),
        "image": str(tmp_path / "grid.png"),
        "mode": "trinary",
        "resolution_m": res,
        "origin": [x0, y0, yaw],
        "negate": False,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
        "cells": [16, 10],
        "occupied_cells": 10,
        "split_m": res,
        "min_length_m": 0.25,
    }


# --- tracing ---------------------------------------------------------------------------------


def test_a_solid_block_is_its_four_faces_through_the_outer_cells():
    mask = np.zeros((12, 14), dtype=bool)
    mask[2:9, 3:12] = True  # rows 2..8, columns 3..11
    centres = np.array([3.5, 2.5, 11.5, 8.5]) * 0.1  # x0, y0, x1, y1 of the outer cells
    x0, y0, x1, y1 = centres
    faces = np.array([[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]])
    assert same_segments(trace_walls(mask, 0.1), faces)


def test_a_thin_wall_is_one_segment_and_a_thick_one_two_faces():
    mask = np.zeros((20, 40), dtype=bool)
    mask[3, 2:30] = True  # one cell thick
    mask[10:13, 5:35] = True  # three cells thick
    walls = trace_walls(mask, 0.05)
    # The thick wall's ends (0.10 m between their outer cells' centres) are too short.
    expected = np.array([[2.5, 3.5, 29.5, 3.5], [5.5, 10.5, 34.5, 10.5], [5.5, 12.5, 34.5, 12.5]])
    assert same_segments(walls, expected * 0.05)


def test_cells_touching_at_corners_make_one_diagonal_wall():
    mask = np.zeros((30, 30), dtype=bool)
    idx = np.arange(2, 27)
    mask[idx, idx] = True
    (wall,) = trace_walls(mask, 0.1)
    ends = sorted([tuple(wall[:2]), tuple(wall[2:])])
    assert np.allclose(ends, [(0.25, 0.25), (2.65, 2.65)], atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(1, 40), min_size=1, max_size=12), st.integers(0, 2**32 - 1))
def test_rings_are_listed_whole_and_in_order(sizes, seed):
    """Any permutation made of cycles comes out cycle by cycle, each from its least member
    and following the links: what a walk along each would give."""
    rng = np.random.default_rng(seed)
    members = rng.permutation(sum(sizes))
    successor = np.empty(members.size, dtype=np.int64)
    start = 0
    for size in sizes:
        cycle = members[start : start + size]
        successor[cycle] = np.roll(cycle, -1)
        start += size
    walked = []
    seen = np.zeros(members.size, dtype=bool)
    for first in range(members.size):
        node = first
        while not seen[node]:
            seen[node] = True
            walked.append(node)
            node = successor[node]
    assert _ring_order(successor).tolist() == walked


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_drawn_cells_follow_the_segment_one_step_at_a_time(seed):
    rng = np.random.default_rng(seed)
    res = 0.05
    for segment in rng.uniform(-3.0, 3.0, (10, 4)):
        column, row = line_cells(segment[None], res)
        cells = np.column_stack([column, row])
        major = int(np.abs(segment[2:] - segment[:2]).argmax())
        assert cells[0, major] == np.floor(segment[major] / res)
        assert cells[-1, major] == np.floor(segment[2 + major] / res)
        steps = np.abs(np.diff(cells, axis=0))
        assert np.all(steps[:, major] == 1) and np.all(steps[:, 1 - major] <= 1)
        # Inner cells' centres lie within half a cell of the segment, the ends' within the
        # half-diagonal of the cells holding the segment's ends.
        centres = (cells + 0.5) * res
        offsets = point_segment_distances(centres, segment[None])[:, 0]
        assert offsets[1:-1].max(initial=0) <= 0.5 * res + 1e-12
        assert offsets.max() <= res * np.sqrt(0.5) + 1e-12


# --- export and import -----------------------------------------------------------------------


def test_an_exported_grid_says_walls_free_and_unknown(tmp_path):
    walls = lab()
    written = write_nav2(tmp_path / "lab.yaml", walls, 0.05)
    header = yaml.safe_load((tmp_path / "lab.yaml").read_text())
    assert header["image"] == "lab.pgm" and header["mode"] == "trinary"
    assert header["resolution"] == 0.05 and header["negate"] == 0
    assert (header["occupied_thresh"], header["free_thresh"]) == (0.65, 0.196)
    pixels = np.asarray(Image.open(tmp_path / "lab.pgm"))
    assert pixels.shape == written.shape[::-1]
    assert set(np.unique(pixels).tolist()) == {0, 205, 254}
    margin = grids.MARGIN_CELLS
    assert np.all(pixels[:margin] == 205) and np.all(pixels[:, -margin:] == 205)
    inside = pixels[margin:-margin, margin:-margin]
    assert not np.any(inside == 205)
    # map_server reads back exactly the cells drawn.
    occupied = occupied_cells(read_header(tmp_path / "lab.yaml"), tmp_path / "lab.yaml")
    assert np.array_equal(occupied, pixels == 0)
    assert written.occupied_cells == int(np.count_nonzero(pixels == 0))


@pytest.mark.parametrize(
    "theta_deg,resolution_m",
    [(0.0, 0.05), (17.0, 0.05), (-33.0, 0.05), (45.0, 0.05), (0.0, 0.02), (45.0, 0.1)],
)
def test_a_map_through_a_grid_moves_no_wall_by_a_cell(theta_deg, resolution_m, tmp_path):
    """Export then import: every endpoint read back lies within one cell of a wall drawn,
    and every endpoint drawn within one cell of a wall read back; square to the grid, the
    walls come back one for one. In 10 cm cells the columns, 3.5 cells across, lose faces
    shorter than a segment may be (0.25 m): there only the walls are held to it."""
    walls = lab(np.deg2rad(theta_deg))
    write_nav2(tmp_path / "lab.yaml", walls, resolution_m)
    back = read_nav2(tmp_path / "lab.yaml").segments
    held = walls if resolution_m < 0.1 else walls[:14]
    read_off = endpoint_offsets_m(back, walls).max()
    drawn_off = endpoint_offsets_m(held, back).max()
    assert read_off < resolution_m and drawn_off < resolution_m, (read_off, drawn_off)
    if theta_deg == 0.0:
        assert len(back) == len(walls)


def test_walls_on_the_lattice_of_the_plan_come_back_to_the_micrometre(tmp_path):
    """The lab is measured in centimetres: in a grid of 1 cm cells whose centres the export
    puts on that lattice, every wall along the axes comes back where it was drawn."""
    walls = lab()
    write_nav2(tmp_path / "lab.yaml", walls, 0.01)
    back = read_nav2(tmp_path / "lab.yaml").segments
    square = np.any(np.isclose(walls[:, :2], walls[:, 2:]), axis=1)
    assert len(back) == len(walls)
    assert endpoint_offsets_m(walls[square], back).max() < 1e-6


def test_scans_of_the_lab_localize_on_its_map_read_back_from_a_5cm_grid(tmp_path, capsys):
    """The acceptance check: the lab exported as a nav2 grid of 5 cm cells and imported
    back; scans simulated in the lab as drawn localize on the imported map within 3 cm and
    0.5° from guesses up to 1 m and 15° off, the lab square to the grid and turned 17°."""
    for theta_deg in (0.0, 17.0):
        walls = lab(np.deg2rad(theta_deg))
        write_map(tmp_path / "lab.json", walls)
        exported = run_cli(
            capsys, "map", "export", tmp_path / "lab.json", "--out", tmp_path / "lab.yaml",
            "--force",
        )  # fmt: skip
        assert exported.code == 0, exported.err
        imported = run_cli(
            capsys, "map", "import", tmp_path / "lab.yaml", "--out", tmp_path / "back.json",
            "--force",
        )  # fmt: skip
        assert imported.code == 0, imported.err
        built = World(walls, name="lab")
        off_m, off_deg = localization_errors(built, read_map(tmp_path / "back.json"), 25, 29)
        assert off_m.max() < 0.03 and off_deg.max() < 0.5, (theta_deg, off_m, off_deg)


def test_the_run_file_of_an_import_names_the_grid_s_image_too(tmp_path, capsys):
    import tomllib

    from segloc_cli.io.files import sha256

    write_map(tmp_path / "lab.json", lab(0.0))
    assert (
        run_cli(capsys, "map", "export", tmp_path / "lab.json", "--out", tmp_path / "lab.yaml").code
        == 0
    )
    assert (
        run_cli(
            capsys, "map", "import", tmp_path / "lab.yaml", "--out", tmp_path / "back.json"
        ).code
        == 0
    )
    run = tomllib.loads((tmp_path / "back.run.toml").read_text(encoding="utf-8"))["run"]
    recorded = {i["role"]: (i["path"], i["sha256"]) for i in run["inputs"]}
    assert recorded["image"] == ("lab.pgm", sha256(tmp_path / "lab.pgm"))
    assert recorded["PLAN.dxf|PLAN.svg|GRID.yaml"][0] == "lab.yaml"


def test_export_writes_nothing_over_what_exists(tmp_path, capsys):
    write_map(tmp_path / "lab.json", lab())
    (tmp_path / "lab.pgm").write_text("kept")
    args = ["map", "export", tmp_path / "lab.json", "--out", tmp_path / "lab.yaml"]
    result = run_cli(capsys, *args)
    assert_one_line_error(result, "lab.pgm", "file exists")
    assert not (tmp_path / "lab.yaml").exists() and (tmp_path / "lab.pgm").read_text() == "kept"
    assert run_cli(capsys, *args, "--force").code == 0
    result = run_cli(capsys, *args[:-1], tmp_path / "fine.yaml", "--resolution", "0.00001")
    assert_one_line_error(result, "fine.yaml", "choose a coarser --resolution")
    assert not (tmp_path / "fine.yaml").exists() and not (tmp_path / "fine.pgm").exists()
    result = run_cli(capsys, *args[:-1], tmp_path / "x.dxf", "--resolution", "0.1")
    assert_one_line_error(result, "--resolution", "applies to nav2 grids only")


@pytest.mark.parametrize("old", [True, False], ids=["over-a-pair", "new"])
@pytest.mark.parametrize(
    ("fails", "named"),
    [("write lab.yaml", "lab.yaml"), ("rename lab.pgm", "lab.pgm"),
     ("rename lab.yaml", "lab.yaml")],
)  # fmt: skip
def test_an_export_replaces_image_and_yaml_together_or_not_at_all(
    old, fails, named, tmp_path, capsys, monkeypatch
):
    """Writing the YAML or renaming either file fails (a full disk, a rename refused): the
    old pair is left as it was (or, with none, no file), with no temporary file, and one line
    names the file that failed."""
    import os
    from pathlib import Path

    write_map(tmp_path / "lab.json", lab())
    args = ["map", "export", tmp_path / "lab.json", "--out", tmp_path / "lab.yaml", "--force"]
    if old:
        assert run_cli(capsys, *args, "--resolution", "0.1").code == 0
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    action, name = fails.split()
    full = OSError(28, os.strerror(28))
    if action == "write":
        real_write_text = Path.write_text

        def write_text(self, *a, **k):
            if self.name.startswith(f".{name}."):
                raise full
            return real_write_text(self, *a, **k)

        monkeypatch.setattr(Path, "write_text", write_text)
    else:
        real_replace = os.replace

        def replace(source, target):
            if Path(target).name == name and Path(source).name.endswith(".tmp"):
                raise PermissionError(13, os.strerror(13))
            return real_replace(source, target)

        monkeypatch.setattr(os, "replace", replace)
    result = run_cli(capsys, *args, "--resolution", "0.05")
    assert_one_line_error(result, str(tmp_path / named), "cannot write file")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    monkeypatch.undo()
    assert run_cli(capsys, *args, "--resolution", "0.05").code == 0
    assert read_header(tmp_path / "lab.yaml").resolution_m == 0.05


# --- bad grids -------------------------------------------------------------------------------

GOOD = {
    "image": "grid.png",
    "resolution": 0.05,
    "origin": [0.0, 0.0, 0.0],
    "negate": 0,
    "occupied_thresh": 0.65,
    "free_thresh": 0.196,
}

BAD_HEADERS = {
    "no-image-key": ({k: v for k, v in GOOD.items() if k != "image"}, "no `image` in this nav2"),
    "no-thresholds": (
        {k: v for k, v in GOOD.items() if "thresh" not in k},
        "no `occupied_thresh`, `free_thresh`",
    ),
    "empty-image": ({**GOOD, "image": ""}, "`image` must name the map's image"),
    "text-resolution": ({**GOOD, "resolution": "fine"}, "`resolution` must be a finite number"),
    "zero-resolution": ({**GOOD, "resolution": 0}, "`resolution` must be more than 0 m, got 0"),
    "short-origin": (
        {**GOOD, "origin": [1.0, 2.0]},
        "`origin` must be [x, y, yaw], got [1.0, 2.0]",
    ),
    "nan-origin": ({**GOOD, "origin": [0, ".nan", 0]}, "`origin` must be a finite number"),
    "occupied-above-1": ({**GOOD, "occupied_thresh": 1.5}, "`occupied_thresh` must lie in [0, 1]"),
    "free-below-0": ({**GOOD, "free_thresh": -0.1}, "`free_thresh` must lie in [0, 1], got -0.1"),
    "free-above-occupied": (
        {**GOOD, "free_thresh": 0.7},
        "`free_thresh` (0.7) must be below `occupied_thresh` (0.65)",
    ),
    "negate-2": ({**GOOD, "negate": 2}, "`negate` must be 0 or 1, got 2"),
    "unknown-mode": ({**GOOD, "mode": "fancy"}, "`mode` must be one of trinary, scale, raw"),
    "missing-image": ({**GOOD, "image": "gone.pgm"}, "gone.pgm is not there; check `image`"),
}


@pytest.mark.parametrize("case", sorted(BAD_HEADERS))
def test_bad_grid_yaml_is_one_line_naming_it(case, tmp_path, capsys):
    document, fragment = BAD_HEADERS[case]
    Image.fromarray(np.zeros((4, 4), dtype=np.uint8)).save(tmp_path / "grid.png")
    path = tmp_path / "grid.yaml"
    text = yaml.safe_dump(document).replace("'.nan'", ".nan")
    path.write_text(text)
    result = run_cli(capsys, "map", "import", path, "--out", tmp_path / "m.json")
    assert_one_line_error(result, f"{path}: ", fragment)
    assert not (tmp_path / "m.json").exists()


def test_bad_grid_files_are_one_line_naming_them(tmp_path, capsys):
    out = tmp_path / "m.json"
    broken = tmp_path / "broken.yaml"
    broken.write_text("image: grid.png\nresolution: [0.05\n")
    line = assert_one_line_error(run_cli(capsys, "map", "import", broken, "--out", out))
    assert f"{broken}: not valid YAML at line 3" in line
    listed = tmp_path / "list.yaml"
    listed.write_text("- image\n- grid.png\n")
    result = run_cli(capsys, "map", "import", listed, "--out", out)
    assert_one_line_error(result, f"{listed}: not a nav2 map YAML: expected the keys image")
    (tmp_path / "notes.pgm").write_text("not an image\n")
    notes = tmp_path / "notes.yaml"
    notes.write_text(yaml.safe_dump({**GOOD, "image": "notes.pgm"}))
    result = run_cli(capsys, "map", "import", notes, "--out", out)
    assert_one_line_error(
        result, "notes.pgm: not a readable PGM or PNG image", "named by notes.yaml"
    )
    blank = write_grid(tmp_path, np.full((20, 20), 254), name="blank")
    result = run_cli(capsys, "map", "import", blank, "--out", out)
    assert_one_line_error(result, f"{blank}: no occupied cells in blank.png (20 × 20 cells of 0.1")
    specks = np.full((20, 20), 254)
    specks[5, 5] = specks[9, 12] = 0
    sparse = write_grid(tmp_path, specks, name="sparse")
    result = run_cli(capsys, "map", "import", sparse, "--out", out)
    assert_one_line_error(result, "2 occupied cells in sparse.png", "make no wall of 0.25 m")
    assert not out.exists()


def test_an_image_larger_than_a_grid_may_be_is_refused_before_it_is_read(tmp_path, monkeypatch):
    path = write_grid(tmp_path, np.zeros((30, 40)))
    monkeypatch.setattr(grids, "MAX_GRID_CELLS", 1000)
    with pytest.raises(InputError, match=r"grid\.png: image is 40 × 30 pixels, more than 1,000"):
        read_nav2(path)
