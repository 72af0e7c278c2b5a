"""Benchmarks against a peer: taskcam and another tool, another method or an earlier
commit on the same input, printed side by side (case, ours, peer, ratio, unit)."""
