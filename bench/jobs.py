"""Jobs of a suite: method x modality x sequence x seed, in one fixed order (for shards)."""

from __future__ import annotations

from dataclasses import dataclass

from bench.sequences import Sequence
from bench.suite import Suite
from chpf.tracking.run_dataset import method_tag


@dataclass(frozen=True)
class Job:
    """One tracking run: a method on one sequence with one modality and one filter seed."""

    seq: Sequence
    method: str
    modality: str
    seed: int

    @property
    def id(self) -> str:
        """Folder name of the job's outputs (unique in a suite)."""
        return f"{self.seq.key}-{method_tag(self.method)}-{self.modality}-seed{self.seed}"


def make_jobs(suite: Suite, seqs: list[Sequence]) -> list[Job]:
    """Every job of the suite, ordered by sequence, modality, method, seed."""
    return [
        Job(s, m, mod, seed)
        for s in seqs
        for mod in suite.modalities
        for m in suite.methods
        for seed in suite.seeds
    ]


def shard(jobs: list[Job], index: int, count: int) -> list[Job]:
    """The jobs of shard ``index`` of ``count`` (0-based): every count-th job from index."""
    return jobs[index::count]
