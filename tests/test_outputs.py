"""Every command checks its output before any work: an output that cannot be written (an
existing file where a folder is due, a folder where a file is due, a path under a file, a place
where nothing can be created) exits 2 with one line naming it, and a full disk is one line."""

from __future__ import annotations

import errno
import gc
import sys
from pathlib import Path

import pytest

from chpf.console import run_main
from chpf.errors import OutputError
from chpf.outdir import check_out_dir, check_out_file
from chpf.resumable_csv import ResumableCsv

# command -> (module with `cli`, arguments before the output path); the inputs do not exist:
# the output is checked first, so its error is the one printed.
COMMANDS = {
    "chpf-track": ("chpf.track_cli", ["--bundle", "nope", "--dataset", "nope", "--out"]),
    "chpf-gen-data": ("data_gen.cli", ["sequences", "--objects", "box", "--frames", "2", "--out"]),
    "chpf-export": ("export.cli", ["--ae", "a.ckpt", "--ch", "c.ckpt", "--object", "box", "--out"]),
    "chpf-eval": ("chpf.eval_cli", ["--dataset", "nope", "--results", "r.csv", "--json"]),
}


def _console(name: str, out: Path, capsys, monkeypatch) -> tuple[int, str, list[str]]:
    import importlib

    module, args = COMMANDS[name]
    monkeypatch.setattr(sys, "argv", [name, *args, str(out)])
    with pytest.raises(SystemExit) as exc:
        importlib.import_module(module).cli()
    cap = capsys.readouterr()
    return exc.value.code, cap.out, cap.err.strip().splitlines()


@pytest.mark.parametrize("name", list(COMMANDS))
def test_unwritable_outputs_are_refused_in_one_line_before_any_work(
    name, tmp_path, capsys, monkeypatch
):
    a_file = tmp_path / "a_file"
    a_file.write_text("mine\n")
    a_dir = tmp_path / "a_dir"
    a_dir.mkdir()
    wants_file = name == "chpf-eval"
    cases = [
        (a_dir if wants_file else a_file, "is a folder" if wants_file else "is not a folder"),
        (a_file / "sub", "not a folder"),
    ]
    if Path("/proc/self").is_dir():
        cases.append((Path("/proc/chpf_no_such/out"), "cannot create"))
    for out, needle in cases:
        code, stdout, err = _console(name, out, capsys, monkeypatch)
        assert code == 2 and len(err) == 1 and stdout == "", (out, stdout, err)
        assert err[0].startswith("error: ") and needle in err[0], (out, err)
    assert a_file.read_text() == "mine\n" and not any(a_dir.iterdir())


def test_check_out_dir_and_file_create_nothing(tmp_path):
    assert check_out_dir(tmp_path / "new" / "deeper") == tmp_path / "new" / "deeper"
    assert check_out_file(tmp_path / "new2" / "r.json") == tmp_path / "new2" / "r.json"
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "f").write_text("")
    with pytest.raises(OutputError, match=r"f: exists and is not a folder"):
        check_out_dir(tmp_path / "f")
    with pytest.raises(OutputError, match=r"f is a file, not a folder"):
        check_out_file(tmp_path / "f" / "x" / "r.json")
    with pytest.raises(OutputError, match=r"is a folder, not a file"):
        check_out_file(tmp_path)


def test_a_full_disk_is_one_line_and_no_noise_from_del(tmp_path, capsys, monkeypatch):
    """A CSV on a full device (/dev/full) fails with ENOSPC; the half-made writer leaves no
    'Exception ignored in __del__' behind, and a console script says it in one line."""
    seen = []
    monkeypatch.setattr(sys, "unraisablehook", seen.append)
    link = tmp_path / "log.csv"
    link.symlink_to("/dev/full")
    with pytest.raises(OSError) as exc:
        ResumableCsv(link, "a,b", lambda path, text: [])
    assert exc.value.errno == errno.ENOSPC and exc.value.filename == str(link)
    del exc
    gc.collect()
    assert seen == []

    def main(argv):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(sys, "argv", ["chpf-x"])
    with pytest.raises(SystemExit) as code:
        run_main(main)()
    err = capsys.readouterr().err.strip().splitlines()
    assert code.value.code == 2 and len(err) == 1
    assert err[0].startswith("error: no space left on device (disk full)") and "rerun" in err[0]
