"""
Benchmarks, validation runs and reliability campaigns; none of them is a test.

Run each script from the repository root as a module, e.g.
`python -m benchmarks.performance.bench_lumped`. Their tables go to benchmarks/results/.

performance/: speed and memory (bench_*.py and their reference points).
validation/: reproductions of the papers' figures and probes of their claims.
reliability/: fuzz and soak campaigns against the live nodes and the file readers.
common.py: the results tables' header and writer; live.py: what the live runs share.
"""
