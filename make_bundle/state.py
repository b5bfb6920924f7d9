"""Per-stage done markers and the settings of a run, written atomically."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

from chpf.atomic import atomic_write_text
from chpf.errors import ConfigError


def _write_json(path: Path, obj: Any) -> None:
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True))


class State:
    """``WORK/state.json`` (settings) and ``WORK/done/STAGE.json`` (one per finished stage)."""

    def __init__(self, work: Path) -> None:
        self.work = work
        self.done_dir = work / "done"

    def settings(self) -> dict | None:
        path = self.work / "state.json"
        return json.loads(path.read_text()) if path.is_file() else None

    def claim(self, settings: dict) -> dict:
        """The settings of the folder: ``settings`` recorded now unless some were recorded
        before (by a parallel shard job: the first one's plan holds for all)."""
        self.work.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=self.work, prefix=".state.", suffix=".tmp")
        with os.fdopen(fd, "w") as f:
            json.dump(settings, f, indent=2, sort_keys=True)
        try:
            os.link(tmp, self.work / "state.json")  # fails if there is one: never replaced
        except FileExistsError:
            pass
        finally:
            os.unlink(tmp)
        return self.settings() or settings

    def check_settings(self, settings: dict, overwrite: bool) -> bool:
        """Refuse a folder made with other settings (``settings["base"]``: the command's);
        with ``overwrite``, forget its finished stages and return True (outputs are stale)."""
        path = self.work / "state.json"
        stale = False
        if path.is_file():
            old = json.loads(path.read_text()).get("base", {})
            new = settings["base"]
            if old != new:
                keys = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
                if not overwrite:
                    raise ConfigError(
                        f"{self.work}: made with other settings ({', '.join(keys)}); "
                        "give --overwrite to start again"
                    )
                shutil.rmtree(self.done_dir, ignore_errors=True)
                stale = True
        self.work.mkdir(parents=True, exist_ok=True)
        self.done_dir.mkdir(exist_ok=True)
        _write_json(path, settings)
        return stale

    def done(self, stage: str) -> dict | None:
        p = self.done_dir / f"{stage}.json"
        return json.loads(p.read_text()) if p.is_file() else None

    def mark(self, stage: str, info: dict) -> None:
        _write_json(self.done_dir / f"{stage}.json", info)
