"""trainer.precision: null picks bf16 only where the CPU computes it natively."""

from __future__ import annotations

from pathlib import Path

import pytest

from training.precision import auto_precision, cpu_flags

EPYC_AVX2 = "processor\t: 0\nvendor_id\t: AuthenticAMD\nflags\t\t: fpu sse sse2 avx avx2 fma\n"
XEON_AMX = "processor\t: 0\nflags\t\t: fpu avx2 avx512f avx512_bf16 amx_bf16 amx_tile\n"


@pytest.mark.parametrize(
    ("cpuinfo", "expected"), [(EPYC_AVX2, "32-true"), (XEON_AMX, "bf16-mixed"), ("", "32-true")]
)
def test_cpu_precision_follows_the_bf16_flags(tmp_path: Path, cpuinfo: str, expected: str) -> None:
    path = tmp_path / "cpuinfo"
    path.write_text(cpuinfo)
    assert auto_precision("cpu", cpu_flags(path)) == expected


def test_cpu_flags_of_a_missing_file_are_empty(tmp_path: Path) -> None:
    assert cpu_flags(tmp_path / "absent") == set()
