"""Speed and memory benchmarks: each prints a table and writes it under benchmarks/results/."""
