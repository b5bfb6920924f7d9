"""The tracking benchmark's timing and table (on the template bundle, a few frames)."""

from __future__ import annotations

import time

from chpf.benchmarks.track_bench import bench_method, format_table, long_run
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
    assert "med ms" in table[0] and "p90 ms" in table[0]
    assert table[2].split()[:2] == ["chpf", f"{row['fps']:.1f}"]


def test_several_objects_add_up_and_the_long_run_reports_memory(template_bundle, rendered_sequence):
    """Two trackers on the same frames: a row's stages are per frame, both objects together
    (twice the encoder passes of one); the long run reports start, middle and end."""
    bundle = Bundle.load(template_bundle)
    seq = rendered_sequence
    frames = (seq.rgb, seq.depth, seq.K, [seq.box(i) for i in range(len(seq))])
    one = bench_method([Tracker.from_bundle(bundle, seed=0)], frames, n_frames=4, warmup=1)
    two = [Tracker.from_bundle(bundle, seed=s) for s in (0, 1)]
    both = bench_method(two, frames, n_frames=4, warmup=1)
    assert both["total"] > 1.5 * one["total"] and both["wall"] >= both["total"]
    marks = long_run(Tracker.from_bundle(bundle), frames, 9)
    assert [m[0] for m in marks] == [1, 5, 9]
    assert all(mb > 10 and ms > 0 for _, mb, ms in marks)
