"""Tests of the BOP results CSV (chpf.results) and the detections JSON (chpf.detections)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from chpf.bop import (
    ResultRow,
    ResultsAppender,
    read_detections,
    read_results_csv,
    write_detections,
    write_results_csv,
)
from chpf.errors import BopFormatError, DatasetError, ResultsFormatError
from chpf.results import HEADER


def _rows(n: int = 4) -> list[ResultRow]:
    rng = np.random.default_rng(1)
    rows = []
    for i in range(n):
        R, _ = cv2.Rodrigues(rng.normal(size=3))
        t = rng.uniform(-0.2, 0.2, 3) + np.array([0, 0, 1.0])
        rows.append(ResultRow(48, i + 1, 1 + i % 2, float(rng.random()), R, t, 0.01 * i))
    rows[-1].time = -1.0
    return rows


def test_round_trip_and_units(tmp_path: Path) -> None:
    rows = _rows()
    path = tmp_path / "res.csv"
    write_results_csv(path, rows)
    lines = path.read_text().splitlines()
    assert lines[0] == HEADER and len(lines) == 1 + len(rows)
    cols = lines[1].split(",")
    assert len(cols) == 7 and len(cols[4].split()) == 9
    np.testing.assert_allclose([float(v) for v in cols[5].split()], rows[0].t * 1000)  # mm on disk
    back = read_results_csv(path)
    assert len(back) == len(rows)
    for a, b in zip(back, rows, strict=True):
        assert a.key == b.key and a.score == b.score and a.time == b.time
        np.testing.assert_allclose(a.R, b.R, atol=1e-15)
        np.testing.assert_allclose(a.t, b.t, atol=1e-15)
    assert back[-1].time == -1.0


def test_reads_bop_toolkit_text(tmp_path: Path) -> None:
    path = tmp_path / "r.csv"
    path.write_text(
        "48,1,1,0.9,1 0 0 0 1 0 0 0 1,10.5 -20 800,0.05\n"  # no header is allowed
        "\n"
        "48,2,1,1,0 -1 0 1 0 0 0 0 1,0 0 1000,-1\n"
    )
    rows = read_results_csv(path)
    assert [r.key for r in rows] == [(48, 1, 1), (48, 2, 1)]
    np.testing.assert_allclose(rows[0].t, [0.0105, -0.02, 0.8])
    assert rows[1].time == -1


@pytest.mark.parametrize(
    ("line", "needle"),
    [
        ("48,1,1,0.9,1 0 0 0 1 0 0 0 1,0 0 800", "7 columns"),
        ("48,1,1,0.9,1 0 0 0 1 0 0 0 1,0 0 800,0.1,extra", "7 columns"),
        ("48,x,1,0.9,1 0 0 0 1 0 0 0 1,0 0 800,0.1", "im_id"),
        ("48,1,1,high,1 0 0 0 1 0 0 0 1,0 0 800,0.1", "score"),
        ("48,1,1,0.9,1 0 0 0 1 0 0 0,0 0 800,0.1", "9 numbers"),
        ("48,1,1,0.9,1 0 0 0 1 0 0 0 a,0 0 800,0.1", "not numeric"),
        ("48,1,1,0.9,1 0 0 0 1 0 0 0 1,0 nan 800,0.1", "non-finite"),
        ("48,1,1,0.9,1 0 0 0 1.01 0 0 0 1,0 0 800,0.1", "not a rotation"),
        ("48,1,1,0.9,1 0 0 0 1 0 0 0 -1,0 0 800,0.1", "not a rotation"),
    ],
)
def test_bad_rows(tmp_path: Path, line: str, needle: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(HEADER + "\n48,1,1,0.9,1 0 0 0 1 0 0 0 1,0 0 800,0.1\n" + line + "\n")
    with pytest.raises(ResultsFormatError) as ei:
        read_results_csv(path)
    msg = str(ei.value)
    assert f"{path}:3" in msg and needle in msg and "\n" not in msg


def test_small_rounding_is_accepted(tmp_path: Path) -> None:
    path = tmp_path / "r.csv"
    path.write_text(HEADER + "\n1,1,1,1,1.0004 0 0 0 1 0 0 0 1,0 0 800,0.1\n")
    assert len(read_results_csv(path)) == 1
    with pytest.raises(ResultsFormatError, match="not found"):
        read_results_csv(tmp_path / "nope.csv")


def test_appender_header_once_and_resume(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "run.csv"
    rows = _rows(5)
    with ResultsAppender(path) as app:
        assert app.done_keys() == set()
        for r in rows[:3]:
            app.append(r)
        # flushed: readable while still open
        assert len(read_results_csv(path)) == 3
    with open(path, "a") as f:  # a run killed mid-row
        f.write("48,9,1,0.5,1 0 0")
    app = ResultsAppender(path)
    assert app.done_keys() == {r.key for r in rows[:3]}
    for r in rows[3:]:
        app.append(r)
    assert app.done_keys() == {r.key for r in rows}
    app.close()
    text = path.read_text()
    assert text.count(HEADER) == 1
    back = read_results_csv(path)
    assert [r.key for r in back] == [r.key for r in rows]


def test_appender_rejects_bad_existing_file(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    path.write_text(HEADER + "\n1,2,3\n")
    with pytest.raises(ResultsFormatError, match=r"run\.csv:2"):
        ResultsAppender(path)
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    ResultsAppender(empty).close()
    assert empty.read_text() == HEADER + "\n"


def test_detections_best_score_and_round_trip(tmp_path: Path) -> None:
    def det(im: int, obj: int, bbox: list, score: float) -> dict:
        return {"scene_id": 48, "image_id": im, "category_id": obj, "bbox": bbox, "score": score}

    dets = [
        det(1, 1, [10, 20, 30, 40], 0.5),
        det(1, 1, [11, 21, 31, 41.5], 0.9),
        det(1, 1, [0, 0, 5, 5], 0.2),
        det(2, 5, [1, 2, 3, 4], 0.3),
    ]
    path = tmp_path / "det.json"
    write_detections(path, dets)
    on_disk = json.loads(path.read_text())
    assert len(on_disk) == 4 and on_disk[0]["time"] == -1.0
    got = read_detections(path)
    assert got == {(48, 1, 1): (11.0, 21.0, 31.0, 41.5), (48, 2, 5): (1.0, 2.0, 3.0, 4.0)}


def test_detections_errors(tmp_path: Path) -> None:
    path = tmp_path / "det.json"
    with pytest.raises(DatasetError, match=r"det\.json"):
        read_detections(path)
    path.write_text("[{")
    with pytest.raises(BopFormatError, match=r"det\.json"):
        read_detections(path)
    path.write_text(json.dumps([{"scene_id": 1, "image_id": 1, "category_id": 1, "bbox": [1, 2]}]))
    with pytest.raises(BopFormatError, match=r"detection 0.*bbox"):
        read_detections(path)
    path.write_text(json.dumps([{"scene_id": 1, "image_id": 1, "bbox": [1, 2, 3, 4]}]))
    with pytest.raises(BopFormatError, match="category_id"):
        read_detections(path)


def test_a_header_with_a_renamed_column_is_named(tmp_path: Path) -> None:
    """Before: "scene_id 'scene_id' is not an integer"; now the header and the column are named."""
    path = tmp_path / "r.csv"
    row = "1,1,1,0.9,1 0 0 0 1 0 0 0 1,0 0 800,0.1\n"
    path.write_text(HEADER.replace("obj_id", "object") + "\n" + row)
    with pytest.raises(ResultsFormatError) as err:
        read_results_csv(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}:1: header is wrong: expected column 'obj_id'")
    assert "found 'object'" in msg
    path.write_text(" scene_id, im_id,obj_id,score,R,t,time\n" + row)  # spaces are fine
    assert len(read_results_csv(path)) == 1
