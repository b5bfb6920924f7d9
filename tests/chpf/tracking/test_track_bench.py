"""The tracking benchmark's timing and table (on the template bundle, a few frames)."""

from __future__ import annotations

import time

from chpf.benchmarks.track_bench import (
    bench_method,
    format_table,
    long_run,
    peak_resident_mb,
    resident_mb,
)
from chpf.bundle import Bundle
from chpf.tracking.tracker import Tracker


def test_bench_method_times_every_frame_and_prints_a_row(template_bundle, rendered_sequence):
    bundle = Bundle.load(template_bundle)
    seq = rendered_sequence
    frames = (seq.rgb, seq.depth, seq.K, [seq.box(i) for i in range(len(seq))])
    tracker = Tracker.from_bundle(bundle, method="chpf")
    t0 = time.perf_counter()
    row = bench_method([tracker], frames, n_frames=6, warmup=2)
    call_ms = (time.perf_counter() - t0) * 1000.0
    assert 0 < row["median"] <= row["p90"] and row["wall"] > 0
    # a timed frame holds the tracker's own stages and lasts less than the whole call's share
    assert row["total"] <= row["wall"] < call_ms / 6
    assert row["fps"] > 6 * 1000.0 / call_ms  # the 6 timed frames ran faster than the call
    assert row["network"] >= row["encode"] > 0 and 0 <= row["non_network_share"] < 1
    table = format_table({"chpf": row}).splitlines()
    assert "med ms" in table[0] and "p90 ms" in table[0] and table[0].endswith("RSS MB")
    assert table[2].split()[:2] == ["chpf", f"{row['fps']:.1f}"]
    # the row's resident memory, in its last column; the peak so far is at least today's
    assert 10 < row["rss_mb"] <= peak_resident_mb() + 1 and resident_mb() <= peak_resident_mb() + 1
    assert table[2].split()[-1] == f"{row['rss_mb']:.0f}"


def test_several_objects_step_in_turn_and_the_long_run_reports_memory(
    template_bundle, rendered_sequence
):
    """Two trackers on the same frames: each steps every warm-up and timed frame, and the row
    holds the stages of both; the long run reports start, middle and end."""
    bundle = Bundle.load(template_bundle)
    seq = rendered_sequence
    frames = (seq.rgb, seq.depth, seq.K, [seq.box(i) for i in range(len(seq))])
    two = [Tracker.from_bundle(bundle, seed=s) for s in (0, 1)]
    row = bench_method(two, frames, n_frames=4, warmup=1)
    assert [t.frame for t in two] == [5, 5]
    assert row["encode"] > 0 and row["wall"] >= row["total"] > 0
    tracker = Tracker.from_bundle(bundle)
    marks = long_run(tracker, frames, 9)
    assert tracker.frame == 9 and [m[0] for m in marks] == [1, 5, 9]
    assert all(mb > 10 and ms > 0 for _, mb, ms in marks)
