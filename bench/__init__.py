"""chpf-bench: the paper's comparison as one command (suites, sequences, jobs, stats, report).

Uses ``chpf`` (tracking, evaluation) and ``data_gen`` (the held-out test sequences); never torch.
"""
