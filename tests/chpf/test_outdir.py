"""chpf.outdir: one writer per output, settings recorded and compared."""

from __future__ import annotations

import json

import pytest

from chpf.errors import OutputError
from chpf.outdir import claim_settings, lock_output_dir, lock_output_path


def test_a_held_lock_refuses_a_second_holder_and_dies_with_its_holder(tmp_path):
    with lock_output_dir(tmp_path / "a", "first"):
        with pytest.raises(OutputError, match=r"another command is writing here \(first, pid"):
            with lock_output_dir(tmp_path / "a", "second"):
                pass
    with lock_output_dir(tmp_path / "a", "second"):  # released on exit
        pass


def test_gen_data_refuses_a_locked_output(tmp_path):
    from data_gen.cli import main as gen_main

    out = tmp_path / "seq"
    with lock_output_path(out, "test"):
        with pytest.raises(OutputError, match="another command is writing here"):
            gen_main(["sequences", "--objects", "box", "--out", str(out), "--frames", "2"])
    assert not out.exists()


def test_claim_settings_same_resumes_other_refused_unless_overwrite(tmp_path):
    assert claim_settings(tmp_path, "s.json", {"seed": 0, "n": (1, 2)}, False) is False
    assert claim_settings(tmp_path, "s.json", {"seed": 0, "n": (1, 2)}, False) is False
    with pytest.raises(OutputError, match=r"other settings \(seed differ"):
        claim_settings(tmp_path, "s.json", {"seed": 1, "n": (1, 2)}, False)
    assert claim_settings(tmp_path, "s.json", {"seed": 1, "n": (1, 2)}, True) is True
    assert json.loads((tmp_path / "s.json").read_text())["seed"] == 1
    other = tmp_path / "other"
    other.mkdir()
    (other / "x.csv").write_text("1\n")
    with pytest.raises(OutputError, match=r"not empty and has no s\.json"):
        claim_settings(other, "s.json", {"seed": 0}, False)
